"""The matrix-field planner: the IK loop of :mod:`.loop` with the matrix field as repulsion.

The repulsion at control point ``p_i`` is ``f_i = k_rep F(p_i)`` [m/s], ``F`` the matrix field
of the scene's occupancy grid (precomputed in ``setup`` in ``"full"`` mode, window sums at the
control points every step in ``"lazy"`` mode), ``k_rep`` derived from the stand-off
(:func:`repulsion_gain`). Everything else (steps, endings, diagnostics) is the shared loop's.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from planbench.problem import Problem
from planbench_plugins.matrix_field.config import MatrixFieldConfig
from planbench_plugins.matrix_field.control_points import ControlPoints
from planbench_plugins.matrix_field.kinematics import ArmKinematics
from planbench_plugins.matrix_field.loop import IKLoopPlanner, Repulsion, ZeroRepulsion, stalled

__all__ = ["MatrixFieldPlanner", "MatrixFieldRepulsion", "stalled", "wall_field", "repulsion_gain", "build_scene_field"]

log = logging.getLogger(__name__)


def wall_field(kernels: Any, distance: float) -> float:
    """Field magnitude at ``distance`` [m] from the face of a flat, one-cell-thick wall.

    Evaluated with the field module itself (lazy window sums, trilinear interpolation) on a plane
    wide enough to fill the kernel across its axis. The point lies on a cell-centre line, so the
    value is the kernel's own: ``|P(d)| (sum T)^2`` between cell centres.
    """
    from planbench.field import lazy_field
    from planbench.occupancy import OccupancyGrid

    r = kernels.resolution
    side = 2 * kernels.support + 3
    data = np.zeros((1, side, side))
    data[0] = 1.0
    origin = np.array([-0.5 * r, -(side / 2) * r, -(side / 2) * r])  # cell (0, c, c) centred at 0
    grid = OccupancyGrid(data, origin, r)
    point = np.array([[-(0.5 * r + distance), 0.0, 0.0]])
    return float(abs(lazy_field(grid, kernels, point)[0, 0]))


def repulsion_gain(config: MatrixFieldConfig, kernels: Any) -> float:
    """``k_rep`` [m/s per field unit]: ``config.repulsion_gain``, or ``speed_max / F_wall(standoff)``."""
    if config.repulsion_gain is not None:
        return float(config.repulsion_gain)
    f = wall_field(kernels, config.standoff)
    if f <= 0:
        return 0.0
    return config.speed_max / f


def build_scene_field(problem: Problem, config: MatrixFieldConfig) -> tuple[Any, Any, Any]:
    """``(grid, kernels, field)`` for a problem: the scene voxelized over the robot's reach.

    Bounds: the scene's bounding box grown by the kernel's reach and one cell, cut to the cube of
    half-side ``robot.reach() + kernel_reach`` around the base (nothing farther can touch the arm
    or push a control point). ``field`` is ``None`` in ``"lazy"`` mode or without obstacles; the
    grid is ``None`` without obstacles in reach.
    """
    from planbench.field import KernelSpec, full_field, surface_grid
    from planbench.occupancy import OccupancyGrid

    kernels = KernelSpec(reach=config.kernel_reach, profile=config.kernel_profile, taper=config.kernel_taper).build(
        config.grid_resolution
    )
    if len(problem.scene) == 0:
        return None, kernels, None
    grow = kernels.reach + config.grid_resolution
    half = problem.robot.reach() + grow
    lo, hi = problem.scene.aabb()
    lo = np.maximum(np.asarray(lo) - grow, -half)
    hi = np.minimum(np.asarray(hi) + grow, half)
    if np.any(hi <= lo):
        return None, kernels, None
    grid = OccupancyGrid.from_scene(problem.scene, config.grid_resolution, bounds=(lo, hi), rule="any")
    if config.surface_only:
        grid = surface_grid(grid)
    field = full_field(grid, kernels, dtype=np.float64) if config.field_mode == "full" else None
    return grid, kernels, field


class MatrixFieldRepulsion:
    """``f_i = gain * F(p_i)`` at the control points (full field sampled, or lazy window sums)."""

    def __init__(self, grid: Any, kernels: Any, field: Any, gain: float) -> None:
        self.grid, self.kernels, self.field, self.gain = grid, kernels, field, gain
        if field is None:
            from planbench.field import lazy_field

            self._lazy = lazy_field

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self.field is not None:
            F = self.field.sample(kin.points)
        else:
            F = self._lazy(self.grid, self.kernels, kin.points)
        F *= self.gain
        return kin.points, F, kin.support, kin.cp_joint


class MatrixFieldPlanner(IKLoopPlanner):
    """Matrix-field IK planner (``matrix-field``). See :mod:`.loop` and
    :class:`~planbench_plugins.matrix_field.config.MatrixFieldConfig`."""

    name = "matrix-field"
    Config = MatrixFieldConfig

    def plot_result(self, problem: Problem, result: Any, path_png: Any) -> Any:
        """The planner's figure of a result (``planbench plan ... --plot out.png``)."""
        from planbench_plugins.matrix_field.plots import plot_result

        return plot_result(problem, result, path_png, planner=self)

    def make_repulsion(self, problem: Problem, points: ControlPoints) -> Repulsion:
        """Voxelize the scene, build the kernels and (full mode) the whole field; derive the gain."""
        grid, kernels, field = build_scene_field(problem, self.config)
        gain = repulsion_gain(self.config, kernels)
        if grid is None or gain <= 0:
            return ZeroRepulsion()
        return MatrixFieldRepulsion(grid, kernels, field, gain)

    def field_at(self, points: np.ndarray) -> np.ndarray:
        """Field (N, 3) at world points [m] for the prepared problem (zeros without obstacles)."""
        prep = self._prepared
        assert prep is not None, "call setup(problem) first"
        rep = prep["repulsion"]
        if not isinstance(rep, MatrixFieldRepulsion):
            return np.zeros((len(points), 3))
        if rep.field is not None:
            return rep.field.sample(points)  # type: ignore[no-any-return]
        return rep._lazy(rep.grid, rep.kernels, points)  # type: ignore[no-any-return]
