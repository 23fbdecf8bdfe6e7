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

from collections.abc import Generator
from typing import TypeVar

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.geometry.occupancy import OccupancyGrid, grow_cells
from planbench.reactive.body import ArmBody
from planbench.robot import Robot
from planbench.scene import Scene

__all__ = ["ArmCells", "finished", "scene_without_touched", "scene_without_touched_in_steps"]

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
        key = (grid.shape, tuple(grid.origin), grid.resolution)
        if key == self._key:
            return False
        self._key = key
        self.body = ArmBody(self.robot, grid.origin, grid.shape, grid.resolution)
        self.size = int(np.prod(grid.shape))
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
        if not len(flat):
            return np.zeros(0, dtype=np.intp)
        hit = np.column_stack(np.unravel_index(flat, body.shape))
        lo = np.maximum(hit.min(axis=0) - cells, 0)
        hi = np.minimum(hit.max(axis=0) + cells + 1, body.shape)
        block = np.zeros(tuple(hi - lo), dtype=bool)
        block[tuple((hit - lo).T)] = True
        idx = np.argwhere(grow_cells(block, cells)) + lo
        return np.ravel_multi_index(tuple(idx.T), body.shape)


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
