"""Which unknown cells of an observed grid a controller counts as occupied (``unknown = "occupied"``).

A depth frame knows the cells its cameras saw (``grid.known``, docs/sensing.md); the rest is
unknown: the shadows behind surfaces, what lies outside the views, the space around and behind
the arm. ``"free"`` reads an unknown cell as free, as a single frame's grid always did (the
optimistic choice of most manipulation stacks). ``"occupied"`` reads some of them as obstacles,
chosen as a perception engineer would, so that the choice stays cheap and does not wall the arm in:

- **only near the arm**: unknown cells within ``unknown_reach`` [m] of one of the arm's control
  points (the IK loop's, :func:`~planbench_plugins.ik_loop.place_control_points`: spheres along
  every moving link). A camera leaves most of the world unknown (73 % of the Panda's 142^3 grid on
  ``dynamic:panda_crossing_fast_depth/0001``); beyond the fields' reach such cells push nothing.
  Merged into boxes, the unknown cells of that grid are 35,753 boxes; within 0.3 m of the arm,
  1,661 (``ompl-replan`` reads unknown cells its own way: its module docstring);
- **never the arm's own body**: cells within a link's radius plus ``unknown_self_margin`` [m] of a
  control point are left free. The sensor marks the cells the arm's body fills known, but its
  robot filter blinds it within ``robot_margin`` of the arm (docs/sensing.md), so a shell around
  the arm is unknown in a single frame. Counting that shell would wall the arm in; an obstacle
  that close is one the robot filter hides in any case.

What is left is not solved by any rule on one frame: the arm's shadow (the unknown behind the arm
as the camera sees it) starts at the arm's surface, so ``"occupied"`` pushes a field controller
toward the camera, until a map fused over frames fills
the shadow in from where the arm was before (``sensing.memory = "map"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid

__all__ = ["UNKNOWN_MODES", "UnknownSettings", "arm_spheres", "near_unknown", "unknown_as_occupied"]

UNKNOWN_MODES = ("free", "occupied")


@dataclass(frozen=True)
class UnknownSettings:
    """How a controller treats the cells its observation did not see (module docstring); a mixin
    of every built-in controller's config. Each controller's docstring says what ``"occupied"``
    does for its method."""

    unknown: str = "free"
    """``"free"``: unknown cells are free (the field controllers' default, chosen on the 24 fast
    depth scenarios of ``dynamic-tune``: ``matrix-field`` solved 8 with it and 6 with
    ``"occupied"``, ``edt-field`` 9 and 3; ``ompl-replan`` overrides it, docs/reactive.md, "Unknown
    space"); ``"occupied"``: the unknown cells near the arm are obstacles."""
    unknown_reach: float = 0.3
    """[m] with ``"occupied"``, only unknown cells within this distance of a control point count
    (beyond every field's reach, 0.15 m from a link surface, plus a link's radius, 0.09 m)."""
    unknown_self_margin: float = 0.02
    """[m] with ``"occupied"``, unknown cells within a link's radius plus this of a control point
    are the arm's own (the sensor's ``robot_margin``, 0.03 m, plus a cell's half-diagonal) and stay free."""

    def validate_unknown(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad unknown setting."""
        if self.unknown not in UNKNOWN_MODES:
            raise InvalidConfigError(
                f"unknown must be one of {UNKNOWN_MODES} (how cells no camera saw are read), got {self.unknown!r}"
            )
        for name in ("unknown_reach", "unknown_self_margin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise InvalidConfigError(f"{name} must be a finite number >= 0 [m], got {v!r}")
        if self.unknown_reach <= 0:
            raise InvalidConfigError(f"unknown_reach must be > 0 [m], got {self.unknown_reach!r}")


def _balls(grid: OccupancyGrid, centres: np.ndarray, radii: np.ndarray, out: np.ndarray) -> None:
    """Set ``out`` (the grid's shape) where a cell's centre lies within ``radii[i]`` of ``centres[i]``."""
    res, shape = grid.resolution, np.array(grid.shape)
    for c, r in zip(np.asarray(centres, dtype=float), np.asarray(radii, dtype=float), strict=True):
        lo = np.clip(np.floor((c - r - grid.origin) / res).astype(int), 0, shape)
        hi = np.clip(np.ceil((c + r - grid.origin) / res).astype(int), 0, shape)
        if np.any(hi <= lo):
            continue
        d2 = [(grid.origin[a] + (np.arange(lo[a], hi[a]) + 0.5) * res - c[a]) ** 2 for a in range(3)]
        inside = d2[0][:, None, None] + d2[1][None, :, None] + d2[2][None, None, :] <= r * r
        out[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] |= inside


def near_unknown(
    grid: OccupancyGrid,
    arms: list[tuple[np.ndarray, np.ndarray]],
    reach: float,
    self_margin: float,
    before: np.ndarray | None = None,
) -> np.ndarray | None:
    """The unknown cells of ``grid`` counted as occupied (module docstring), a bool array of its
    shape; None when every cell is known. ``arms``: the control points' world positions (N, 3)
    [m] and link radii (N,) [m] of the arm, where it is (first) and wherever else its body is
    known to be free of obstacles (a goal, say): only the first one's reach counts.

    ``before``: what the previous frame counted (same grid). A cell counted then and still unknown
    stays counted even where the arm's body now is: the arm moving into unknown space does not
    make it its own (else a field would fade as the arm enters, and let it through)."""
    if grid.known is None:
        return None
    near = np.zeros(grid.shape, dtype=bool)
    centres, radii = arms[0]
    _balls(grid, centres, np.full(len(centres), reach), near)
    body = np.zeros(grid.shape, dtype=bool)
    for centres, radii in arms:
        _balls(grid, centres, np.asarray(radii) + self_margin, body)
    if before is not None and before.shape == grid.shape:
        body &= ~before
    return near & ~grid.known & ~body


def unknown_as_occupied(grid: OccupancyGrid, cells: np.ndarray | None) -> OccupancyGrid:
    """``grid`` with ``cells`` (bool, its shape) occupied and every cell known; ``grid`` itself when
    ``cells`` is None or empty."""
    if cells is None or not cells.any():
        return grid
    data = np.maximum(grid.data, cells, dtype=grid.data.dtype)  # values of a checked grid, and 0 or 1
    return OccupancyGrid.unchecked(data, grid.origin, grid.resolution, grid.outside)


def arm_spheres(robot: Any, points: Any, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The control points ``points`` (:class:`~planbench_plugins.ik_loop.ControlPoints`) of
    ``robot`` at ``q`` [rad]: world positions (N, 3) [m] and link radii (N,) [m]."""
    return points.world(robot, q), np.asarray(points.radius, dtype=float)
