"""OMPL geometric planners on planbench problems, with coal collision checking.

One class, :class:`OMPLPlanner`, runs any OMPL geometric planner by its OMPL class name (``planner=
"AORRTC"``); the named baselines (``ompl-rrtconnect`` ...) are subclasses that fix the planner.

How a query runs (all inside ``plan()``, so all of it is timed by the harness):

1. The goal: the problem's goal configuration when it has one (``target="configuration"``); for a
   pose-only goal, or a goal configuration outside the robot's joint limits (the goal pose is still a
   valid target), goal configurations from the IK sampler in :mod:`.ik` (``target="pose"``; a goal
   configuration outside the limits, clipped to them, is the sampler's first initial guess).
2. OMPL's random generator is reseeded from the ``rng`` handed in (see *Seeding* below), then a fresh
   state space (the joint limits as bounds), ``SimpleSetup``, planner and problem are built.
3. ``solve`` runs for what is left of the time limit. Only an exact solution counts. The limit
   counts elapsed time (``clock = "wall"``) or this process's CPU time (``"cpu"``: what the closed
   loop charges a controller, so a controller's plan does as much work on a loaded machine).
4. The path is simplified (``simplify=True``, OMPL's ``PathSimplifier`` via ``simplifySolution``)
   for at most what is left of the time limit; its time is reported apart in ``info``.
5. The path is certified as the harness certifies it (``verify=True``,
   :class:`planbench.checking.certified.CertifiedChecker`, its verdict only: every segment proven free, no
   sampling). OMPL's search and simplifier check motions at sampled points, and the simplifier's
   shortcuts can graze an obstacle between them (seen on MotionBenchMaker: up to 0.2 mm deep). A
   segment that fails is *repaired*: replaced by a detour through one random waypoint near its first
   collision (normal steps of 0.02 to 0.2 rad, 3 tries each), else by a short RRT-Connect sub-query
   between its ends (at most ``SUBSOLVE_TIME``), both with certified motion checks; a waypoint that is
   not provably free itself is replaced with it. The segments before the failing one are certified
   already, the path is re-checked from the repair on; at most ``repair_attempts`` (5) repairs a
   query (``info["repaired_segments"]``). If the simplified path cannot be certified so, the raw path
   with only OMPL's ``reduceVertices`` is tried, then the raw path itself (``info["path_source"]``:
   ``simplified``, ``reduced`` or ``raw``). Only if all fail: ``COLLISION``. The certified checker is
   built in ``setup`` (untimed, like the collision checker).

   Measured (``python benchmarks/ompl_certified.py --problems 'mbm:*/0001-0020' --before ea38f5d``,
   ompl-rrtconnect, seed 0, 5 s, one fresh process per run, interleaved, 2 busy cores): as before
   (fall back to the reduced/raw path, checker built in ``plan``) 137/140 certified successes
   (110 simplified, 25 reduced, 2 raw, 3 none), median planning time 208 ms; with the checker built
   in ``setup`` but no repair, the same paths at 160 ms; with repair 140/140, all simplified (33
   segments repaired on 30 problems), 159 ms. Certified motion checks cost more than they save
   (``*/0001-0005``, 35 problems): in the simplifier only (``simplify_check="certified"``) 35/35 at
   666 ms, in the search too (``motion_check="certified"``) 34/35 at 775 ms (one time-out), against
   248 ms for the repair's first version there; so both stay ``"sampled"`` by default.

Collision checking: a plain Python function is OMPL's state validity checker; it calls
:meth:`planbench.checking.collision.CollisionChecker.in_collision` (coal, robot against the scene's
primitives plus self-collision with the robot's ignore list, through a broadphase) or, with
``collision="grid"``, the same checker against the voxelized scene (:mod:`.grid`). States are
sampled within the joint limits, so the checker does not test limits.

Motion validation (:mod:`.motion`): with ``motion_check="sampled"`` (search) and
``simplify_check="sampled"`` (simplifier), the defaults, a segment ``a -> b`` is checked at the
configurations ``a + (j / n)(b - a)`` with ``n = ceil(max_i |b_i - a_i| / resolution)``: no joint
moves more than ``resolution`` [rad] (default 0.01) between checked configurations, in one pinocchio
batch per motion. With ``"certified"``, a motion that passes the sampled check is then certified
(each certified segment is remembered, and not checked again in step 5).

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

Progress of anytime planners: for an OMPL planner that reports a best cost (``bestCost()`` in the
Python bindings: ``RRTstar``, ``InformedRRTstar``, ``BITstar``, ``AORRTC`` ...), the search records
OMPL's progress properties ``best cost`` (path length [rad] of the best solution so far; None before
the first) and, where the bindings have ``numIterations()``, ``iterations``, every
``progress_interval`` [s] (default 0.05 s, the ``timeBetweenUpdates`` of OMPL's
``ompl::tools::Benchmark``), into ``info["progress"]`` (``time`` [s] since ``plan`` began, one list
per property), plus one sample when the search ends. OMPL's own way, its planner's
``getPlannerProgressProperties()`` read from a second thread, has no Python binding in OMPL 2.x, so
the sampling is a planner termination condition, evaluated by the planner itself once per iteration
(in its own thread: nothing is read while the planner writes it); a sample is taken at the first
iteration after each multiple of the interval. ``PRMstar`` reports no best cost in the bindings and
records none. Measured (``python benchmarks/ompl_progress.py``: RRT*, ``optimize``, 1 s on each of
``mbm:*/0001``, 3 repeats, 2 busy cores): 249 iterations/s recording against 273 not, a median
ratio of 0.994 per pair of runs, within the noise; 19 to 21 samples a run.

OMPL's own log output goes to the terminal from C++; ``log_level`` sets OMPL's process-wide level
before each query (default ``"none"``: nothing). All OMPL objects are freed at the end of each query,
so nanobind has no leaked objects to report at interpreter exit.
"""

from __future__ import annotations

import math
import re
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError, UnknownNameError
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem
from planbench.validate import verdict_checker

from .grid import grid_checker, grid_for_scene
from .ik import sample_goal_configurations
from .motion import CertifiedSegments, SegmentChecker, make_motion_validator

__all__ = ["OMPLConfig", "OMPLAnyConfig", "OMPLPlanner", "geometric_planners", "planner_parameters"]

COLLISION_MODES = ("primitives", "grid")
CLOCKS: dict[str, Callable[[], float]] = {"wall": time.perf_counter, "cpu": time.process_time}
"""What a time limit counts (``OMPLConfig.clock``): elapsed time, or this process's CPU time."""
LOG_LEVELS = ("none", "error", "warn", "info", "debug")
MOTION_CHECKS = ("sampled", "certified")
DETOUR_RADII = (0.02, 0.05, 0.1, 0.2)  # [rad] standard deviations of a repair's random waypoint
DETOUR_TRIES = 3  # random waypoints per radius
SUBSOLVE_TIME = 1.0  # [s] at most for one repair's RRT-Connect sub-query


@dataclass(frozen=True)
class OMPLConfig:
    """Settings of the OMPL planners (``ompl-rrtconnect`` etc.)."""

    params: Mapping[str, Any] = field(default_factory=dict)
    """The OMPL planner's own parameters by OMPL's names, e.g. ``{"range": 1.0}`` or
    ``{"goal_bias": 0.1, "rewire_factor": 1.1}``; each calls the planner's setter (``setRange``,
    ``setGoalBias`` ...). They are applied over the planner's planbench defaults (``ompl-rrtconnect``:
    ``{"range": 0.5}``; ``{"range": 0}`` gives OMPL's own choice back); others keep OMPL's defaults."""
    collision: str = "primitives"
    """``"primitives"``: the scene's exact obstacles; ``"grid"``: its occupancy grid (see ``grid_*``)."""
    grid_resolution: float = 0.02
    """Cell size of the occupancy grid in ``collision="grid"`` mode [m]."""
    grid_geometry: str = "octree"
    """How the grid's occupied cells are given to coal: ``"octree"`` or ``"boxes"``."""
    resolution: float = 0.01
    """Motion validation: largest joint motion between checked configurations [rad]; at the
    harness's 0.01 the check points are exactly the harness's (see :mod:`.motion`)."""
    simplify: bool = True
    """Shortcut and smooth the path with OMPL's PathSimplifier (time reported in ``info``)."""
    optimize: bool = False
    """Asymptotically optimal planners: keep improving until the time limit (not reproducible)
    instead of stopping at the first exact solution."""
    verify: bool = True
    """Certify the returned path as the harness does; a segment that fails is repaired (see
    ``repair_attempts``); if the simplified path cannot be, fall back to the raw path (vertices
    reduced, then as found); ``COLLISION`` if all fail."""
    motion_check: str = "sampled"
    """How the search checks motions: ``"sampled"`` (at the check points of ``resolution``) or
    ``"certified"`` (the sampled check, then the harness's certified check of each motion that
    passes it)."""
    simplify_check: str = "sampled"
    """How the simplifier checks motions: ``"sampled"`` or ``"certified"`` (as ``motion_check``)."""
    repair_attempts: int = 5
    """Segments of the returned path that fail certification and are re-planned (a short certified
    RRT-Connect sub-query between their ends); 0: no repair."""
    ik_goals: int = 4
    """Pose-only goals: how many goal configurations to sample with IK."""
    ik_time_fraction: float = 0.2
    """Pose-only goals: share of the time limit the IK sampler may use [-]."""
    log_level: str = "none"
    """OMPL's own log output (process-wide): none, error, warn, info or debug."""
    clock: str = "wall"
    """What the time limit counts: ``"wall"``, elapsed time (OMPL's and the benchmark's convention);
    ``"cpu"``, this process's CPU time (:data:`CLOCKS`), which is what the closed loop charges a
    controller, so that a controller's plan gets the same compute on a loaded machine as on an idle
    one (``ompl-replan``'s ``plan_clock``)."""
    progress_interval: float = 0.05
    """Anytime planners (those reporting a best cost): record OMPL's progress properties (best cost,
    iterations) every ``progress_interval`` [s] of the search into ``info["progress"]`` (see the
    module docstring); 0: none recorded."""

    def __post_init__(self) -> None:
        if self.collision not in COLLISION_MODES:
            raise InvalidConfigError(f"collision must be one of {COLLISION_MODES}, got {self.collision!r}")
        if self.grid_geometry not in ("octree", "boxes"):
            raise InvalidConfigError(f"grid_geometry must be 'octree' or 'boxes', got {self.grid_geometry!r}")
        if self.clock not in CLOCKS:
            raise InvalidConfigError(
                f"clock must be one of {tuple(CLOCKS)} (what the time limit counts), got {self.clock!r}"
            )
        if self.log_level not in LOG_LEVELS:
            raise InvalidConfigError(f"log_level must be one of {LOG_LEVELS}, got {self.log_level!r}")
        for name in ("grid_resolution", "resolution"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be > 0, got {v!r}")
        for name in ("motion_check", "simplify_check"):
            if getattr(self, name) not in MOTION_CHECKS:
                raise InvalidConfigError(f"{name} must be one of {MOTION_CHECKS}, got {getattr(self, name)!r}")
        if not (isinstance(self.repair_attempts, int) and self.repair_attempts >= 0):
            raise InvalidConfigError(f"repair_attempts must be an integer >= 0, got {self.repair_attempts!r}")
        if not (isinstance(self.ik_goals, int) and self.ik_goals >= 1):
            raise InvalidConfigError(f"ik_goals must be an integer >= 1, got {self.ik_goals!r}")
        v = self.progress_interval
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InvalidConfigError(f"progress_interval must be a number >= 0 [s], got {v!r}")
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

    return sorted(n for n in dir(og) if isinstance(getattr(og, n), type) and issubclass(getattr(og, n), ob.Planner))


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def _setter(param: str) -> str:
    return "set" + "".join(part[:1].upper() + part[1:] for part in param.split("_"))


def planner_parameters(planner: str) -> list[str]:
    """Parameter names (OMPL's, snake_case) that ``params`` accepts for an OMPL planner class."""

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
    Config: ClassVar[Any] = OMPLAnyConfig
    fresh_process: ClassVar[bool] = True
    """Benchmarks run every query of an OMPL planner in a new worker process: OMPL's state (its
    random generator, its log) is process-wide. The query reseeds it as well, so library calls in
    one process are reproducible too."""
    ompl_planner: ClassVar[str | None] = None  # fixed by the named subclasses
    default_params: ClassVar[Mapping[str, Any]] = {}  # planbench's defaults for the planner's own parameters

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
        # every parameter the query sets, planbench's defaults included (what a benchmark stores)
        self.config = replace(self.config, params={**self.default_params, **self.config.params})
        self._checker: CollisionChecker | None = None
        self._checker_key: tuple[Any, ...] | None = None
        self._checker_problem: Problem | None = None
        self._segments: dict[float, SegmentChecker] = {}

    @property
    def planner_name(self) -> str:
        return self.ompl_planner or self.config.planner

    # --- setup (untimed): the collision checker ----------------------------------------------
    def setup(self, problem: Problem) -> None:
        """Build the collision checker (and in grid mode, voxelize the scene) and the certified one."""
        self._checker_for(problem)
        verdict_checker(problem)  # built here, untimed; cached on the problem

    def use_checker(self, problem: Problem, checker: CollisionChecker) -> None:
        """Plan ``problem`` against ``checker`` instead of a checker built from its scene (the
        caller's: an observed grid's cells as one octree, say, which costs milliseconds where the
        same cells as hundreds of boxes cost a second); in place of :meth:`setup`. The returned path
        is still certified (``verify``) against ``problem.scene``."""
        self._checker = checker
        self._checker_problem = problem
        self._checker_key = (self.config.collision, self.config.grid_resolution, self.config.grid_geometry)
        self._segments = {}

    def _checker_for(self, problem: Problem) -> CollisionChecker:
        c = self.config
        key = (c.collision, c.grid_resolution, c.grid_geometry)
        # the problem itself, not its id(): a freed problem's id can be reused by the next one
        if self._checker is None or self._checker_problem is not problem or self._checker_key != key:
            if c.collision == "primitives":
                self._checker = CollisionChecker.for_problem(problem)
            else:
                grid = grid_for_scene(problem.scene, c.grid_resolution, padding=c.grid_resolution)
                self._checker = grid_checker(problem.robot, grid, c.grid_geometry)
            self._segments = {}
            self._checker_key = key
            self._checker_problem = problem
        return self._checker

    def _segments_for(self, checker: CollisionChecker, resolution: float) -> SegmentChecker:
        segments = self._segments.get(resolution)
        if segments is None:
            segments = self._segments[resolution] = SegmentChecker(checker, resolution)
        return segments

    # --- plan (timed) ------------------------------------------------------------------------
    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        c = self.config
        now = CLOCKS[c.clock]
        t_start = now()
        deadline = t_start + time_limit
        robot = problem.robot
        checker = self._checker_for(problem)
        motions = self._segments_for(checker, c.resolution)
        certified = CertifiedSegments(motions, verdict_checker(problem))
        counted: list[Any] = [checker, motions]
        checks_before = sum(x.n_checks for x in counted)
        params = {**self.default_params, **c.params}
        info: dict[str, Any] = {
            "ompl_planner": self.planner_name,
            "collision": c.collision,
            "ompl_params": params,
            "clock": c.clock,
        }

        def result(status: PlanStatus, path: Any = None, message: str = "") -> PlanResult:
            info["collision_checks"] = sum(x.n_checks for x in counted) - checks_before
            return PlanResult(status, path, None, target, message, info)

        target = "configuration"
        if checker.in_collision(problem.start):  # before the IK sampler spends its share of the budget
            return result(PlanStatus.INVALID_START, message=f"start in collision ({c.collision} mode)")

        # 1. goal configurations
        seeds: list[np.ndarray] = []
        if problem.goal.q is not None:
            goal_q = np.array(problem.goal.q)
            bad = robot.limit_violations(goal_q)
            if bad:
                # the goal pose stays a valid target: plan to IK configurations of it instead
                info["goal_outside_limits"] = "; ".join(bad)
                seeds = [np.clip(goal_q, robot.lower, robot.upper)]
                target = "pose"
            elif checker.in_collision(goal_q):
                return result(PlanStatus.INVALID_GOAL, message=f"goal configuration in collision ({c.collision} mode)")
        else:
            target = "pose"
        if target == "configuration":
            goals = [goal_q]
        else:
            t_ik = time.perf_counter()
            goals = sample_goal_configurations(
                problem,
                checker.in_collision,
                rng,
                c.ik_goals,
                c.ik_time_fraction * time_limit,
                seeds=seeds,
                clock=now,
            )
            info["ik_time"] = time.perf_counter() - t_ik
            info["ik_goals"] = len(goals)
            if not goals:
                return result(
                    PlanStatus.INVALID_GOAL, message="the IK sampler found no collision-free goal configuration"
                )

        def finish(path: np.ndarray) -> np.ndarray:
            path[0] = problem.start
            if target == "configuration" and np.abs(path[-1] - goals[0]).max() < 1e-9:
                path[-1] = goals[0]
            return path

        seed = int(rng.integers(1, 2**31 - 1))
        info["ompl_seed"] = seed
        path, status_text, extra = _solve(
            self.planner_name,
            c,
            params,
            problem.start,
            goals,
            checker,
            motions,
            certified,
            seed,
            (t_start, deadline),
            finish,
            now,
        )
        info.update(extra)
        info["ompl_status"] = status_text
        info["certified_checks"] = certified.n_certified
        info["verify_time"] = certified.time
        info["verify_distance_queries"] = certified.queries
        if path is None:
            status, message = _STATUS_MESSAGES.get(status_text, (PlanStatus.TIMEOUT, f"OMPL: {status_text}"))
            if status is PlanStatus.INVALID_GOAL:
                # every goal handed to OMPL was checked valid above: the planner's own reason is in its log
                message += (
                    f" although its {len(goals)} goal configuration(s) are collision-free and within the limits"
                    " (AORRTC does this when start and goal connect directly); log_level='error' shows OMPL's reason"
                )
            return result(status, message=message)
        path = finish(path)
        if info.get("path_source") == "none":
            return result(
                PlanStatus.COLLISION,
                path,
                "OMPL's path (simplified, reduced and raw) is not certified collision-free by the harness's checker",
            )
        return result(PlanStatus.SUCCESS, path)


def _parameter_values(planner: Any, planner_name: str) -> dict[str, Any]:
    """Every parameter of the OMPL planner as it planned (its getters: OMPL's defaults and the
    values its ``setup`` chose included, e.g. ``range``), by the names ``params`` takes."""
    out: dict[str, Any] = {}
    for name in planner_parameters(planner_name):
        getter = getattr(planner, "get" + _setter(name)[3:], None)
        if getter is None:
            continue
        try:
            value = getter()
        except Exception:  # a getter that needs arguments, or refuses before setup: not a setting
            continue
        if isinstance(value, (bool, int, float, str)):
            out[name] = value
    return out


class Progress:
    """OMPL's progress properties of an anytime planner (``best cost``, ``iterations``), sampled
    every ``interval`` [s]: a planner termination condition's function that never stops the planner
    (see the module docstring). ``t0``: the ``perf_counter`` time the samples' ``time`` counts from."""

    def __init__(self, planner: Any, t0: float, interval: float) -> None:
        self._best_cost: Callable[[], Any] | None = planner.bestCost
        self._iterations: Callable[[], Any] | None = getattr(planner, "numIterations", None)
        self._has_iterations = self._iterations is not None
        self.t0 = t0
        self.interval = interval
        self.time: list[float] = []
        self.best_cost: list[float | None] = []
        self.iterations: list[int] = []
        self._next = t0

    def __call__(self) -> bool:
        now = time.perf_counter()
        if now >= self._next and self._best_cost is not None:
            self.sample(now)
        return False

    def detach(self) -> None:
        """Forget the planner (no more samples): breaks the cycle planner -> condition -> this -> planner."""
        self._best_cost = self._iterations = None

    def sample(self, now: float) -> None:
        """Record the planner's properties at ``now`` (a ``perf_counter`` time [s])."""
        elapsed = now - self.t0
        if self._best_cost is None or (self.time and elapsed <= self.time[-1]):
            return
        self._next = self.t0 + self.interval * (math.floor(elapsed / self.interval) + 1)
        cost = float(self._best_cost().value())
        self.time.append(elapsed)
        self.best_cost.append(cost if math.isfinite(cost) else None)
        if self._iterations is not None:
            self.iterations.append(int(self._iterations()))

    def as_info(self) -> dict[str, Any]:
        """The samples as ``info["progress"]``: ``interval`` [s], then one list per property."""
        out: dict[str, Any] = {"interval": self.interval, "time": self.time, "best cost": self.best_cost}
        if self._has_iterations:
            out["iterations"] = self.iterations
        return out


def _until(deadline: float, now: Callable[[], float]) -> Any:
    """OMPL's termination condition at ``deadline`` [s] on ``now``'s clock: OMPL's own timer for
    elapsed time, else a condition that reads the clock (a Python call each time OMPL asks, about
    a microsecond against a motion check's tens)."""
    if now is time.perf_counter:
        return ob.timedPlannerTerminationCondition(max(deadline - now(), 0.0))
    return ob.PlannerTerminationCondition(lambda: now() >= deadline)


def _solve(
    planner_name: str,
    c: OMPLConfig,
    params: Mapping[str, Any],
    start: np.ndarray,
    goals: list[np.ndarray],
    checker: CollisionChecker,
    motions: SegmentChecker,
    certified: CertifiedSegments,
    seed: int,
    clock: tuple[float, float],
    finish: Callable[[np.ndarray], np.ndarray],
    now: Callable[[], float] = time.perf_counter,
) -> tuple[np.ndarray | None, str, dict[str, Any]]:
    """One OMPL query; every OMPL object is created and freed here. ``clock``: the times [s] on
    ``now``'s clock (:data:`CLOCKS`) when ``plan`` began and its deadline. Returns the first path
    of simplified, reduced, raw that ``accept`` takes (``info["path_source"]``; ``"none"`` and the
    raw path when it takes none)."""
    t_plan, deadline = clock

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
    # What OMPL uses besides the motion validator (e.g. some planners' step sizes): the same resolution.
    space.setLongestValidSegmentFraction(c.resolution / space.getMaximumExtent())

    in_collision = checker.in_collision
    index = range(nq)

    def is_valid(state: Any) -> bool:
        # a fresh array per call: PRM calls this from two threads
        return not in_collision(np.array([state[i] for i in index]))

    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(is_valid)
    si = ss.getSpaceInformation()
    validator = make_motion_validator(si, motions, nq, certified)
    validator.certify = c.motion_check == "certified"
    si.setMotionValidator(validator)
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
    for key, value in params.items():
        getattr(planner, _setter(key))(value)
    ss.setPlanner(planner)
    ss.setup()

    def as_array(path: Any) -> np.ndarray:
        return np.array([[path.getState(k)[i] for i in index] for k in range(path.getStateCount())])

    info: dict[str, Any] = {}
    if deadline - now() <= 0:
        return None, "Timeout", info
    t0 = time.perf_counter()
    if c.progress_interval > 0 and hasattr(planner, "bestCost"):
        origin = t_plan if now is time.perf_counter else t0 - (now() - t_plan)  # the plan's start, elapsed time
        progress = Progress(planner, origin, c.progress_interval)
        stop = ob.plannerOrTerminationCondition(_until(deadline, now), ob.PlannerTerminationCondition(progress))
        try:
            status = ss.solve(stop)
            progress.sample(time.perf_counter())
        finally:
            progress.detach()  # a planner that keeps the condition (AORRTC) would keep itself alive
        info["progress"] = progress.as_info()
    else:
        status = ss.solve(_until(deadline, now))
    info["solve_time"] = time.perf_counter() - t0
    if hasattr(planner, "numIterations"):
        info["iterations"] = int(planner.numIterations())
    info["ompl_parameters"] = _parameter_values(planner, planner_name)
    text = status.asString()
    if text != "Exact solution" or not ss.haveExactSolutionPath():
        return None, text, info
    info["simplify_time"] = 0.0
    info["repaired_segments"] = 0
    raw = og.PathGeometric(ss.getSolutionPath())
    attempts = [c.repair_attempts]

    def state(q: np.ndarray) -> Any:
        st = space.allocState()
        for i in index:
            st[i] = float(q[i])
        return st

    detour_rng = np.random.default_rng(seed)

    def detour(a: np.ndarray, b: np.ndarray, fraction: float) -> np.ndarray | None:
        """``[a, p, b]`` with both segments certified free, ``p`` a random configuration around the
        segment's first collision (``fraction`` along it), tried at growing distances; or None."""
        near = a + fraction * (b - a)
        for radius in DETOUR_RADII:
            for _ in range(DETOUR_TRIES):
                if now() >= deadline:
                    return None
                p = np.clip(near + detour_rng.normal(0.0, radius, size=nq), lower, upper)
                if not in_collision(p) and certified.free(a, p) and certified.free(p, b):
                    return np.stack([a, p, b])
        return None

    def subsolve(a: np.ndarray, b: np.ndarray, fraction: float) -> np.ndarray | None:
        """A path from ``a`` to ``b`` whose every segment is certified free, or None within the time
        left: a detour through one random waypoint near the collision, else RRT-Connect with
        certified motion checks (its path then with vertices reduced, also certified)."""
        if now() >= deadline:
            return None
        piece = detour(a, b, fraction)
        if piece is not None:
            return piece
        if now() >= deadline:
            return None
        sub = og.SimpleSetup(space)
        sub.setStateValidityChecker(is_valid)
        sub_si = sub.getSpaceInformation()
        sub_validator = make_motion_validator(sub_si, motions, nq, certified)
        sub_validator.certify = True
        sub_si.setMotionValidator(sub_validator)
        sub.setStartAndGoalStates(state(a), state(b))
        rrt = og.RRTConnect(sub_si)
        rrt.setRange(float(params.get("range", 0.5)) if planner_name == "RRTConnect" else 0.5)
        sub.setPlanner(rrt)
        sub.setup()
        if (
            sub.solve(_until(min(deadline, now() + SUBSOLVE_TIME), now)).asString() != "Exact solution"
            or not sub.haveExactSolutionPath()
        ):
            return None
        found = og.PathGeometric(sub.getSolutionPath())
        og.PathSimplifier(sub_si).reduceVertices(found)
        return as_array(found)

    def point_free(q: np.ndarray) -> bool:
        return certified.check(q[None, :]).free

    def certify(path: np.ndarray) -> np.ndarray | None:
        """``path`` itself when it certifies, else with its failing segments re-planned by
        ``subsolve`` (at most ``repair_attempts`` in the query), else None."""
        if not c.verify:
            return path
        path = finish(path)
        while True:
            # the whole path, as the harness checks it: segments certified one by one can disagree
            # with the whole-path check on a contact within micrometres (seen on a UR5 scene)
            verdict = certified.check(path)
            if verdict.free:
                return path
            s = verdict.segment
            if s < 0 or attempts[0] <= 0:  # s < 0: the query budget ran out, nothing to repair
                return None
            attempts[0] -= 1
            lo, hi = s, s + 1  # a waypoint that is not provably free itself is replaced too
            while lo > 0 and not point_free(path[lo]):
                lo -= 1
            while hi < len(path) - 1 and not point_free(path[hi]):
                hi += 1
            fraction = verdict.fraction if (lo, hi) == (s, s + 1) and math.isfinite(verdict.fraction) else 0.5
            piece = subsolve(path[lo], path[hi], fraction)
            if piece is None:
                return None
            info["repaired_segments"] += 1
            path = np.vstack([path[:lo], piece, path[hi + 1 :]])

    if c.simplify and now() >= deadline:
        info["simplify_skipped"] = "no time left after the search"
    elif c.simplify:
        t1 = time.perf_counter()
        validator.certify = c.motion_check == "certified" or c.simplify_check == "certified"
        ss.simplifySolution(_until(deadline, now))
        info["simplify_time"] = time.perf_counter() - t1
        path = certify(as_array(ss.getSolutionPath()))
        if path is not None:
            info["path_source"] = "simplified"
            return path, text, info
        t1 = time.perf_counter()
        reduced = og.PathGeometric(raw)
        og.PathSimplifier(si).reduceVertices(reduced)
        info["simplify_time"] += time.perf_counter() - t1
        path = certify(as_array(reduced))
        if path is not None:
            info["path_source"] = "reduced"
            return path, text, info
    path = as_array(raw)
    fixed = certify(path)
    info["path_source"] = "raw" if fixed is not None else "none"
    return (fixed if fixed is not None else path), text, info
