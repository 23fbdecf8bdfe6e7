"""``ompl-replan``: a global sampling planner on the latest observation, a path follower, and a
replan whenever the path it follows becomes invalid.

This is how a sampling planner is deployed in a changing scene, and the comparator the reactive
methods must beat: RRT-Connect (any registered static planner, ``planner``) plans from the arm's
configuration to the goal in the observed scene: the exact geometry with ``truth`` sensing, the
occupied cells with ``depth`` sensing (whole cells, as one coal octree when the planner takes a
checker, :meth:`~planbench_plugins.ompl_planners.base.OMPLPlanner.use_checker`, else as boxes;
``cell_inset`` shrinks the boxes). The obstacles the arm already touches where a plan starts are
left out of that plan and of the path's checks (truth: whole obstacles; depth: the occupied cells
within a cell of the arm's body, and of its body at the goal, which the task asserts free: observed
cells lie up to a cell beyond the true surface, so an arm a centimetre from a table can be "in" its
cells). The follower moves along the path at ``speed_scale`` of every joint's velocity limit. On
every new frame the rest of the path (from the arm's configuration) is checked against the new
observation every ``check_resolution`` rad; when it collides, the controller commands a stop in
that tick and replans in the next, so that the command the runner holds while the planning time is
charged (as on a robot) is the stop, not the old path's velocity. A failed plan leaves the arm
still until the next frame.

**Safe mode** (``unknown = "occupied"``; default ``"free"``, :class:`~.unknown.UnknownSettings`):
plan optimistically, execute only into known space (as FASTER does for quadrotors: the plan may
cross unknown space, the committed motion may not). The plan is the default's, unknown cells free;
on every frame the rest of the path is also scanned with the arm's body
(:class:`~planbench.reactive.body.ArmBody`, the cells the ``unobserved_motion`` metric counts) for
the first configuration that fills a cell the frame does not know (``grid.known``), and the
follower stops ``lookahead`` seconds of path motion short of it (the runner stops a command at once:
the margin covers the check's spacing and a command held while a frame is checked). Allowed
unknown cells, where there is no alternative: those within ``unknown_self_margin`` of the arm's
body where the run starts (the sensor's robot filter blinds it there and the start is where the
arm is) and at the goal (which the task asserts free). When the follower is held at such a point
on a new frame, or a path is blocked within ``lookahead`` of the arm, the unknown cells the body
would fill over the next ``avoid_horizon`` seconds of the path join a set of cells to avoid
(each leaves it once a frame knows it), and the arm replans around them with the occupied cells.
If no plan avoids them, or after ``max_detours`` such replans without progress, it plans as the
default does and follows that path without the scan (``forced`` in ``info``): the only way on goes
through space no frame has seen.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.planner import PlanStatus
from planbench.problem import Goal, Problem
from planbench.reactive.body import ArmBody, body_points
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.registry import REGISTRY
from planbench.scene import Scene
from planbench_plugins.controllers.cells import cell_boxes
from planbench_plugins.controllers.unknown import UnknownSettings
from planbench_plugins.ompl_planners.grid import cells_checker

__all__ = ["OMPLReplanConfig", "OMPLReplanController"]


@dataclass(frozen=True)
class OMPLReplanConfig(UnknownSettings):
    """Settings of ``ompl-replan``. ``unknown = "occupied"`` is its safe mode (module docstring):
    plan optimistically, move only into cells an observation knows."""

    planner: str = "ompl-rrtconnect"
    """The registered static planner that (re)plans."""
    plan_time: float = 1.0
    """Time limit of one (re)plan [s]."""
    speed_scale: float = 0.5
    """Speed along the path, as a fraction of each joint's velocity limit (0, 1]."""
    check_resolution: float = 0.02
    """Spacing of the configurations at which the rest of the path is checked on a new frame [rad]."""
    cell_inset: float = 0.0
    """How far each box of observed cells is shrunk on each side, in cells [0, 0.5): 0 plans
    around whole cells (the grid's ``"any"`` rule: conservative); measured on the ``dynamic``
    suite, an inset of a quarter cell let the follower's fingers touch the tables it planned next to."""
    lookahead: float = 0.05
    """Safe mode: [s] of motion along the path (at ``speed_scale``) the follower keeps between the
    arm and the first configuration that fills an unknown cell (more than ``check_resolution``)."""
    avoid_horizon: float = 0.5
    """Safe mode: [s] of the path past a block whose unknown cells a replan avoids."""
    max_detours: int = 3
    """Safe mode: replans around unknown cells in a row (without 0.5 s of progress along a path
    between them) before the arm plans as the default does and goes through."""
    surface_margin: float = 0.04
    """Safe mode: [m] unknown cells within this of an occupied cell (centre to centre) are the
    unseen rest of a seen surface (the far side of a plate seen from above, the edge seen
    edge-on): obstacles for a plan, and never entered, even where no plan avoids other unknown cells."""
    gate: bool = True
    """Safe mode: follow the path only into cells the observation knows (else only the hidden
    cells next to occupied ones are kept out of, ``surface_margin``)."""
    start_margin: float = 0.04
    """Safe mode: [m] unknown cells within this of the arm's body where the run starts (rounded up
    to whole cells) may be entered: the sensor's robot filter blinds it within ``robot_margin``
    (0.03 m) of the arm, so these are never seen until the arm has moved; the same at the goal."""

    def __post_init__(self) -> None:
        for name in ("plan_time", "check_resolution", "lookahead", "avoid_horizon", "start_margin", "surface_margin"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be a finite number > 0, got {v!r}")
        if not 0 < self.speed_scale <= 1:
            raise InvalidConfigError(f"speed_scale must be in (0, 1], got {self.speed_scale!r}")
        if not 0 <= self.cell_inset < 0.5:
            raise InvalidConfigError(f"cell_inset must be in [0, 0.5) cells, got {self.cell_inset!r}")
        if isinstance(self.max_detours, bool) or not isinstance(self.max_detours, int) or self.max_detours < 0:
            raise InvalidConfigError(f"max_detours must be an integer >= 0, got {self.max_detours!r}")
        self.validate_unknown()


_PROGRESS = 0.5  # [s] along a path that resets the count of detours (max_detours)


def _next_to(cells: np.ndarray, shape: tuple[int, ...], radius: float, known: np.ndarray) -> np.ndarray:
    """Flat indices of the unknown cells (``known`` False) whose centres lie within ``radius``
    cells of one of ``cells`` (flat indices into a grid of ``shape``)."""
    r = int(math.floor(radius))
    if not len(cells) or r < 1:
        return np.zeros(0, dtype=np.intp)
    span = np.arange(-r, r + 1)
    offsets = np.stack(np.meshgrid(span, span, span, indexing="ij"), axis=-1).reshape(-1, 3)
    offsets = offsets[(np.sum(offsets**2, axis=1) <= radius * radius) & np.any(offsets != 0, axis=1)]
    idx = np.column_stack(np.unravel_index(cells, shape))
    out = []
    dims = np.asarray(shape)
    for off in offsets:  # one offset at a time: small arrays
        nb = idx + off
        ok = np.all((nb >= 0) & (nb < dims), axis=1)
        flat = np.ravel_multi_index(tuple(nb[ok].T), shape)
        out.append(flat[~known.flat[flat]])
    return np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.intp)


class OMPLReplanController(Controller):
    """``ompl-replan`` (module docstring)."""

    name = "ompl-replan"
    Config = OMPLReplanConfig

    def setup(self, task: ControlTask) -> None:
        self.task = task
        self.planner = REGISTRY.make(self.config.planner)
        self.vmax = self.config.speed_scale * np.asarray(task.robot.velocity_limit, dtype=float)
        self.safe = self.config.unknown == "occupied"
        body_points(task.robot, 0.02)  # the body's sample points at the default resolution, untimed

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        self.rng = rng
        self.start = np.array(q, dtype=float)
        self.path: np.ndarray | None = None  # the path being followed, its first row where the arm was
        self.times: np.ndarray | None = None  # [s] at each of its waypoints, at the scaled velocity limits
        self.tau = 0.0  # [s] position along it
        self.tau_limit = math.inf  # [s] where the follower stops (safe mode: short of unknown cells)
        self.through = np.zeros(0, dtype=np.intp)  # safe mode: unknown cells no plan avoided, entered
        self.detours = 0
        self.observation: Observation | None = None
        self.checker: CollisionChecker | None = None  # the frame's obstacles, less what the arm touches
        self.scene: Scene | None = None  # truth: the frame's scene, less what the arm touches
        self.occupied: np.ndarray | None = None  # depth: the frame's occupied cells (flat indices)
        self.body: ArmBody | None = None
        self.geometry: tuple[Any, ...] | None = None  # the grid the cell caches below belong to
        self.near_goal: np.ndarray | None = None  # cells within a cell of the body at the goal
        self.own: np.ndarray | None = None  # safe mode: unknown cells the arm may enter (start, goal)
        self.allowed: np.ndarray | None = None  # safe mode: known or own, the frame's (bool, grid shape)
        self.avoid = np.zeros(0, dtype=np.intp)  # safe mode: unknown cells that blocked a path
        self.hidden = np.zeros(0, dtype=np.intp)  # safe mode: unknown cells next to occupied ones
        self.fresh = False
        self.still = True  # the last command was a stop (or nothing): a plan may start now
        self.may_plan = False  # one plan per frame at most
        self.stats: dict[str, Any] = {"plans": 0, "failed_plans": 0, "plan_times": [], "invalidated": 0, "dropped": 0}
        self.stats.update(blocked=0, forced=0, avoided_cells=0)

    def update(self, observation: Observation) -> None:
        self.observation = observation
        self.checker = None  # built in the step (it needs the arm's configuration)
        self.fresh = True

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        if self.observation is None:
            return np.zeros_like(q)
        if self.fresh:  # a new frame: the rest of the path is checked, one plan is allowed
            self.fresh, self.may_plan = False, True
            self._frame(q)
            if self.path is not None:
                self._check_rest(q)
        if self.path is None:
            if not self.still:  # stop first: the runner holds this command while the plan is made
                self.still = True
                return np.zeros_like(q)
            if self.may_plan:
                self.may_plan = False
                self._plan(q)
            if self.path is None:
                return np.zeros_like(q)
        self.still = False
        return self._follow(q)

    def info(self) -> dict[str, Any]:
        return dict(self.stats)

    # --- the frame ----------------------------------------------------------------------------
    def _frame(self, q: np.ndarray) -> None:
        """The frame's checker (less the obstacles the arm at ``q`` touches) and, in safe mode, the
        cells the arm may enter."""
        obs = self.observation
        assert obs is not None
        if obs.scene is not None:  # truth: the exact geometry
            self.scene, self.checker = self._around(obs.scene, q)
            self.allowed = None
            return
        grid = obs.grid
        self._geometry(grid)
        self.occupied = np.flatnonzero(grid.data >= 0.5)
        self.allowed = None
        if not self.safe or grid.known is None:
            self.checker = self._cells_checker(self.occupied, q)
            return
        # the unseen rest of a seen surface: an obstacle, never entered
        self.hidden = _next_to(self.occupied, grid.shape, self.config.surface_margin / grid.resolution, grid.known)
        self.checker = self._cells_checker(np.union1d(self.occupied, self.hidden), q)
        if len(self.avoid):
            self.avoid = self.avoid[~grid.known.flat[self.avoid]]  # a known cell is no longer avoided
        if self.config.gate:
            allowed = grid.known.copy()
            assert self.own is not None and self.near_goal is not None
            allowed.flat[self.own] = True
            allowed.flat[self.through] = True
            allowed.flat[self.hidden] = False
            allowed.flat[self.near_goal] = True
            self.allowed = allowed

    def _geometry(self, grid: OccupancyGrid) -> None:
        """The caches that belong to the grid's cells: the arm's body, the cells near it at the goal
        and, in safe mode, where it started."""
        key = (grid.shape, tuple(grid.origin), grid.resolution)
        if key == self.geometry:
            return
        self.geometry = key
        self.body = ArmBody(self.task.robot, grid.origin, grid.shape, grid.resolution)
        goal_q = self.task.goal.q
        self.near_goal = self._near(np.asarray(goal_q), 1) if goal_q is not None else np.zeros(0, dtype=np.intp)
        self.avoid = np.zeros(0, dtype=np.intp)
        self.through = np.zeros(0, dtype=np.intp)
        if self.safe:
            cells = max(1, math.ceil(self.config.start_margin / grid.resolution))
            own = [self._near(self.start, cells)]
            if goal_q is not None:
                own.append(self._near(np.asarray(goal_q), cells))
            self.own = np.unique(np.concatenate(own))

    def _near(self, q: np.ndarray, cells: int) -> np.ndarray:
        """Flat indices of the cells within ``cells`` cells (a cube) of those the arm fills at ``q``."""
        assert self.body is not None
        mark = np.zeros(self.body.shape, dtype=bool)
        self.body.mark(mark, q)
        hit = np.argwhere(mark)
        if not len(hit):
            return np.zeros(0, dtype=np.intp)
        lo = np.maximum(hit.min(axis=0) - cells, 0)
        hi = np.minimum(hit.max(axis=0) + cells + 1, self.body.shape)
        block = mark[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        grown = ndimage.binary_dilation(block, np.ones((3, 3, 3), dtype=bool), iterations=cells)
        idx = np.argwhere(grown) + lo
        return np.ravel_multi_index(tuple(idx.T), self.body.shape)

    def _cells_checker(self, cells: np.ndarray, q: np.ndarray) -> CollisionChecker:
        """A checker of the cells (flat indices) less those within a cell of the arm at ``q`` and at
        the goal, when the arm touches them there (counted in ``dropped``)."""
        checker = self._checker_of(cells)
        goal_q = self.task.goal.q
        touched = checker.in_collision(q) or (goal_q is not None and checker.in_collision(np.asarray(goal_q)))
        if not touched:
            return checker
        assert self.near_goal is not None
        near = np.concatenate([self._near(q, 1), self.near_goal])
        kept = cells[~np.isin(cells, near)]
        self.stats["dropped"] += len(cells) - len(kept)
        return self._checker_of(kept)

    def _checker_of(self, cells: np.ndarray) -> CollisionChecker:
        obs = self.observation
        assert obs is not None
        grid = obs.grid
        if self.config.cell_inset <= 0:
            return cells_checker(self.task.robot, grid, cells)
        return CollisionChecker(self.task.robot, self._boxes(cells))

    def _boxes(self, cells: np.ndarray) -> Scene:
        """The cells (flat indices) as boxes, shrunk by ``cell_inset``."""
        grid = self.observation.grid  # type: ignore[union-attr]
        mask = np.zeros(grid.shape, dtype=bool)
        mask.flat[cells] = True
        inset = self.config.cell_inset * grid.resolution
        boxes = tuple(
            dataclasses.replace(o, size=tuple(s - 2 * inset for s in o.size)) if o.size is not None else o
            for o in cell_boxes(mask, grid.origin, grid.resolution)
        )
        return Scene(boxes, "observed-cells")

    def _around(self, scene: Scene, q: np.ndarray) -> tuple[Scene, CollisionChecker]:
        """Truth: the scene without the obstacles the arm at ``q`` touches (counted in ``dropped``),
        and a checker of it."""
        checker = CollisionChecker(self.task.robot, scene)
        touched = {obstacle.removeprefix("obstacle:") for _, obstacle in checker.collisions(q)}
        if not touched:
            return scene, checker
        self.stats["dropped"] += len(touched)
        scene = Scene(tuple(o for o in scene.obstacles if o.name not in touched), scene.name)
        return scene, CollisionChecker(self.task.robot, scene)

    # --- the rest of the path ------------------------------------------------------------------
    def _rest(self, q: np.ndarray, tau: float, until: float = math.inf) -> list[tuple[float, np.ndarray]]:
        """The configurations at which the rest of the path from ``q`` (at ``tau`` [s] along it) is
        checked, each with its time along the path [s], up to ``until`` [s]."""
        path, times = self.path, self.times
        assert path is not None and times is not None
        i = min(int(np.searchsorted(times, tau, side="right")), len(path) - 1)
        ends = np.vstack([q, path[i:]])
        stamps = np.concatenate([[tau], times[i:]])
        out = []
        for a, b, ta, tb in zip(ends[:-1], ends[1:], stamps[:-1], stamps[1:], strict=True):
            n = max(1, int(math.ceil(np.max(np.abs(b - a)) / self.config.check_resolution)))
            for u in np.arange(1, n + 1) / n:
                if ta + u * (tb - ta) > until:
                    return out
                out.append((ta + u * (tb - ta), a + u * (b - a)))
        return out

    def _check_rest(self, q: np.ndarray) -> None:
        """On a new frame: drop the path if its rest collides with the frame's obstacles; in safe
        mode, set where the follower stops short of unknown cells, and when that is where the arm
        is, avoid those cells and replan."""
        assert self.checker is not None
        gate = self.allowed is not None
        block = math.inf
        for when, x in self._rest(q, self.tau):
            if self.checker.in_collision(x):
                self.stats["invalidated"] += 1
                self.path = None
                return
            if gate and block == math.inf and self.body is not None and self.body.in_unknown(x, self.allowed):
                block = when
        self.tau_limit = block - self.config.lookahead
        if block < math.inf and self.tau >= self.tau_limit - 1e-9:  # held short of unknown cells
            self._avoid(q, block)

    def _avoid(self, q: np.ndarray, block: float) -> None:
        """The path is blocked by unknown cells at ``block`` [s] along it: avoid the unknown cells
        the body fills from there over ``avoid_horizon`` and replan (or go through: module docstring)."""
        assert self.body is not None and self.allowed is not None
        self.stats["blocked"] += 1
        if self.tau >= _PROGRESS:
            self.detours = 0
        self.detours += 1
        mark = np.zeros(self.body.shape, dtype=bool)
        at = self._at(block)
        self.body.mark(mark, at)
        for _, x in self._rest(at, block, block + self.config.avoid_horizon):
            self.body.mark(mark, x)
        mark &= ~self.allowed
        self.avoid = np.union1d(self.avoid, np.flatnonzero(mark))
        self.stats["avoided_cells"] = len(self.avoid)
        self.path = None

    # --- planning ---------------------------------------------------------------------------
    def _plan(self, q: np.ndarray) -> None:
        """Plan from ``q``: in safe mode around the cells to avoid; when no plan does (or after
        ``max_detours`` detours in a row), those cells may be entered (``forced``) and the arm plans
        as the default does, its path still scanned for other unknown cells."""
        avoiding = self.allowed is not None and len(self.avoid) > 0
        if avoiding and self.detours <= self.config.max_detours and self._plan_once(q, True):
            return
        if avoiding:  # no way around them: through them
            assert self.allowed is not None
            self.stats["forced"] += 1
            self.through = np.union1d(self.through, self.avoid)
            self.allowed.flat[self.avoid] = True
            self.avoid = np.zeros(0, dtype=np.intp)
            self.detours = 0
        self._plan_once(q, False)

    def _plan_once(self, q: np.ndarray, avoiding: bool) -> bool:
        task = self.task
        t0 = time.perf_counter()
        checker = self.checker
        assert checker is not None
        if avoiding:  # safe mode: around the hidden cells and the avoided ones
            assert self.occupied is not None
            checker = self._cells_checker(np.union1d(np.union1d(self.occupied, self.hidden), self.avoid), q)
        use_checker = getattr(self.planner, "use_checker", None)
        truth = self.observation is not None and self.observation.scene is not None
        if truth:
            assert self.scene is not None
            scene = self.scene
        elif use_checker is not None:
            scene = Scene(name="observed-cells")  # the checker holds the cells; certified for self-collision
        else:
            assert self.occupied is not None
            cells = np.union1d(self.occupied, self.hidden) if self.safe else self.occupied
            scene = self._boxes(np.union1d(cells, self.avoid) if avoiding else cells)
        problem = Problem.create(
            task.robot, scene, q, goal_q=task.goal.q, goal_pose=task.goal.pose, tolerances=task.tolerances
        )
        if use_checker is not None and not truth:
            use_checker(problem, checker)
        else:
            self.planner.setup(problem)
        result = self.planner.plan(problem, time_limit=self.config.plan_time, rng=self.rng)
        self.stats["plans"] += 1
        self.stats["plan_times"].append(time.perf_counter() - t0)
        if result.status is not PlanStatus.SUCCESS or result.path is None or len(result.path) < 1:
            self.stats["failed_plans"] += 1
            return False
        path = np.array(result.path, dtype=float)
        steps = np.max(np.abs(np.diff(path, axis=0)) / self.vmax, axis=1) if len(path) > 1 else np.zeros(0)
        self.path, self.times = path, np.concatenate([[0.0], np.cumsum(steps)])
        self.tau, self.tau_limit = 0.0, math.inf
        self._limit(q)
        return True

    def _limit(self, q: np.ndarray) -> None:
        """Safe mode: where the follower stops on a fresh path (short of its first unknown cell)."""
        if self.allowed is None or self.body is None:
            return
        for when, x in self._rest(q, 0.0):
            if self.body.in_unknown(x, self.allowed):
                self.tau_limit = when - self.config.lookahead
                return

    # --- following --------------------------------------------------------------------------
    def _at(self, tau: float) -> np.ndarray:
        """The path's configuration at ``tau`` [s] along it."""
        path, times = self.path, self.times
        assert path is not None and times is not None
        if tau <= 0 or len(path) == 1:
            return path[0].copy()
        if tau >= times[-1]:
            return path[-1].copy()
        i = int(np.searchsorted(times, tau, side="right")) - 1
        f = (tau - times[i]) / (times[i + 1] - times[i]) if times[i + 1] > times[i] else 1.0
        return path[i] + f * (path[i + 1] - path[i])

    def _follow(self, q: np.ndarray) -> np.ndarray:
        """Advance along the path by one control period at the scaled velocity limits (not past
        ``tau_limit``) and steer toward that point (which also pulls the arm back onto the path
        after a held command)."""
        T = self.task.period
        assert self.times is not None
        self.tau = max(self.tau, min(self.tau + T, self.tau_limit, float(self.times[-1])))
        target = self._at(self.tau)
        full = self.vmax / self.config.speed_scale
        return np.clip((target - q) / T, -full, full)
