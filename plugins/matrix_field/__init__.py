"""``matrix-field``: the matrix-field planner (docs/method.md) as a planbench plugin.

The shared IK loop (:mod:`planbench_plugins.ik_loop`) with the matrix field of the scene as its
repulsion (:mod:`planbench.field.scene_field`). Modules: ``config`` (settings), ``planner``.
"""

from planbench_plugins.ik_loop import ControlPoints, place_control_points, plot_result
from planbench_plugins.matrix_field.calibrated import CalibratedRepulsion, grid_repulsion
from planbench_plugins.matrix_field.config import MatrixFieldConfig
from planbench_plugins.matrix_field.planner import MatrixFieldPlanner

__all__ = [
    "CalibratedRepulsion",
    "ControlPoints",
    "MatrixFieldConfig",
    "MatrixFieldPlanner",
    "grid_repulsion",
    "place_control_points",
    "plot_result",
]
