"""Potential-field baselines sharing the matrix-field planner's IK loop (issue 6).

Only the repulsion source differs from ``matrix-field`` (:mod:`planbench_plugins.ik_loop.loop`),
so comparing them compares the fields. Both use Khatib's profile (:mod:`planbench_plugins.ik_loop.khatib`):

- ``distance-field`` (:mod:`.distance`): coal's exact distance and witness point between each
  robot link and its nearest obstacle;
- ``edt-field`` (:mod:`.edt`): the gradient of the occupancy grid's Euclidean distance transform
  (scipy), sampled trilinearly at the matrix field's control points.
"""

from planbench_plugins.ik_loop import khatib_gain, khatib_magnitude
from planbench_plugins.potential_fields.config import DistanceFieldConfig, EDTFieldConfig, PotentialFieldConfig
from planbench_plugins.potential_fields.distance import DistanceFieldPlanner, DistanceFieldRepulsion
from planbench_plugins.potential_fields.edt import EDTFieldPlanner, EDTFieldRepulsion

__all__ = [
    "DistanceFieldConfig",
    "DistanceFieldPlanner",
    "DistanceFieldRepulsion",
    "EDTFieldConfig",
    "EDTFieldPlanner",
    "EDTFieldRepulsion",
    "PotentialFieldConfig",
    "khatib_gain",
    "khatib_magnitude",
]
