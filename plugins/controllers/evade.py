"""Getting out of the way of an obstacle that comes at the arm.

A replanning controller stops when its path is blocked and plans again; while the goal is blocked
(a box crossing over it) it stands and waits. Standing still is safe from a static scene, not from
a box on its way through the arm: on ``dynamic-tune`` (2026-11-27) the depth runs of
``xarm7_crossing_*/0007`` stopped, the goal refused by every plan while the box passed over it,
and the box ran into the standing arm at every speed, a frame having shown it coming for half a
second. A person next to a robot expects it to yield.

The threat is what came in lately, without a track: the cells of the moving clusters of
:class:`~.prediction.MotionPredictor` (occupied now, seen free before, within
``prediction_memory``) and, where a track's velocity is trusted, the cells it sweeps. A track
needs frames close together and a replanning controller sees frames only between its plans, so
the moving cells alone must do. When one lies within ``evade_distance`` of the arm's body (its
sample points, ``SAMPLE_SPACING`` apart, to the cells' centres; the parts that a joint moves, not
the base, which no retreat moves), the arm retreats: a straight
joint motion of at most ``evade_step`` per joint, the one of ``evade_samples`` random ones (joint
limits kept) whose end keeps the body farthest from those cells (up to twice the distance; then
the shortest), its motion checked against every occupied cell and the arm itself. None farther
than where the arm stands: no retreat. A controller works a retreat out only for a standing arm:
the command it holds meanwhile would carry a moving arm off the motion that was checked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial import cKDTree

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.body import body_points
from planbench.robot import Robot

__all__ = ["EVADE_MODES", "ArmSamples", "EvadeSettings", "Threat", "retreat"]

EVADE_MODES = ("none", "retreat")
"""``"none"``: never; ``"retreat"``: back away from what came in lately (module docstring)."""

_MOTION_CHECKS = 8
"""Most candidate motions checked for collision per retreat, best first (each a coal check every
``check_resolution``): the rest of the budget is not spent on worse ones."""


@dataclass(frozen=True)
class EvadeSettings:
    """How a controller gets out of the way (module docstring); a mixin of a controller's config."""

    evade: str = "retreat"
    """``"retreat"`` (the default) or ``"none"`` (module docstring). Chosen on ``dynamic-tune``
    (2026-11-27, once a retreat started only from a standing arm): truth 68 of 72 against 63, 1
    collision with an observed obstacle against 9; depth 63 of 72 with no collision, against 61-63
    with 3-5 in the default's earlier runs (docs/reactive.md, "A retreat from a standing arm")."""
    evade_distance: float = 0.15
    """[m] A moving cell closer than this to the arm's body is a threat."""
    evade_step: float = 0.5
    """[rad] Largest move of one joint in a retreat."""
    evade_samples: int = 64
    """Random retreats scored per threat."""

    def validate_evade(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad setting."""
        if self.evade not in EVADE_MODES:
            raise InvalidConfigError(f"evade must be one of {EVADE_MODES}, got {self.evade!r}")
        for name in ("evade_distance", "evade_step"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InvalidConfigError(f"{name} must be a finite number > 0, got {v!r}")
        v = self.evade_samples
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise InvalidConfigError(f"evade_samples must be an integer >= 1, got {v!r}")


SAMPLE_SPACING = 0.05
"""[m] Spacing of the body's sample points a threat's distance is measured from: those of
:func:`~planbench.reactive.body.body_points`, one kept per cube of this side, so every point of the
body lies within about this of one; 470 on the Panda (its base left out: :class:`ArmSamples`),
where the grid's 2 cm give 30,151 (a retreat scores dozens of configurations in one tick: 23 ms a
retreat, against 93 ms with the grid's)."""


class ArmSamples:
    """Sample points [m] of the arm's body in the world at a configuration, ``spacing`` apart: of
    the parts a joint moves only. A part fixed to the world (the base) is left out: no motion takes
    it farther from anything, so a threat measured from it could never be retreated from, and the
    arm stood still under it (on ``dynamic-test:xarm7_pair_fast_depth/0008``, cells that came in
    beside the xArm7's base, within 3-7 cm of it, were nearest in 13 of the 21 retreats of 30 that
    found no end, the arm stopped for each, and the crossing ball hit it)."""

    def __init__(self, robot: Robot, spacing: float = SAMPLE_SPACING) -> None:
        self.robot = robot
        moved = [obj.parentJoint != 0 for obj in robot.collision_model.geometryObjects]
        parts, kept = [], []
        for index, points in enumerate(body_points(robot, spacing)):  # mesh vertices kept: thin them to one per cube
            if not moved[index]:
                continue
            _, first = np.unique(np.floor(points / spacing).astype(np.int64), axis=0, return_index=True)
            parts.append(points[np.sort(first)])
            kept.append(index)
        if not parts:
            raise InvalidConfigError(f"robot {robot.name!r} has no collision geometry that a joint moves")
        self.local = np.concatenate(parts)
        self.part = np.repeat(np.asarray(kept), [len(p) for p in parts])
        self._data = robot.model.createData()
        self._geometry_data = pin.GeometryData(robot.collision_model)

    def at(self, q: np.ndarray) -> np.ndarray:
        """The points (N, 3) [m] with the arm at ``q`` [rad]."""
        pin.updateGeometryPlacements(self.robot.model, self._data, self.robot.collision_model, self._geometry_data, q)
        placements = self._geometry_data.oMg
        R = np.array([M.rotation for M in placements])[self.part]
        t = np.array([M.translation for M in placements])[self.part]
        return np.einsum("nij,nj->ni", R, self.local) + t  # type: ignore[no-any-return]


class Threat:
    """Distances [m] from the arm's body to some cells of a grid (flat indices), from the body's
    sample points to the cells' centres."""

    def __init__(self, grid: OccupancyGrid, cells: np.ndarray) -> None:
        self.grid = grid
        self.tree = cKDTree(self._centres(np.asarray(cells, dtype=np.intp))) if len(cells) else None

    def _centres(self, cells: np.ndarray) -> np.ndarray:
        ijk = np.column_stack(np.unravel_index(cells, self.grid.shape))
        return self.grid.origin + (ijk + 0.5) * self.grid.resolution  # type: ignore[no-any-return]

    def distance(self, body: ArmSamples, q: np.ndarray, cap: float = math.inf) -> float:
        """The least distance [m] from the body's sample points at ``q`` to the cells' centres
        (``cap`` when farther: a bound that speeds up the search)."""
        if self.tree is None:
            return cap
        d, _ = self.tree.query(body.at(q), k=1, distance_upper_bound=cap)
        return float(min(cap, float(np.min(d))))


def retreat(
    q: np.ndarray,
    threat: Threat,
    body: ArmSamples,
    checker: CollisionChecker,
    limits: tuple[np.ndarray, np.ndarray],
    settings: EvadeSettings,
    resolution: float,
    rng: np.random.Generator,
) -> np.ndarray | None:
    """Where the arm at ``q`` retreats to (module docstring), or None: no motion checked free ends
    farther from the threat than ``q`` is, by more than a cell. ``resolution`` [rad]: the spacing
    of the motion's collision checks."""
    q = np.asarray(q, dtype=float)
    cap = 2.0 * settings.evade_distance
    here = threat.distance(body, q, cap)
    lower, upper = limits
    steps = rng.uniform(-settings.evade_step, settings.evade_step, size=(settings.evade_samples, len(q)))
    ends = np.clip(q + steps, lower, upper)
    scores = np.array([threat.distance(body, x, cap) for x in ends])
    moves = np.max(np.abs(ends - q), axis=1)
    order = np.lexsort((moves, -scores))  # farthest first, then the shortest move
    for i in order[:_MOTION_CHECKS]:
        if scores[i] <= here + threat.grid.resolution:
            return None
        n = max(1, math.ceil(moves[i] / resolution))
        if not any(checker.in_collision(q + u * (ends[i] - q)) for u in np.arange(1, n + 1) / n):
            return ends[i]  # type: ignore[no-any-return]
    return None
