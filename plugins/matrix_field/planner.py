"""The matrix-field planner: the shared IK loop (:mod:`planbench_plugins.ik_loop`) with the matrix
field as repulsion.

The repulsion at control point ``p_i`` is ``f_i = k_rep F(p_i)`` [m/s], ``F`` the matrix field
of the scene's occupancy grid (precomputed in ``setup`` in ``"full"`` mode, window sums at the
control points every step in ``"lazy"`` mode; :mod:`planbench.field.scene_field`), ``k_rep``
derived from the stand-off. Everything else (steps, endings, diagnostics) is the shared loop's.
"""

from __future__ import annotations

import numpy as np

from planbench.field.scene_field import FieldRepulsion, scene_repulsion
from planbench.problem import Problem
from planbench_plugins.ik_loop import ControlPoints, IKLoopPlanner, Repulsion, ZeroRepulsion
from planbench_plugins.matrix_field.calibrated import CalibratedRepulsion, calibrated_repulsion
from planbench_plugins.matrix_field.config import MatrixFieldConfig
from planbench_plugins.matrix_field.wall_push import WallKhatibRepulsion, wall_khatib

__all__ = ["MatrixFieldPlanner"]


class MatrixFieldPlanner(IKLoopPlanner):
    """Matrix-field IK planner (``matrix-field``). See :mod:`planbench_plugins.ik_loop` and
    :class:`~planbench_plugins.matrix_field.config.MatrixFieldConfig`."""

    name = "matrix-field"
    Config = MatrixFieldConfig
    presets = {
        "paper": {
            "damping": "fixed",
            "goal_tolerance_scale": 1.0,
            "tool_repulsion_gain": 0.0,
            "hierarchy": "nullspace",
            "self_collision": False,
            "escape_attempts": 0,
        },
        "calibrated": {"field_kind": "calibrated"},
    }
    """``matrix-field:paper``: the method as specified (docs/method.md), every configurable departure
    set back: the repulsion in the pose task's null space only, a fixed damping ``lambda``,
    success at the problem's own tolerances, no tool repulsion. Departures that are not settings
    (the angular speed cap, the collision checks, the limit handling) stay; docs/method.md lists
    them. ``matrix-field:calibrated``: the calibrated field (``field_kind="calibrated"``,
    docs/method.md section 8) in place of the directional kernels."""

    auto_hierarchy_redundant = "nullspace"
    """``hierarchy="auto"`` on a redundant arm: the null space, for both fields (docs/method.md,
    section 4). The priority rows were chosen here before the loop had escapes (MotionBenchMaker
    0001-0020, 48/140 against 44/140); with escapes they stall the hand short of goals next to
    obstacles, the same stall after every escape (issue 32, docs/planners.md). The controller of
    the same name keeps its rows (:class:`~planbench_plugins.controllers.MatrixFieldController`)."""

    def make_repulsion(self, problem: Problem, points: ControlPoints) -> Repulsion:
        """Voxelize the scene, build the kernels and (full mode) the whole field; derive the gain."""
        if self.config.field_kind == "calibrated":
            return calibrated_repulsion(problem, self.config) or ZeroRepulsion()
        rep = scene_repulsion(problem, self.config)
        if rep is None:
            return ZeroRepulsion()
        return wall_khatib(rep, self.config) if self.config.field_push != "linear" else rep

    def field_at(self, points: np.ndarray) -> np.ndarray:
        """Field (N, 3) at world points [m] for the prepared problem (zeros without obstacles)."""
        rep = self.stepper.repulsion
        rep = getattr(rep, "inner", rep)  # under the self-collision push
        if not isinstance(rep, (FieldRepulsion, CalibratedRepulsion, WallKhatibRepulsion)):
            return np.zeros((len(points), 3))
        return rep.field_at(points)
