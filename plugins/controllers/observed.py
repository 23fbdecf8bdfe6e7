"""What a planning controller does with the obstacles the arm already touches in an observation.

A plan must start where the arm is, yet an observation can show the arm "in" an obstacle: observed
cells lie up to a cell beyond the true surface (an arm a centimetre from a table is in its cells),
and a moving obstacle may brush the arm. ``ompl-replan`` and ``matrix-field-guided`` leave those
obstacles out of a plan, the same way:

- truth sensing: the obstacles of the scene the arm touches (:func:`scene_without_touched`);
- depth sensing: the cells within a cell of the arm's body (:class:`ArmCells`, the cells
  :class:`~planbench.reactive.body.ArmBody` fills, grown by whole cells), when the arm touches
  cells there.
"""

from __future__ import annotations

import itertools
from collections.abc import Generator
from typing import Any, TypeVar

import coal
import numpy as np
import pinocchio as pin

from planbench.checking.collision import CollisionChecker
from planbench.geometry.occupancy import OccupancyGrid, grow_cells
from planbench.reactive.body import ArmBody
from planbench.robot import Robot
from planbench.scene import Scene

__all__ = [
    "ArmCells",
    "GoalCells",
    "LinkBoxes",
    "PathBoxes",
    "finished",
    "scene_without_touched",
    "scene_without_touched_in_steps",
]

R = TypeVar("R")


class ArmCells:
    """The cells of an observed grid that ``robot`` fills, and those next to them; the arm's body
    and the cells near its ``goal_q`` [rad] are kept per grid geometry (:meth:`fit`)."""

    def __init__(self, robot: Robot, goal_q: np.ndarray | None) -> None:
        self.robot = robot
        self.goal_q = None if goal_q is None else np.asarray(goal_q, dtype=float)
        self.body: ArmBody | None = None
        """The arm's body on the grid last fitted (None before)."""
        self.near_goal = np.zeros(0, dtype=np.intp)
        """Flat indices of the cells within a cell of the arm's body at the goal (none without one)."""
        self.at_goal = np.zeros(0, dtype=np.intp)
        """Flat indices of the cells the arm's body fills at the goal (none without one)."""
        self.size = 0
        """Cells of the grid last fitted."""
        self._key: tuple[object, ...] | None = None

    def fit(self, grid: OccupancyGrid) -> bool:
        """Use ``grid``'s cells (its shape, origin and resolution); True when they changed, and
        the body and :attr:`near_goal` were built anew."""
        return self.fit_geometry(np.asarray(grid.origin, dtype=float), grid.shape, grid.resolution)

    def fit_geometry(self, origin: np.ndarray, shape: tuple[int, ...], resolution: float) -> bool:
        """:meth:`fit` for a grid of lower corner ``origin`` [m], ``shape`` and ``resolution`` [m]
        given before any frame (a controller's setup, so that its first frame does not pay for it)."""
        key = (tuple(int(n) for n in shape), tuple(float(x) for x in origin), float(resolution))
        if key == self._key:
            return False
        self._key = key
        self.body = ArmBody(self.robot, np.asarray(origin, dtype=float), key[0], key[2])  # type: ignore[arg-type]
        self.size = int(np.prod(shape))
        self.near_goal = self.near(self.goal_q, 1) if self.goal_q is not None else np.zeros(0, dtype=np.intp)
        self.at_goal = self.body.cells(self.goal_q) if self.goal_q is not None else np.zeros(0, dtype=np.intp)
        return True

    def near(self, q: np.ndarray, cells: int) -> np.ndarray:
        """Flat indices of the cells within ``cells`` cells (a cube) of those the arm fills at ``q``."""
        body = self.body
        if body is None:
            raise RuntimeError("ArmCells.fit(grid) before near()")
        return self.around(body.cells(q), cells)

    def around(self, flat: np.ndarray, cells: int) -> np.ndarray:
        """Flat indices of the cells within ``cells`` cells (a cube) of the cells ``flat`` (the
        arm's, :meth:`ArmBody.cells`): :meth:`near` in two steps, for a caller that spreads them."""
        body = self.body
        if body is None:
            raise RuntimeError("ArmCells.fit(grid) before around()")
        return cells_around(flat, body.shape, cells)


def cells_around(flat: np.ndarray, shape: tuple[int, ...], cells: int) -> np.ndarray:
    """Flat indices of the cells of a grid of ``shape`` within ``cells`` cells (a cube) of the
    cells ``flat``, those included."""
    if not len(flat):
        return np.zeros(0, dtype=np.intp)
    hit = np.column_stack(np.unravel_index(flat, shape))
    lo = np.maximum(hit.min(axis=0) - cells, 0)
    hi = np.minimum(hit.max(axis=0) + cells + 1, shape)
    block = np.zeros(tuple(hi - lo), dtype=bool)
    block[tuple((hit - lo).T)] = True
    idx = np.argwhere(grow_cells(block, cells)) + lo
    return np.ravel_multi_index(tuple(idx.T), shape)


class GoalCells:
    """Which occupied cells near the arm's body at the goal a plan leaves out (:meth:`classify`):
    those occupied the first time a frame knew them (the static scene a grasp touches: observed
    cells lie up to a cell beyond the true surface), those within ``fringe`` cells (26-neighbours,
    per step) of such a cell, and those that appeared after a frame saw them free but have stayed
    longer than ``block_time`` [s] (what a map keeps where no ray passes any more: an obstacle that
    left in the arm's shadow). The others are an obstacle standing on the goal: kept, so that no
    plan reaches the goal while it is there.

    The fringe: a static surface's cells flicker in a depth map (rays that graze the surface clear
    a cell its hits set), so a cell beside a can that a frame saw free is occupied again the next,
    and would block the goal anew each time (on the Panda's tall bookshelf, ``dynamic-tune``'s
    shelf set, the goal was blocked in nearly every frame of a run and never reached in 20 s). A
    cell beside the static scene is taken for that surface, as a cell beyond it is at first sight;
    an obstacle standing on the goal still has cells farther from it. ``fringe = 0`` (the
    default): none."""

    def __init__(self, block_time: float, fringe: int = 0) -> None:
        self.block_time = block_time
        self.fringe = fringe
        self.first_seen = np.zeros(0, dtype=bool)  # the cells a frame knew
        self.static = np.zeros(0, dtype=bool)  # those occupied when first known
        self.beside = np.zeros(0, dtype=bool)  # those within ``fringe`` cells of a static one
        self._static_count = -1  # static cells when ``beside`` was found
        self.since = np.zeros(0)  # [s] since when the others are occupied (NaN: not)
        self.blocking = np.zeros(0, dtype=bool)
        """The cells that block the goal in the frame last classified: appeared, not yet stale."""

    def classify(self, time: float, grid: OccupancyGrid, near: np.ndarray) -> np.ndarray:
        """The frame at ``time`` [s]: for each of the cells ``near`` (flat indices into ``grid``,
        the same cells every frame until they change, which starts over), whether it is left out
        (the cells no frame has known are neither left out nor :attr:`blocking`)."""
        if len(self.first_seen) != len(near):
            self.first_seen = np.zeros(len(near), dtype=bool)
            self.static = np.zeros(len(near), dtype=bool)
            self.beside = np.zeros(len(near), dtype=bool)
            self._static_count = -1
            self.since = np.full(len(near), np.nan)
        occupied = np.asarray(grid.data).reshape(-1)[near] >= 0.5
        if not self.first_seen.all():  # the mask's bits of these cells only: no bool per cell of the grid
            new = grid.known_at(near) & ~self.first_seen
            self.static[new] = occupied[new]
            self.first_seen |= new
        surface = self.static
        if self.fringe > 0:
            count = int(np.count_nonzero(self.static))
            if count != self._static_count:  # static cells are only ever added: found again when they are
                self.beside = np.isin(near, cells_around(near[self.static], grid.shape, self.fringe))
                self._static_count = count
            surface = self.static | (self.beside & occupied)
        blocker = occupied & self.first_seen & ~surface
        self.since[~blocker] = np.nan
        self.since[blocker & np.isnan(self.since)] = time
        stale = time - self.since > self.block_time  # False where NaN
        self.blocking = blocker & ~stale
        return np.asarray(surface | stale, dtype=bool)


class LinkBoxes:
    """World-axis-aligned boxes around each of the arm's collision objects. A box holds its object,
    so a cell outside every box of a configuration cannot touch the arm there: a cheap way to rule
    out most cells, and most configurations, before an exact check of a path."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot
        corners = []
        for obj in robot.collision_model.geometryObjects:
            geometry = obj.geometry
            geometry.computeLocalAABB()
            box = geometry.aabb_local
            lo, hi = np.asarray(box.min_, dtype=float), np.asarray(box.max_, dtype=float)
            corners.append(np.array(list(itertools.product(*zip(lo, hi, strict=True)))))
        self.corners = np.stack(corners)  # (objects, 8, 3), each in its object's frame
        self.geometries = [obj.geometry for obj in robot.collision_model.geometryObjects]
        self.data = robot.model.createData()
        self.geometry_data = pin.GeometryData(robot.collision_model)

    def placements(self, q: np.ndarray) -> np.ndarray:
        """Each object's placement in the world at ``q`` [rad], (objects, 4, 4)."""
        pin.updateGeometryPlacements(self.robot.model, self.data, self.robot.collision_model, self.geometry_data, q)
        return np.array([M.homogeneous for M in self.geometry_data.oMg])  # one call per object: the cheapest read

    def boxes(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (objects, 3) [m] of each object's world box at placements ``h``."""
        world = np.einsum("gij,gkj->gki", h[:, :3, :3], self.corners) + h[:, None, :3, 3]
        return world.min(axis=1), world.max(axis=1)

    def touches(self, q: np.ndarray, grid: OccupancyGrid) -> bool:
        """Whether the arm at ``q`` [rad] touches one of the occupied cells of ``grid`` (data >=
        0.5): coal's exact test of each object against the cells its box (grown by a cell)
        overlaps, as an octree; the arm with itself is not asked."""
        h = self.placements(q)
        lower, upper = self.boxes(h)
        res = grid.resolution
        first, last = _cell_span(lower, upper, grid)
        request = coal.CollisionRequest()
        at = coal.Transform3s(np.eye(3), np.asarray(grid.origin, dtype=float))
        for g, (a, b) in enumerate(zip(first, last, strict=True)):
            idx = np.argwhere(grid.data[a[0] : b[0], a[1] : b[1], a[2] : b[2]] >= 0.5)
            if not len(idx):
                continue
            octree = coal.makeOctree((idx + a + 0.5) * res, res)
            place = coal.Transform3s(h[g, :3, :3], h[g, :3, 3])
            if coal.collide(self.geometries[g], place, octree, at, request, coal.CollisionResult()):
                return True
        return False

    def along(self, configurations: np.ndarray, grid: OccupancyGrid) -> PathBoxes:
        """The boxes at each of ``configurations`` (n, nq) [rad], and the cells of ``grid`` they
        overlap (a cell more on every side: a cell that only touches a face)."""
        n, objects = len(configurations), len(self.corners)
        lower, upper = np.empty((n, objects, 3)), np.empty((n, objects, 3))
        placements = np.empty((n, objects, 4, 4))
        for i, q in enumerate(configurations):
            placements[i] = self.placements(q)
            lower[i], upper[i] = self.boxes(placements[i])
        mask = np.zeros(grid.shape, dtype=bool)
        res = grid.resolution
        first, last = (x.reshape(-1, 3) for x in _cell_span(lower, upper, grid))
        for a, b in zip(first, last, strict=True):
            mask[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = True
        region = (first.min(axis=0), last.max(axis=0)) if n else (np.zeros(3, int), np.zeros(3, int))
        return PathBoxes(lower - res, upper + res, mask, region, grid.origin.copy(), res, placements, self.geometries)


def _cell_span(lower: np.ndarray, upper: np.ndarray, grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray]:
    """The first and one-past-last cell indices (..., 3) of ``grid`` that boxes with corners
    ``lower`` and ``upper`` [m] overlap, a cell more on every side, clipped to the grid."""
    shape, res = np.asarray(grid.shape), grid.resolution
    first = np.clip(np.floor((lower - grid.origin) / res).astype(int) - 1, 0, shape)
    last = np.clip(np.floor((upper - grid.origin) / res).astype(int) + 2, 0, shape)
    return first, last


class PathBoxes:
    """:meth:`LinkBoxes.along`: the boxes at a path's configurations, grown by a cell, and the
    cells they overlap."""

    def __init__(
        self,
        lower: np.ndarray,
        upper: np.ndarray,
        mask: np.ndarray,
        region: tuple[np.ndarray, np.ndarray],
        origin: np.ndarray,
        resolution: float,
        placements: np.ndarray,
        geometries: list[Any],
    ) -> None:
        self.lower, self.upper = lower, upper  # (configurations, objects, 3) [m]
        self.mask = mask  # bool, the grid's shape
        self.region = tuple(slice(int(a), int(b)) for a, b in zip(*region, strict=True))  # the mask's bounds
        self.origin, self.resolution = origin, resolution
        self.placements = placements  # (configurations, objects, 4, 4)
        self.geometries = geometries  # the objects' coal geometries

    def fresh(self, grid: OccupancyGrid, checked: np.ndarray) -> np.ndarray:
        """Flat indices of the occupied cells of ``grid`` (data >= 0.5) inside the mask and not
        ``checked`` (bool, flat): read in the mask's bounds only, not the whole grid."""
        r = self.region
        sub = (grid.data[r] >= 0.5) & self.mask[r] & ~checked.reshape(self.mask.shape)[r]
        idx = np.argwhere(sub) + np.array([x.start for x in r])
        return np.ravel_multi_index(tuple(idx.T), self.mask.shape).astype(np.intp)

    def near(self, cells: np.ndarray) -> np.ndarray:
        """Of the flat indices ``cells``, those inside the mask (cells a box may touch)."""
        return cells[self.mask.reshape(-1)[cells]]

    def touching(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (configuration, object) pairs, as two index arrays sorted by configuration, whose
        box holds the centre of one of ``cells`` (flat indices; the boxes grown by a cell hold
        every cell that touches them)."""
        idx = np.column_stack(np.unravel_index(cells, self.mask.shape))
        centres = self.origin + (idx + 0.5) * self.resolution
        # the box around all of a configuration's boxes first, then its objects' own boxes
        lo, hi = self.lower.min(axis=1), self.upper.max(axis=1)
        cell, row = np.nonzero(np.all((centres[:, None, :] >= lo) & (centres[:, None, :] <= hi), axis=-1))
        c = centres[cell][:, None, :]
        inside = np.all((c >= self.lower[row]) & (c <= self.upper[row]), axis=-1)  # (pairs, objects)
        k, obj = np.nonzero(inside)
        pairs = np.unique(row[k] * len(self.geometries) + obj)
        return pairs // len(self.geometries), pairs % len(self.geometries)

    def collides(self, cells: np.ndarray, rows: np.ndarray, objects: np.ndarray) -> bool:
        """Whether one of ``objects`` at its configuration of ``rows`` (:meth:`touching`) touches
        one of ``cells`` (flat indices, as one octree): coal's exact test, object by object."""
        if not len(rows):
            return False
        idx = np.column_stack(np.unravel_index(cells, self.mask.shape))
        octree = coal.makeOctree((idx + 0.5) * self.resolution, self.resolution)
        at = coal.Transform3s(np.eye(3), np.asarray(self.origin, dtype=float))
        request = coal.CollisionRequest()
        for i, g in zip(rows, objects, strict=True):
            h = self.placements[i, g]
            result = coal.CollisionResult()
            if coal.collide(self.geometries[g], coal.Transform3s(h[:3, :3], h[:3, 3]), octree, at, request, result):
                return True
        return False


def scene_without_touched(robot: Robot, scene: Scene, q: np.ndarray) -> tuple[Scene, CollisionChecker, int]:
    """``scene`` less the obstacles ``robot`` at ``q`` touches, a checker of it, and how many
    obstacles were left out."""
    return finished(scene_without_touched_in_steps(robot, scene, q))


def finished(steps: Generator[None, None, R]) -> R:
    """What a job built in steps (a generator) returns, its steps run at once."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]


def scene_without_touched_in_steps(
    robot: Robot, scene: Scene, q: np.ndarray
) -> Generator[None, None, tuple[Scene, CollisionChecker, int]]:
    """:func:`scene_without_touched` with a ``yield`` between its steps (each a fraction of a
    millisecond), for a control loop; ``yield from`` it. The contacts are listed only when the
    broadphase finds the arm at ``q`` in collision (every pair's check costs more)."""
    checker = yield from CollisionChecker.in_steps(robot, scene)
    yield
    if not checker.in_collision(q):
        return scene, checker, 0
    yield
    touched = {b.removeprefix("obstacle:") for _, b in checker.collisions(q) if b.startswith("obstacle:")}
    if not touched:  # the arm touches only itself
        return scene, checker, 0
    yield
    scene = Scene(tuple(o for o in scene.obstacles if o.name not in touched), scene.name)
    checker = yield from CollisionChecker.in_steps(robot, scene)
    return scene, checker, len(touched)
