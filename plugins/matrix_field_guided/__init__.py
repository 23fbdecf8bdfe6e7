"""``matrix-field-guided``: a global path from a sampling planner, tracked reactively with the
matrix field keeping clearance (docs/method.md, "matrix-field-guided").

Reactive methods are deployed this way: a global planner (OMPL RRT-Connect on the same scene, by
default) finds a path through the clutter, and a local reactive loop follows it while the field
pushes the arm away from what it passes. Modules: ``config`` (settings), ``reference`` (the
global path as a reference trajectory), ``tracking`` (one step of the tracking law), ``planner``.
The controller ``matrix-field-guided`` (``planbench_plugins.controllers``) runs the same law per
control tick: :class:`Reference` and the two functions of ``tracking`` are public for it.
"""

from planbench_plugins.matrix_field_guided.config import MatrixFieldGuidedConfig
from planbench_plugins.matrix_field_guided.planner import MatrixFieldGuidedPlanner
from planbench_plugins.matrix_field_guided.reference import Reference
from planbench_plugins.matrix_field_guided.tracking import push_weight, tracking_velocity

__all__ = ["MatrixFieldGuidedConfig", "MatrixFieldGuidedPlanner", "Reference", "push_weight", "tracking_velocity"]
