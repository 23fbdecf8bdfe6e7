"""What the controller had observed while it moved: the risk it took, from the simulation's side.

Two things a closed-loop run records beside its trajectory, both from the observations the
controller was actually delivered (never from its own account):

- **Motion through unknown space.** A tick counts as *unobserved motion* when the arm moved during
  it and, at its end, fills a cell (:class:`~planbench.reactive.body.ArmBody`) that the latest
  delivered observation does not know (``grid.known``; with no observation delivered yet, every
  cell is unknown). Truth sensing knows every cell, so only the time before its first frame counts.
  The metric ``unobserved_motion`` [s] is the duration of those ticks: the time the arm spent
  where nothing told the controller it was free.
- **Which obstacles were ever observed.** An obstacle is observed from the delivery of the first
  observation that showed it: with truth sensing, one whose scene holds it; with depth sensing,
  one whose grid has an occupied cell whose centre lies within ``resolution * (1 + sqrt(3) / 2)``
  of the obstacle's surface at the frame's capture time (a point of the surface lies in a cell
  whose centre is half a diagonal away; one more cell for range noise). A mesh obstacle, which has
  no signed distance here, counts as shown by an occupied cell in its bounding box grown by that
  much. A collision with an obstacle never observed is reported apart: no controller could have
  avoided it by what it was shown.
- **Where a collision happened.** An obstacle counts as observed once any part of it was shown;
  a shelf board seen at one end can be hit at the other, where no camera saw it. So a collision
  is also told apart when it happens *in unobserved space*: at every contact point (coal's, the
  arm at the end of the colliding tick) the latest delivered observation does not know the
  point's cell and has no occupied cell within the reach above. The controller was shown neither
  the obstacle there nor free space.
"""

from __future__ import annotations

import math

import numpy as np

from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.body import ArmBody
from planbench.reactive.controller import Observation
from planbench.reactive.scenario import Scenario
from planbench.scene import Obstacle

__all__ = ["Exposure"]


class Exposure:
    """Tracks, over one run, what the delivered observations showed (module docstring)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.first_seen: dict[str, float] = {}
        """Obstacle name -> the time [s] of the delivery that first showed it."""
        self._latest: Observation | None = None
        self._body: ArmBody | None = None
        self._names = [o.name for o in scenario.problem.scene.obstacles] + [m.name for m in scenario.moving]

    def delivered(self, observation: Observation, t: float) -> None:
        """The controller was delivered ``observation`` at time ``t`` [s]."""
        self._latest = observation
        unseen = [n for n in self._names if n not in self.first_seen]
        if not unseen:
            return
        scene = observation.scene
        if scene is not None:  # truth: the scene itself
            shown = {o.name for o in scene.obstacles}
        else:
            captured = {o.name: o for o in self.scenario.scene_at(observation.time).obstacles}
            shown = {n for n in unseen if n in captured and _shown(captured[n], observation)}
        for name in unseen:
            if name in shown:
                self.first_seen[name] = float(t)

    def in_unknown(self, q: np.ndarray) -> bool:
        """Whether the arm at ``q`` [rad] fills a cell the latest delivered observation does not know."""
        latest = self._latest
        if latest is None:
            return True
        known = latest.grid.known
        if known is None:
            return False
        grid = latest.grid
        body = self._body
        if body is None or body.shape != grid.shape or not np.array_equal(body.lower, grid.origin):
            body = self._body = ArmBody(self.scenario.problem.robot, grid.origin, grid.shape, grid.resolution)
        return body.in_unknown(q, known)

    def unobserved_at(self, points: np.ndarray) -> bool:
        """Whether every point [m] (N, 3) lies in unobserved space for the latest delivered
        observation (module docstring): its cell unknown, no occupied cell within reach. With no
        observation delivered, every point does; with every cell known (truth), none does."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        latest = self._latest
        if latest is None:
            return True
        grid = latest.grid
        if grid.known is None or len(points) == 0:
            return False
        shape, reach = np.array(grid.shape), _reach(grid)
        for p in points:
            cell = np.floor((p - grid.origin) / grid.resolution).astype(int)
            if np.all((cell >= 0) & (cell < shape)) and grid.known[tuple(cell)]:
                return False
            centres = _occupied_centres(grid, p, p)
            if np.any(np.linalg.norm(centres - p, axis=1) <= reach):
                return False
        return True


def _shown(obstacle: Obstacle, observation: Observation) -> bool:
    """Whether the observation's grid has an occupied cell on ``obstacle`` (module docstring)."""
    grid = observation.grid
    lo, hi = obstacle.aabb()
    centres = _occupied_centres(grid, lo, hi)
    if len(centres) == 0:
        return False
    if obstacle.type == "mesh":
        return True
    return bool(np.any(obstacle.signed_distance(centres) <= _reach(grid)))


def _reach(grid: OccupancyGrid) -> float:
    """[m] How far from a surface the centre of a cell that shows it may lie (module docstring)."""
    return grid.resolution * (1.0 + math.sqrt(3.0) / 2.0)


def _occupied_centres(grid: OccupancyGrid, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Centres [m] (N, 3) of the grid's occupied cells in the box ``lo``-``hi`` grown by the reach."""
    res, reach = grid.resolution, _reach(grid)
    i0 = np.clip(np.floor((lo - reach - grid.origin) / res).astype(int), 0, grid.shape)
    i1 = np.clip(np.floor((hi + reach - grid.origin) / res).astype(int) + 1, 0, grid.shape)
    if np.any(i1 <= i0):
        return np.zeros((0, 3))
    block = grid.data[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]]
    return grid.origin + (i0 + np.argwhere(block > 0) + 0.5) * res  # type: ignore[no-any-return]
