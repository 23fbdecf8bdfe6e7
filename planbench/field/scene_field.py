"""The matrix field of a problem's scene, as a planner uses it: settings, the field, the push.

A planner that steers by the matrix field (``matrix-field``, ``matrix-field-qp``, a controller
later) needs the same four things: the field's settings (:class:`FieldSettings`, mixed into the
planner's config), the scene voxelized around the robot and correlated with the kernels
(:func:`build_scene_field`), a gain that turns field units into a speed
(:func:`standoff_gain`), and the push at points on the arm (:class:`FieldRepulsion`). They live
here, next to the field, so that those planners share them without importing each other.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.field.full import MatrixField, full_field
from planbench.field.interpolate import field_sampler
from planbench.field.kernels import PROFILES, TAPERS, Kernels, KernelSpec
from planbench.field.lazy import lazy_field
from planbench.field.surface import surface_grid
from planbench.geometry.occupancy import OccupancyGrid, scene_grid

__all__ = [
    "FIELD_MODES",
    "FieldSettings",
    "FieldRepulsion",
    "build_scene_field",
    "scene_repulsion",
    "standoff_gain",
    "wall_field",
]

FIELD_MODES = ("full", "lazy")


@dataclass(frozen=True)
class FieldSettings:
    """The matrix field's settings, mixed into a planner's config (``class C(FieldSettings,
    IKLoopConfig)``); :meth:`validate_field` checks them."""

    field_mode: str = "full"
    """``"full"``: precompute the field in ``setup`` (static scenes); ``"lazy"``: window sums at
    the control points every step (for grids that change). Both give the same path."""
    grid_resolution: float = 0.02
    """Occupancy grid cell size [m]."""
    kernel_reach: float = 0.15
    """Influence distance of the repulsion [m] (the kernel spans ``-reach .. +reach``)."""
    kernel_profile: str = "linear"
    """Profile along the kernel axis: ``linear``, ``gaussian`` or ``inverse-power``."""
    kernel_taper: str = "linear"
    """Taper across the kernel axis: ``linear``, ``gaussian`` or ``constant``."""
    surface_only: bool = True
    """Keep only surface cells before the field (thin walls and solid blocks repel alike)."""

    def validate_field(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad field setting."""
        for name in ("grid_resolution", "kernel_reach"):
            value = getattr(self, name)
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise InvalidConfigError(f"{name} must be a number, got {value!r}") from None
            if isinstance(value, bool) or not math.isfinite(v) or v <= 0:
                raise InvalidConfigError(f"{name} must be finite and > 0, got {value!r}")
        for name, choices in (("field_mode", FIELD_MODES), ("kernel_profile", PROFILES), ("kernel_taper", TAPERS)):
            if getattr(self, name) not in choices:
                raise InvalidConfigError(f"{name} must be one of {tuple(choices)}, got {getattr(self, name)!r}")
        if not isinstance(self.surface_only, bool):
            raise InvalidConfigError(f"surface_only must be true or false, got {self.surface_only!r}")
        standoff = getattr(self, "standoff", None)  # the loop's, when mixed into a loop planner's config
        if standoff is not None and standoff >= self.kernel_reach:
            raise InvalidConfigError(
                f"standoff {standoff} m must be below kernel_reach {self.kernel_reach} m: the "
                "field is zero beyond the reach, so no gain can push there"
            )

    def kernels(self) -> Kernels:
        return KernelSpec(reach=self.kernel_reach, profile=self.kernel_profile, taper=self.kernel_taper).build(
            self.grid_resolution
        )


def wall_field(kernels: Kernels, distance: float) -> float:
    """Field magnitude at ``distance`` [m] from the face of a flat, one-cell-thick wall.

    Evaluated with the field module itself (lazy window sums, trilinear interpolation) on a plane
    wide enough to fill the kernel across its axis. The point lies on a cell-centre line, so the
    value is the kernel's own: ``|P(d)| (sum T)^2`` between cell centres.
    """
    r = kernels.resolution
    side = 2 * kernels.support + 3
    data = np.zeros((1, side, side))
    data[0] = 1.0
    origin = np.array([-0.5 * r, -(side / 2) * r, -(side / 2) * r])  # cell (0, c, c) centred at 0
    grid = OccupancyGrid(data, origin, r)
    point = np.array([[-(0.5 * r + distance), 0.0, 0.0]])
    return float(abs(lazy_field(grid, kernels, point)[0, 0]))


def standoff_gain(kernels: Kernels, speed_max: float, standoff: float) -> float:
    """``speed_max / F_wall(standoff)`` [m/s per field unit]: a point ``standoff`` [m] from a flat
    wall is pushed away at ``speed_max`` [m/s]; 0 when the field is zero there."""
    f = wall_field(kernels, standoff)
    return speed_max / f if f > 0 else 0.0


def build_scene_field(
    problem: Any, settings: FieldSettings
) -> tuple[OccupancyGrid | None, Kernels, MatrixField | None]:
    """``(grid, kernels, field)`` for a problem: the scene voxelized around the robot
    (:func:`planbench.geometry.occupancy.scene_grid`, margin the kernel's reach plus one cell), surface
    cells only if set, and in ``"full"`` mode the whole field. ``field`` is ``None`` in
    ``"lazy"`` mode or without obstacles; ``grid`` is ``None`` without obstacles in reach."""
    kernels = settings.kernels()
    grid = scene_grid(
        problem.scene, settings.grid_resolution, kernels.reach + settings.grid_resolution, robot=problem.robot
    )
    if grid is None:
        return None, kernels, None
    if settings.surface_only:
        grid = surface_grid(grid)
    field = full_field(grid, kernels, dtype=np.float64) if settings.field_mode == "full" else None
    return grid, kernels, field


class FieldRepulsion:
    """``f_i = gain * F(p_i)`` [m/s] at points on the arm: the full field sampled, or (lazy) window
    sums over the grid. ``forces(kin)`` is the IK loop's repulsion interface."""

    def __init__(
        self, grid: OccupancyGrid, kernels: Kernels, field: MatrixField | None, gain: float, surface: bool = False
    ) -> None:
        self.grid, self.kernels, self.field, self.gain = grid, kernels, field, gain
        self.surface = surface  # lazy: read the grid through the surface pass (lazy_field's surface)
        self._points: np.ndarray | None = None  # the control points the buffers below are for
        self._F = np.empty((0, 3))
        self._fill: Callable[[], None] = lambda: None

    def field_at(self, points: np.ndarray) -> np.ndarray:
        """The field (N, 3) at world points [m], in field units (before the gain)."""
        if self.field is not None:
            return self.field.sample(points)
        return lazy_field(self.grid, self.kernels, points, surface=self.surface)  # type: ignore[no-any-return]

    def forces(self, kin: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(points, F, support, joint)`` at the control points ``kin.points``. ``F`` is a buffer,
        rewritten by the next call; the first call for a ``kin`` prepares it (full mode: the
        compiled sampler bound to ``kin.points`` and ``F``, sampling and gain in one pass)."""
        points = kin.points
        if points is not self._points:
            self._prepare(points)
        self._fill()
        return points, self._F, kin.support, kin.cp_joint

    def _prepare(self, points: np.ndarray) -> None:
        F = np.empty((len(points), 3))
        if self.field is not None:
            self._fill = field_sampler(self.field, points, F, self.gain)
        else:
            grid, kernels, gain, surface = self.grid, self.kernels, self.gain, self.surface

            def fill() -> None:
                np.multiply(lazy_field(grid, kernels, points, surface=surface), gain, out=F)

            self._fill = fill
        self._points, self._F = points, F


def scene_repulsion(problem: Any, config: Any) -> FieldRepulsion | None:
    """The matrix field of ``problem``'s scene as a repulsion, or ``None`` when nothing pushes (no
    obstacle in reach, or a zero gain). ``config``: :class:`FieldSettings` plus the loop's
    ``speed_max`` [m/s], ``standoff`` [m] and ``repulsion_gain`` [-], a multiplier of
    :func:`standoff_gain` (computed for the kernels at the grid's resolution, so the same
    ``repulsion_gain`` gives the same push at any resolution)."""
    grid, kernels, field = build_scene_field(problem, config)
    gain = config.repulsion_gain * standoff_gain(kernels, config.speed_max, config.standoff)
    if grid is None or gain <= 0:
        return None
    return FieldRepulsion(grid, kernels, field, gain)
