"""The calibrated field as the IK loop's repulsion (``field_kind="calibrated"``).

The calibrated distance ``d`` and its gradient (:mod:`planbench.field.calibrated`) at the control
points, turned into a push by Khatib's profile exactly as ``edt-field`` turns its distance
transform into one (:mod:`planbench_plugins.ik_loop.khatib`):
``f_i = |f|(d_i) grad d_i / |grad d_i|``, ``d0 = kernel_reach``, the gain from the stand-off. Only
the distance differs between the two, so comparing them compares the fields.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from planbench.field.calibrated import CalibratedKernel, CalibratedSpec, DistanceField, calibrated_at, calibrated_full
from planbench.field.interpolate import field_sampler
from planbench.geometry.occupancy import OccupancyGrid, scene_grid
from planbench_plugins.ik_loop import ArmKinematics, khatib_gain, khatib_magnitude

__all__ = ["CalibratedRepulsion", "calibrated_gain", "calibrated_repulsion"]


class CalibratedRepulsion:
    """Khatib's push along the calibrated distance's gradient (module docstring). ``field``: the
    distance precomputed at cell centres (``"full"`` mode), or ``None`` to evaluate it at the
    points from ``grid`` every step (``"lazy"``)."""

    def __init__(
        self,
        grid: OccupancyGrid,
        kernel: CalibratedKernel,
        field: DistanceField | None,
        gain: float,
        influence_distance: float,
        floor: float,
    ) -> None:
        self.grid, self.kernel, self.field = grid, kernel, field
        self.gain, self.d0, self.floor = float(gain), float(influence_distance), float(floor)
        self._points: np.ndarray | None = None  # the control points the buffers below are for
        self._F = np.empty((0, 3))
        self._fill: Callable[[], None] = lambda: None

    def distance_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(d, grad d)`` at world points (N, 3) [m]: ``d`` [m] capped at ``d0``."""
        if self.field is not None:
            return self.field.sample(points)
        d, grad = calibrated_at(self.grid, self.kernel, points)
        return np.minimum(d, self.d0), grad

    def field_at(self, points: np.ndarray) -> np.ndarray:
        """``grad d`` (N, 3) at world points: the direction of the push (away from obstacles)."""
        return self.distance_at(points)[1]

    def at(self, points: np.ndarray) -> np.ndarray:
        """Repulsive velocities (N, 3) [m/s] at world points (N, 3) [m]."""
        d, g = self.distance_at(points)
        norm = np.sqrt(np.einsum("ij,ij->i", g, g))
        mag = khatib_magnitude(d, self.gain, self.d0, self.floor)
        scale = np.divide(mag, norm, out=np.zeros_like(mag), where=norm > 1e-9)
        return g * scale[:, None]

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(points, F, support, joint)`` at ``kin.points``; ``F`` is a buffer rewritten by the
        next call (full mode: the compiled samplers bound to the points and buffers, so the loop
        gets the same arrays every step)."""
        points = kin.points
        if points is not self._points:
            self._prepare(points)
        self._fill()
        return points, self._F, kin.support, kin.cp_joint

    def _prepare(self, points: np.ndarray) -> None:
        F = np.empty((len(points), 3))
        if self.field is None:

            def fill() -> None:
                F[:] = self.at(points)

        else:
            deficit, grad = np.empty((len(points), 3)), np.empty((len(points), 3))
            sample_d = field_sampler(self.field.deficit, points, deficit)
            sample_g = field_sampler(self.field.gradient, points, grad)
            d0, gain, floor = self.d0, self.gain, self.floor

            def fill() -> None:
                sample_d()
                sample_g()
                d = np.maximum(deficit[:, 0] + d0, floor)
                norm = np.sqrt(np.einsum("ij,ij->i", grad, grad))
                mag = np.where(d < d0, gain * (1.0 / d - 1.0 / d0) / (d * d), 0.0)  # khatib_magnitude
                np.multiply(grad, (mag / np.maximum(norm, 1e-9) * (norm > 1e-9))[:, None], out=F)

        self._points, self._F, self._fill = points, F, fill


def calibrated_gain(config: Any) -> float:
    """Khatib's ``k`` [m^2/s] from the loop's stand-off, times ``repulsion_gain`` (``edt-field``'s)."""
    return float(config.repulsion_gain * khatib_gain(config.speed_max, config.standoff, config.kernel_reach))


def grid_repulsion(grid: OccupancyGrid, config: Any, mode: str) -> CalibratedRepulsion | None:
    """The calibrated push of ``grid`` (solid cells) for ``config`` (a ``MatrixFieldConfig``),
    precomputed when ``mode == "full"``; ``None`` when the gain is zero."""
    gain = calibrated_gain(config)
    if gain <= 0:
        return None
    kernel = CalibratedSpec(sigma=config.field_sigma, reach=config.kernel_reach).build(grid.resolution)
    field = calibrated_full(grid, kernel) if mode == "full" else None
    return CalibratedRepulsion(grid, kernel, field, gain, config.kernel_reach, config.distance_floor)


def calibrated_repulsion(problem: Any, config: Any) -> CalibratedRepulsion | None:
    """The calibrated push of ``problem``'s scene, voxelized like the matrix field's grid (margin
    ``kernel_reach`` plus a cell, rule ``"any"``) but kept solid; ``None`` without obstacles in reach."""
    margin = config.kernel_reach + config.grid_resolution
    grid = scene_grid(problem.scene, config.grid_resolution, margin, robot=problem.robot)
    if grid is None:
        return None
    return grid_repulsion(grid, config, config.field_mode)
