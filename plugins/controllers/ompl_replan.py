"""``ompl-replan``: a global sampling planner on the latest observation, a path follower, and a
replan whenever the path it follows becomes invalid.

This is how a sampling planner is deployed in a changing scene, and the comparator the reactive
methods must beat: RRT-Connect (any registered static planner, ``planner``) plans from the arm's
configuration to the goal in the observed scene: the exact geometry with ``truth`` sensing, the
occupied cells as boxes with ``depth`` sensing (whole cells; ``cell_inset`` shrinks them). The
obstacles the arm already touches where a plan starts are left out of that plan (observed cells
lie up to a cell beyond the true surface, so an arm a centimetre from a table can be "in" its
cells). The follower moves along
the path at ``speed_scale`` of every joint's velocity limit. On every new frame the rest of the path
(from the arm's configuration) is checked against the new observation every ``check_resolution``
rad; when it collides, the controller commands a stop in that tick and replans in the next, so
that the command the runner holds while the planning time is charged (as on a robot) is the stop,
not the old path's velocity. A failed plan leaves the arm still until the next frame.

**Safe mode** (``unknown = "occupied"``; default ``"free"``, :class:`~.unknown.UnknownSettings`):
on every frame, the cells the observation did not see (``grid.known``) within ``unknown_reach`` of
the arm where it is count as obstacles, merged into boxes with the occupied cells, both for the
check of the rest of the path and for a plan from there: a receding horizon of known-free space.
The path is re-checked on every frame, and the arm moves less than ``unknown_reach`` between two
frames (a frame's period, its latency and a held command at the scaled velocity limits), so the
follower never leaves known-free space: it stops (instantly: the runner has no acceleration limit)
where the rest of the path would enter unknown cells, and plans around them from there. Left out:
the arm's own cells (its body, spheres along the links plus ``unknown_self_margin``, at its
configuration and at the goal's, which the task asserts reachable; the sensor blinds itself
there) and, as for observed cells, the unknown boxes the arm already touches where a plan starts.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.planner import PlanStatus
from planbench.problem import Goal, Problem
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.registry import REGISTRY
from planbench.scene import Scene
from planbench_plugins.controllers.cells import cell_boxes, cell_scene
from planbench_plugins.controllers.unknown import UnknownSettings, arm_spheres, near_unknown
from planbench_plugins.ik_loop import place_control_points

__all__ = ["OMPLReplanConfig", "OMPLReplanController"]


@dataclass(frozen=True)
class OMPLReplanConfig(UnknownSettings):
    """Settings of ``ompl-replan``. ``unknown = "occupied"`` is its safe mode (module docstring):
    the unknown cells near the arm are obstacles for the path's checks and plans."""

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

    def __post_init__(self) -> None:
        for name in ("plan_time", "check_resolution"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be a finite number > 0, got {v!r}")
        if not 0 < self.speed_scale <= 1:
            raise InvalidConfigError(f"speed_scale must be in (0, 1], got {self.speed_scale!r}")
        if not 0 <= self.cell_inset < 0.5:
            raise InvalidConfigError(f"cell_inset must be in [0, 0.5) cells, got {self.cell_inset!r}")
        self.validate_unknown()


class OMPLReplanController(Controller):
    """``ompl-replan`` (module docstring)."""

    name = "ompl-replan"
    Config = OMPLReplanConfig

    def setup(self, task: ControlTask) -> None:
        self.task = task
        self.planner = REGISTRY.make(self.config.planner)
        self.vmax = self.config.speed_scale * np.asarray(task.robot.velocity_limit, dtype=float)
        self.safe = self.config.unknown == "occupied"
        self.points = place_control_points(task.robot) if self.safe else None  # the arm's body, as spheres
        goal_q = task.goal.q
        self.goal_arm = arm_spheres(task.robot, self.points, goal_q) if self.safe and goal_q is not None else None

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        self.rng = rng
        self.path: np.ndarray | None = None  # the path being followed, its first row where the arm was
        self.s = 0.0  # position along it: segment index + fraction
        self.checker: CollisionChecker | None = None
        self.frame_checker: CollisionChecker | None = None
        self.scene: Scene | None = None
        self.grid: OccupancyGrid | None = None  # the last frame's, for its unknown cells (safe mode)
        self.counted: np.ndarray | None = None  # the unknown cells counted on the last frame
        self.fresh = False
        self.still = True  # the last command was a stop (or nothing): a plan may start now
        self.may_plan = False  # one plan per frame at most
        self.stats: dict[str, Any] = {"plans": 0, "failed_plans": 0, "plan_times": [], "invalidated": 0, "dropped": 0}
        self.stats["unknown_boxes"] = 0  # on the last frame (safe mode)

    def update(self, observation: Observation) -> None:
        self.scene = observation.scene if observation.scene is not None else self._cells(observation)
        self.grid = observation.grid
        self.checker = None  # built when first needed (in the step: it is part of checking)
        self.frame_checker = None  # the whole observed scene's
        self.fresh = True

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        if self.scene is None:
            return np.zeros_like(q)
        if self.fresh:  # a new frame: the rest of the path is checked, one plan is allowed
            self.fresh, self.may_plan = False, True
            if self.safe:
                self.scene = self._with_unknown(q)
            if self.path is not None and not self._rest_free(q):
                self.stats["invalidated"] += 1
                self.path = None
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

    # --- planning ---------------------------------------------------------------------------
    def _cells(self, observation: Observation) -> Scene:
        scene = cell_scene(observation.grid)
        inset = self.config.cell_inset * observation.grid.resolution
        if inset <= 0:
            return scene
        shrunk = tuple(
            dataclasses.replace(o, size=tuple(s - 2 * inset for s in o.size)) if o.size is not None else o  # boxes
            for o in scene.obstacles
        )
        return Scene(shrunk, scene.name)

    def _with_unknown(self, q: np.ndarray) -> Scene:
        """The frame's scene plus its unknown cells near the arm at ``q`` as boxes (safe mode)."""
        assert self.scene is not None and self.grid is not None and self.points is not None
        arms = [arm_spheres(self.task.robot, self.points, q)]
        if self.goal_arm is not None:
            arms.append(self.goal_arm)
        c = self.config
        cells = near_unknown(self.grid, arms, c.unknown_reach, c.unknown_self_margin, self.counted)
        self.counted = cells
        if cells is None or not cells.any():
            self.stats["unknown_boxes"] = 0
            return self.scene
        obstacles = cell_boxes(cells, self.grid.origin, self.grid.resolution, "unknown")
        self.stats["unknown_boxes"] = len(obstacles)
        return Scene((*self.scene.obstacles, *obstacles), self.scene.name)

    def _plan(self, q: np.ndarray) -> None:
        task = self.task
        t0 = time.perf_counter()
        scene, _ = self._around(q)
        problem = Problem.create(
            task.robot, scene, q, goal_q=task.goal.q, goal_pose=task.goal.pose, tolerances=task.tolerances
        )
        self.planner.setup(problem)
        result = self.planner.plan(problem, time_limit=self.config.plan_time, rng=self.rng)
        self.stats["plans"] += 1
        self.stats["plan_times"].append(time.perf_counter() - t0)
        if result.status is not PlanStatus.SUCCESS or result.path is None or len(result.path) < 1:
            self.stats["failed_plans"] += 1
            return
        self.path, self.s = np.array(result.path, dtype=float), 0.0

    def _around(self, q: np.ndarray, count: bool = True) -> tuple[Scene, CollisionChecker]:
        """The observed scene without the obstacles the arm at ``q`` already touches, and a
        checker of it: observed cells are at most a cell off the true surface, so an arm a
        centimetre from a table can be "in" the table's cells; a plan must start somewhere
        (counted in ``dropped``). The frame's checker is built once and reused when nothing is
        touched."""
        assert self.scene is not None
        if self.frame_checker is None:
            self.frame_checker = CollisionChecker(self.task.robot, self.scene)
        touched = {obstacle.removeprefix("obstacle:") for _, obstacle in self.frame_checker.collisions(q)}
        if not touched:
            return self.scene, self.frame_checker
        if count:
            self.stats["dropped"] += len(touched)
        scene = Scene(tuple(o for o in self.scene.obstacles if o.name not in touched), self.scene.name)
        return scene, CollisionChecker(self.task.robot, scene)

    def _rest_free(self, q: np.ndarray) -> bool:
        """Whether the arm's way from ``q`` along the rest of the path is free in the observation."""
        assert self.path is not None and self.scene is not None
        if self.checker is None:  # what a plan from here would avoid (see _around)
            self.checker = self._around(q, count=False)[1]
        i = min(int(self.s) + 1, len(self.path) - 1)
        rest = np.vstack([q, self.path[i:]])
        for a, b in zip(rest[:-1], rest[1:], strict=True):
            n = max(1, int(math.ceil(np.max(np.abs(b - a)) / self.config.check_resolution)))
            for u in np.linspace(0.0, 1.0, n + 1)[1:]:
                if self.checker.in_collision(a + u * (b - a)):
                    return False
        return True

    # --- following --------------------------------------------------------------------------
    def _follow(self, q: np.ndarray) -> np.ndarray:
        """Advance along the path by one control period at the scaled velocity limits and steer
        toward that point (which also pulls the arm back onto the path after a held command)."""
        path, T = self.path, self.task.period
        assert path is not None
        budget = T  # [s] of motion left in this tick
        i, f = int(self.s), self.s - int(self.s)
        while i < len(path) - 1 and budget > 0:
            seg = path[i + 1] - path[i]
            duration = float(np.max(np.abs(seg) / self.vmax))  # [s] for the whole segment
            left = (1.0 - f) * duration
            if left <= budget:
                budget -= left
                i, f = i + 1, 0.0
            else:
                f += budget / duration
                budget = 0.0
        self.s = i + f
        target = path[i] if i >= len(path) - 1 else path[i] + f * (path[i + 1] - path[i])
        return np.clip((target - q) / T, -self.vmax / self.config.speed_scale, self.vmax / self.config.speed_scale)
