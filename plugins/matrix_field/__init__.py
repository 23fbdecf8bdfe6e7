"""``matrix-field``: the matrix-field planner (METHOD.md section 4) as a planbench plugin.

Modules: ``config`` (settings), ``tasks`` (one function per task term), ``control_points``
(automatic placement along the links), ``kinematics`` (per-step pinocchio pass with buffers),
``planner`` (the loop, failure detection, field setup), ``plots``.
"""

from planbench_plugins.matrix_field.config import MatrixFieldConfig
from planbench_plugins.matrix_field.control_points import ControlPoints, place_control_points
from planbench_plugins.matrix_field.planner import MatrixFieldPlanner

__all__ = ["MatrixFieldConfig", "MatrixFieldPlanner", "ControlPoints", "place_control_points", "plot_result"]


def plot_result(problem, result, path_png=None, **kwargs):  # type: ignore[no-untyped-def]
    """Three panels: the arm with control points and repulsive vectors, the end-effector path among
    the obstacles, errors and repulsion over time. See :func:`.plots.plot_result`."""
    from planbench_plugins.matrix_field.plots import plot_result as _plot

    return _plot(problem, result, path_png, **kwargs)
