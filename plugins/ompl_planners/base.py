"""OMPL geometric planners on planbench problems, with coal collision checking.

One class, :class:`OMPLPlanner`, runs any OMPL geometric planner by its OMPL class name (``planner=
"AORRTC"``); the named baselines (``ompl-rrtconnect`` ...) are subclasses that fix the planner.

How a query runs (all inside ``plan()``, so all of it is timed by the harness):

1. The goal: the problem's goal configuration when it has one (``target="configuration"``); for a
   pose-only goal, goal configurations from the IK sampler in :mod:`.ik` (``target="pose"``).
2. OMPL's random generator is reseeded from the ``rng`` handed in (see *Seeding* below), then a fresh
   state space (the joint limits as bounds), ``SimpleSetup``, planner and problem are built.
3. ``solve`` runs for what is left of the time limit. Only an exact solution counts.
4. The path is simplified (``simplify=True``, OMPL's ``PathSimplifier`` via ``simplifySolution``)
   for at most what is left of the time limit; its time is reported apart in ``info``.
5. The returned path is checked once more like the harness checks it (no joint moves more than
   ``resolution`` between checked configurations); a collision there gives ``COLLISION``.

Collision checking: a plain Python function is OMPL's state validity checker; it calls
:meth:`planbench.collision.CollisionChecker.in_collision` (coal, robot against the scene's
primitives plus self-collision with the robot's ignore list, through a broadphase) or, with
``collision="grid"``, the same checker against the voxelized scene (:mod:`.grid`). States are
sampled within the joint limits, so the checker does not test limits.

Motion validation: OMPL's discrete motion validator checks a segment at points at most
``resolution`` [rad] apart in the Euclidean joint-space distance. No joint moves more than the
Euclidean distance, so no joint moves more than ``resolution`` between checks: at least as dense as
the harness's validation (0.01 rad on the largest joint by default), up to sqrt(nq) times denser.
The check points differ from the harness's, which is why step 5 exists.

Seeding: OMPL has one process-wide seed generator; every OMPL object with randomness draws its own
seed from it when it is created. ``ompl.util.RNG.setSeed`` before each query (with a seed drawn from
the planner's ``rng``) reseeds that generator, and every random object of the query is created after
it, so the same seed gives the same path, in a fresh process and also for repeated queries in one
process (OMPL logs an error that "changing the seed now will not lead to deterministic sampling": it
concerns objects created earlier, and none of the query's are). ``RNG.getSeed()`` keeps reporting
the first seed of the process. Exceptions: planners that run threads (``PRM``, ``PRMstar``: a
second thread searches the roadmap while it grows) and any planner with ``optimize=True`` (it stops
at the time limit, so the path depends on how fast the machine is) are not reproducible, nor is
``AORRTC``, which in OMPL 2.0.1 always runs until the time limit. The
benchmark runner's one process per run does not change this; the reseeding is what makes it work.

OMPL's own log output goes to the terminal from C++; ``log_level`` sets OMPL's process-wide level
before each query (default ``"none"``: nothing). All OMPL objects are freed at the end of each query,
so nanobind has no leaked objects to report at interpreter exit.
"""

from __future__ import annotations

import math
import re
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planbench.collision import CollisionChecker
from planbench.errors import InvalidConfigError, UnknownNameError
from planbench.metrics import densify
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem

__all__ = ["OMPLConfig", "OMPLAnyConfig", "OMPLPlanner", "geometric_planners", "planner_parameters"]

COLLISION_MODES = ("primitives", "grid")
LOG_LEVELS = ("none", "error", "warn", "info", "debug")


@dataclass(frozen=True)
class OMPLConfig:
    """Settings of the OMPL planners (``ompl-rrtconnect`` etc.)."""

    params: Mapping[str, Any] = field(default_factory=dict)
    """The OMPL planner's own parameters by OMPL's names, e.g. ``{"range": 1.0}`` or
    ``{"goal_bias": 0.1, "rewire_factor": 1.1}``; each calls the planner's setter (``setRange``,
    ``setGoalBias`` ...). Unset parameters keep OMPL's defaults."""
    collision: str = "primitives"
    """``"primitives"``: the scene's exact obstacles; ``"grid"``: its occupancy grid (see ``grid_*``)."""
    grid_resolution: float = 0.02
    """Cell size of the occupancy grid in ``collision="grid"`` mode [m]."""
    grid_geometry: str = "octree"
    """How the grid's occupied cells are given to coal: ``"octree"`` or ``"boxes"``."""
    resolution: float = 0.01
    """Motion validation: largest Euclidean joint-space step between checked states [rad]."""
    simplify: bool = True
    """Shortcut and smooth the path with OMPL's PathSimplifier (time reported in ``info``)."""
    optimize: bool = False
    """Asymptotically optimal planners: keep improving until the time limit (not reproducible)
    instead of stopping at the first exact solution."""
    verify: bool = True
    """Check the returned path densely, as the harness does, and report ``COLLISION`` if it fails."""
    ik_goals: int = 4
    """Pose-only goals: how many goal configurations to sample with IK."""
    ik_time_fraction: float = 0.2
    """Pose-only goals: share of the time limit the IK sampler may use [-]."""
    log_level: str = "none"
    """OMPL's own log output (process-wide): none, error, warn, info or debug."""

    def __post_init__(self) -> None:
        if self.collision not in COLLISION_MODES:
            raise InvalidConfigError(f"collision must be one of {COLLISION_MODES}, got {self.collision!r}")
        if self.grid_geometry not in ("octree", "boxes"):
            raise InvalidConfigError(f"grid_geometry must be 'octree' or 'boxes', got {self.grid_geometry!r}")
        if self.log_level not in LOG_LEVELS:
            raise InvalidConfigError(f"log_level must be one of {LOG_LEVELS}, got {self.log_level!r}")
        for name in ("grid_resolution", "resolution"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be > 0, got {v!r}")
        if not (isinstance(self.ik_goals, int) and self.ik_goals >= 1):
            raise InvalidConfigError(f"ik_goals must be an integer >= 1, got {self.ik_goals!r}")
        if not 0 < self.ik_time_fraction < 1:
            raise InvalidConfigError(f"ik_time_fraction must be in (0, 1), got {self.ik_time_fraction!r}")
        if not isinstance(self.params, Mapping):
            raise InvalidConfigError(f"params must be a mapping of OMPL parameter names to values, got {self.params!r}")
        object.__setattr__(self, "params", dict(self.params))


@dataclass(frozen=True)
class OMPLAnyConfig(OMPLConfig):
    """Settings of the ``ompl`` planner: any OMPL geometric planner by its class name."""

    planner: str = "RRTConnect"
    """OMPL geometric planner class name, e.g. ``"AORRTC"``, ``"RRTstar"``, ``"LBKPIECE1"``."""


def geometric_planners() -> list[str]:
    """Names of the OMPL geometric planners this ``ompl`` build offers."""
    from ompl import base as ob
    from ompl import geometric as og

    return sorted(n for n in dir(og) if isinstance(getattr(og, n), type) and issubclass(getattr(og, n), ob.Planner))


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def _setter(param: str) -> str:
    return "set" + "".join(part[:1].upper() + part[1:] for part in param.split("_"))


def planner_parameters(planner: str) -> list[str]:
    """Parameter names (OMPL's, snake_case) that ``params`` accepts for an OMPL planner class."""
    from ompl import base as ob
    from ompl import geometric as og

    base = set(dir(ob.Planner))
    cls = getattr(og, planner)
    return sorted(_snake(n[3:]) for n in dir(cls) if n.startswith("set") and n not in base)


_LOG_LEVEL_NAMES = {
    "none": "LOG_NONE",
    "error": "LOG_ERROR",
    "warn": "LOG_WARN",
    "info": "LOG_INFO",
    "debug": "LOG_DEBUG",
}

_STATUS_MESSAGES = {
    "Approximate solution": (PlanStatus.TIMEOUT, "only an approximate solution within the time limit"),
    "Timeout": (PlanStatus.TIMEOUT, "no solution within the time limit"),
    "Invalid start": (PlanStatus.INVALID_START, "OMPL rejected the start state"),
    "Invalid goal": (PlanStatus.INVALID_GOAL, "OMPL rejected the goal state"),
    "Infeasible": (PlanStatus.INFEASIBLE, "OMPL proved the problem infeasible"),
}


class OMPLPlanner(Planner):
    """Any OMPL geometric planner (``planner=`` its OMPL class name). See the module docstring.

    Planners: I. A. Sucan, M. Moll, L. E. Kavraki, "The Open Motion Planning Library", IEEE Robotics
    & Automation Magazine 19(4), 2012; each planner's own paper is cited in OMPL's documentation.
    """

    name = "ompl"
    Config: Any = OMPLAnyConfig
    ompl_planner: str | None = None  # fixed by the named subclasses

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        planner = self.planner_name
        known = geometric_planners()
        if planner not in known:
            raise UnknownNameError("OMPL geometric planner", planner, known)
        accepted = planner_parameters(planner)
        for key in self.config.params:
            if key not in accepted:
                raise UnknownNameError(f"parameter of OMPL planner {planner}", key, accepted)
        self._checker: CollisionChecker | None = None
        self._checker_key: tuple[Any, ...] | None = None

    @property
    def planner_name(self) -> str:
        return self.ompl_planner or self.config.planner

    # --- setup (untimed): the collision checker ----------------------------------------------
    def setup(self, problem: Problem) -> None:
        """Build the collision checker (and in grid mode, voxelize the scene)."""
        self._checker_for(problem)

    def _checker_for(self, problem: Problem) -> CollisionChecker:
        c = self.config
        key = (id(problem), c.collision, c.grid_resolution, c.grid_geometry)
        if self._checker is None or self._checker_key != key:
            if c.collision == "primitives":
                self._checker = CollisionChecker.for_problem(problem)
            else:
                from .grid import grid_checker, grid_for_scene

                grid = grid_for_scene(problem.scene, c.grid_resolution, padding=c.grid_resolution)
                self._checker = grid_checker(problem.robot, grid, c.grid_geometry)
            self._checker_key = key
        return self._checker

    # --- plan (timed) ------------------------------------------------------------------------
    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        t_start = time.perf_counter()
        deadline = t_start + time_limit
        c = self.config
        robot = problem.robot
        checker = self._checker_for(problem)
        checks_before = checker.n_checks
        info: dict[str, Any] = {"ompl_planner": self.planner_name, "collision": c.collision}

        def result(status: PlanStatus, path: Any = None, message: str = "") -> PlanResult:
            info["collision_checks"] = checker.n_checks - checks_before
            return PlanResult(status, path, None, target, message, info)

        # 1. goal configurations
        if problem.goal.q is not None:
            target = "configuration"
            goals = [np.array(problem.goal.q)]
            bad = robot.limit_violations(goals[0])
            if bad:
                return result(PlanStatus.INVALID_GOAL, message="goal outside joint limits: " + "; ".join(bad))
            if checker.in_collision(goals[0]):
                return result(PlanStatus.INVALID_GOAL, message=f"goal configuration in collision ({c.collision} mode)")
        else:
            from .ik import sample_goal_configurations

            target = "pose"
            t_ik = time.perf_counter()
            goals = sample_goal_configurations(
                problem, checker.in_collision, rng, c.ik_goals, c.ik_time_fraction * time_limit
            )
            info["ik_time"] = time.perf_counter() - t_ik
            info["ik_goals"] = len(goals)
            if not goals:
                return result(
                    PlanStatus.INVALID_GOAL, message="the IK sampler found no collision-free goal configuration"
                )
        if checker.in_collision(problem.start):
            return result(PlanStatus.INVALID_START, message=f"start in collision ({c.collision} mode)")

        seed = int(rng.integers(1, 2**31 - 1))
        info["ompl_seed"] = seed
        path, status_text, times = _solve(self.planner_name, c, problem.start, goals, checker, seed, deadline)
        info.update(times)
        info["ompl_status"] = status_text
        if path is None:
            status, message = _STATUS_MESSAGES.get(status_text, (PlanStatus.TIMEOUT, f"OMPL: {status_text}"))
            return result(status, message=message)

        path[0] = problem.start
        if target == "configuration" and np.abs(path[-1] - goals[0]).max() < 1e-9:
            path[-1] = goals[0]
        if c.verify:
            t_verify = time.perf_counter()
            dense, segment = densify(path, c.resolution)
            for k, q in enumerate(dense):
                if checker.in_collision(q):
                    info["verify_time"] = time.perf_counter() - t_verify
                    return result(
                        PlanStatus.COLLISION,
                        path,
                        f"OMPL's path collides on segment {int(segment[k])} when checked at the harness's resolution",
                    )
            info["verify_time"] = time.perf_counter() - t_verify
        return result(PlanStatus.SUCCESS, path)


def _solve(
    planner_name: str,
    c: OMPLConfig,
    start: np.ndarray,
    goals: list[np.ndarray],
    checker: CollisionChecker,
    seed: int,
    deadline: float,
) -> tuple[np.ndarray | None, str, dict[str, float]]:
    """One OMPL query; every OMPL object is created and freed here."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(getattr(ou, _LOG_LEVEL_NAMES[c.log_level]))
    ou.RNG.setSeed(seed)  # before any random OMPL object of this query exists (module docstring)

    nq = len(start)
    space = ob.RealVectorStateSpace(nq)
    bounds = ob.RealVectorBounds(nq)
    lower, upper = checker.robot.lower, checker.robot.upper
    for i in range(nq):
        bounds.setLow(i, float(lower[i]))
        bounds.setHigh(i, float(upper[i]))
    space.setBounds(bounds)
    # Motion validation: states at most `resolution` apart (Euclidean); OMPL takes a fraction of the extent.
    space.setLongestValidSegmentFraction(c.resolution / space.getMaximumExtent())

    in_collision = checker.in_collision
    index = range(nq)

    def is_valid(state: Any) -> bool:
        # a fresh array per call: PRM calls this from two threads
        return not in_collision(np.array([state[i] for i in index]))

    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(is_valid)
    si = ss.getSpaceInformation()
    s = space.allocState()
    for i in index:
        s[i] = float(start[i])
    if len(goals) == 1:
        g = space.allocState()
        for i in index:
            g[i] = float(goals[0][i])
        ss.setStartAndGoalStates(s, g)
    else:
        ss.setStartState(s)
        goal = ob.GoalStates(si)
        for q in goals:
            g = space.allocState()
            for i in index:
                g[i] = float(q[i])
            goal.addState(g)
        ss.setGoal(goal)
    objective = ob.PathLengthOptimizationObjective(si)
    if not c.optimize:
        # any exact solution satisfies it: stop at the first (not inf: AORRTC breaks on an infinite bound)
        objective.setCostThreshold(ob.Cost(sys.float_info.max))
    ss.setOptimizationObjective(objective)
    planner = getattr(og, planner_name)(si)
    for key, value in c.params.items():
        getattr(planner, _setter(key))(value)
    ss.setPlanner(planner)
    ss.setup()

    times: dict[str, float] = {}
    remaining = deadline - time.perf_counter()
    if remaining <= 0:
        return None, "Timeout", times
    t0 = time.perf_counter()
    status = ss.solve(remaining)
    times["solve_time"] = time.perf_counter() - t0
    text = status.asString()
    if text != "Exact solution" or not ss.haveExactSolutionPath():
        return None, text, times
    times["simplify_time"] = 0.0
    if c.simplify:
        remaining = deadline - time.perf_counter()
        if remaining > 0:
            t1 = time.perf_counter()
            ss.simplifySolution(remaining)
            times["simplify_time"] = time.perf_counter() - t1
    solution = ss.getSolutionPath()
    path = np.array([[solution.getState(k)[i] for i in index] for k in range(solution.getStateCount())])
    return path, text, times
