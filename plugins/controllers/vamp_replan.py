"""``vamp-replan``: VAMP's RRT-Connect replanning from the arm's configuration on every sensor frame,
and a path follower.

VAMP plans in about a millisecond, so this controller does what a slower planner cannot: it
replans on every frame rather than only when its path is invalidated. On the first tick after a
frame arrives it builds VAMP's environment from what the frame shows (with depth sensing its point
cloud, ``source = "points"``, one point per occupied 2 cm cube, or the grid's occupied cells,
``source = "cells"``; with truth sensing, where a frame has no points, the exact scene as VAMP
primitives), less the points beyond the arm's reach, and plans from the arm's configuration to the
goal configuration (VAMP's RRT-Connect, then its simplification). The new path replaces the old
one; when no path is found, the old path is kept if VAMP's check of its rest from the arm still
passes in the new environment, else the arm stops until a later frame gives a path. Everything a
frame costs (the environment, the plan, the check) is charged to that tick, as the closed-loop
rules charge every controller (docs/writing-a-controller.md, "Call order and timing"): building
VAMP's point-cloud structure for a few thousand points takes tens of milliseconds here, more than
the plan.

Obstacle points that VAMP's sphere model of the arm touches at its configuration, or at the goal
(which the task asserts free), are left out of that frame's environment: the depth camera's robot
filter removes points only within 3 cm of the true arm, and VAMP's spheres reach beyond it in
places, so without this the start of every plan could be "in collision". Unknown space is treated
as free (the frame shows what it shows; no map of what was never seen), as ``ompl-replan`` with
``unknown = "free"``. VAMP plans to a goal configuration: a task without one is not driven (the arm
stays still; ``info()["no_goal_configuration"]``). Only the robots VAMP has a model of (Panda, UR5)
can be driven; any other raises :class:`planbench_plugins.vamp_planners.UnsupportedRobotError` in
``setup``.

The follower moves along the path at ``speed_scale`` of every joint's velocity limit, commanding
each tick the velocity that reaches the path's configuration one period ahead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import vamp
from scipy.spatial import cKDTree

from planbench.errors import InvalidConfigError
from planbench.problem import Goal
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench_plugins.vamp_planners import VampRobot, environment, vamp_robot

__all__ = ["VampReplanConfig", "VampReplanController"]

SOURCES = ("points", "cells")


@dataclass(frozen=True)
class VampReplanConfig:
    """Settings of ``vamp-replan``."""

    source: str = "points"
    """What a frame's VAMP environment is built from: ``"points"`` (the frame's point cloud; the
    grid's occupied cells when the frame has no points) or ``"cells"`` (the grid's occupied cells,
    each a point at its centre with the cell's half diagonal as radius: the map, with what earlier
    frames saw). With truth sensing, the exact scene either way."""
    point_spacing: float = 0.02
    """``source = "points"``: the cloud becomes one VAMP point per occupied lattice cube of this edge
    [m], at the cube's centre, with the cube's half diagonal as radius (every observed point lies in
    a sphere; fewer points make VAMP's environment cheaper to build every frame)."""
    speed_scale: float = 0.5
    """Speed along the path, as a fraction of each joint's velocity limit (0, 1]."""
    max_iterations: int = 20_000
    """VAMP's iteration budget for one plan (a plan that finds nothing costs at most this)."""
    simplify: bool = True
    """Shorten each new path with VAMP's simplification."""

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise InvalidConfigError(f"source must be one of {SOURCES}, got {self.source!r}")
        for name in ("point_spacing", "speed_scale"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be a finite number > 0, got {v!r}")
        if not self.speed_scale <= 1:
            raise InvalidConfigError(f"speed_scale must be in (0, 1], got {self.speed_scale!r}")
        m = self.max_iterations
        if isinstance(m, bool) or not isinstance(m, int) or m < 1:
            raise InvalidConfigError(f"max_iterations must be an integer >= 1, got {m!r}")


def _timed(path: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """Times [s] at the waypoints of ``path`` when every segment takes its slowest joint's time."""
    steps = np.max(np.abs(np.diff(path, axis=0)) / vmax, axis=1) if len(path) > 1 else np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(steps)])


class VampReplanController(Controller):
    """``vamp-replan`` (module docstring)."""

    name = "vamp-replan"
    Config = VampReplanConfig

    def setup(self, task: ControlTask) -> None:
        self.task = task
        self.robot: VampRobot = vamp_robot(task.robot)
        self.vmax = self.config.speed_scale * np.asarray(task.robot.velocity_limit, dtype=float)
        self.goal = None if task.goal.q is None else np.array(task.goal.q, dtype=float)
        self.settings = vamp.RRTCSettings()
        self.settings.range = float(vamp.ROBOT_RRT_RANGES.get(self.robot.name, self.settings.range))
        self.settings.max_iterations = self.settings.max_samples = self.config.max_iterations

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        self.rng = rng
        self.path: np.ndarray | None = None
        self.times: np.ndarray | None = None
        self.t0 = 0.0  # [s] the run time when the path was started
        self.env: Any = None
        self.fresh = False
        self.stats: dict[str, Any] = {"plans": 0, "failed_plans": 0, "kept": 0, "stopped": 0, "points": []}
        if self.goal is None:
            self.stats["no_goal_configuration"] = True

    def update(self, observation: Observation) -> None:
        self.observation = observation
        self.fresh = True

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        if self.goal is None:
            return np.zeros_like(q)
        if self.fresh:
            self.fresh = False
            self._replan(t, np.asarray(q, dtype=float))
        if self.path is None or self.times is None:
            return np.zeros_like(q)
        ahead = min(t - self.t0 + self.task.period, float(self.times[-1]))
        target = np.array([np.interp(ahead, self.times, self.path[:, j]) for j in range(len(q))])
        return np.clip((target - q) / self.task.period, -self.vmax, self.vmax)

    def info(self) -> dict[str, Any]:
        out = dict(self.stats)
        points = out.pop("points")
        out["median_points"] = float(np.median(points)) if points else 0.0
        return out

    # --- a frame -------------------------------------------------------------------------------
    def _environment(self, q: np.ndarray) -> Any:
        """The frame's VAMP environment, less the points VAMP's arm touches at ``q`` and the goal."""
        obs = self.observation
        c = self.config
        if obs.scene is not None:  # truth sensing: the exact geometry
            return environment(obs.scene, self.robot)[0]
        grid = obs.grid
        if c.source == "points" and obs.points is not None:
            # one point per occupied lattice cube of edge point_spacing, at its centre
            idx = np.floor(np.asarray(obs.points, dtype=float) / c.point_spacing).astype(np.int64)
            lo = idx.min(axis=0) if len(idx) else np.zeros(3, dtype=np.int64)
            span = (idx.max(axis=0) - lo + 1) if len(idx) else np.ones(3, dtype=np.int64)
            keys = np.unique(np.ravel_multi_index((idx - lo).T, tuple(span)))
            cubes = np.column_stack(np.unravel_index(keys, tuple(span))) + lo
            points, spacing = (cubes + 0.5) * c.point_spacing, c.point_spacing
        else:
            cells = np.argwhere(grid.data >= 0.5)
            points, spacing = np.asarray(grid.origin, dtype=float) + (cells + 0.5) * grid.resolution, grid.resolution
        radius = 0.5 * math.sqrt(3.0) * spacing  # the cube's half diagonal: the sphere holds the cube
        base = self.robot.base
        cloud = points @ base[:3, :3].T + base[:3, 3]
        # beyond the arm's reach (VAMP's figures: its first joint, its longest reach) nothing collides
        name = self.robot.name
        first = np.asarray(vamp.ROBOT_FIRST_JOINT_LOCATIONS.get(name, (0.0, 0.0, 0.0)), dtype=float)
        reach = float(vamp.ROBOT_MAX_RADII.get(name, math.inf)) + radius
        cloud = cloud[np.linalg.norm(cloud - first, axis=1) <= reach]
        if len(cloud):
            tree = cKDTree(cloud)
            touched: list[int] = []
            for x in (q, self.goal):  # VAMP's arm spheres at the arm's configuration and at the goal
                spheres = self.robot.module.fk(np.asarray(x, dtype=np.float32))
                for b in spheres:
                    touched.extend(tree.query_ball_point((b.x, b.y, b.z), b.r + radius))
            if touched:
                cloud = np.delete(cloud, np.unique(touched), axis=0)
        self.stats["points"].append(len(cloud))
        env = vamp.Environment()
        if len(cloud):
            r_min, r_max = self.robot.radii
            env.add_pointcloud(cloud.astype(np.float32).tolist(), r_min, r_max, float(radius))
        return env

    def _replan(self, t: float, q: np.ndarray) -> None:
        """A new environment from the frame, a plan from ``q``; the old path kept if no plan is
        found and its rest still passes VAMP's check, else a stop."""
        module = self.robot.module
        self.env = env = self._environment(q)
        assert self.goal is not None
        q32, goal32 = q.astype(np.float32), self.goal.astype(np.float32)
        sampler = module.halton()
        sampler.skip(int(self.rng.integers(1024)))
        self.stats["plans"] += 1
        found = None
        if module.validate(q32, env) and module.validate(goal32, env):
            found = module.rrtc(q32, goal32, env, self.settings, sampler)
        if found is not None and found.solved:
            path = found.path
            if self.config.simplify:
                path = module.simplify(path, env, vamp.SimplifySettings(), sampler).path
            new = np.asarray(path.numpy(), dtype=float)
            new[0], new[-1] = q, self.goal
            self.path, self.times, self.t0 = new, _timed(new, self.vmax), t
            return
        self.stats["failed_plans"] += 1
        if self.path is not None and self._rest_free(t, q):
            self.stats["kept"] += 1
            return
        if self.path is not None:
            self.stats["stopped"] += 1
        self.path = self.times = None

    def _rest_free(self, t: float, q: np.ndarray) -> bool:
        """Whether VAMP's check passes the old path's rest from ``q`` in the new environment."""
        assert self.path is not None and self.times is not None
        i = int(np.searchsorted(self.times, t - self.t0, side="right"))
        rest = np.vstack([q, self.path[i:]]).astype(np.float32)
        module = self.robot.module
        return all(module.validate_motion(a, b, self.env, False) for a, b in zip(rest[:-1], rest[1:], strict=True))
