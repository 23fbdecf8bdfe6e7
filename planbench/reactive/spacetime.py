"""An omniscient space-time planner: finds a scenario's solvability certificate knowing every motion.

Path-velocity decomposition (Kant & Zucker, 1986): a geometric path from the start to the goal is
planned in the static scene, then a timing along it is searched against the moving obstacles.

1. **Paths.** The registered static planner (``planner``, RRT-Connect: OMPL's simplifier shortcuts
   its path) plans in the static scene, with a new seed for each path; every other path avoids
   where the moving obstacles will be: they are added as static obstacles at their poses every
   ``sweep_interval`` seconds of a time window (their swept volume; the copies that touch the start
   or the goal configuration left out, since the timing can wait for those).
2. **Timing.** The path is resampled so that one step of ``step`` seconds at ``speed_scale`` of
   the velocity limits covers ``increments`` points. A* over (time step, path point), one step per
   move, forward, waiting or back by at most ``increments`` points (each move within the velocity
   limits), cost the arrival time, heuristic the steps left at full speed; each move's straight
   joint segment is certified against the moving geometry over its step
   (:meth:`TickChecker.check_tick`, lazily: when A* pops it; results cached).
3. **Proof.** The moves become the knots of a :class:`Certificate`, numbers rounded as written,
   its control ticks certified one by one; a step whose fine ticks fail is forbidden and the timing
   searched again. The certificate returned has passed
   :func:`~planbench.reactive.solvability.verify_certificate`, the judge of a controller's run:
   nothing the search assumed is trusted.

Paths are tried until one gives a certificate or the ``budget`` is spent. A scenario whose start
is in collision at t = 0, or whose goal configuration is in the static scene's collision, is
refused at once (no search can help).
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.planner import PlanStatus
from planbench.problem import Problem
from planbench.reactive.certificate import ANGLE_DECIMALS, TIME_DECIMALS, Certificate
from planbench.reactive.checker import TickChecker
from planbench.reactive.runner import RunMetrics
from planbench.reactive.scenario import Scenario
from planbench.reactive.solvability import certificate_record, verify_certificate
from planbench.scene import Obstacle, Scene

__all__ = ["CertificateSearch", "SpaceTimeSettings", "find_certificate"]

PLANNER_NAME = "spacetime"


@dataclass(frozen=True)
class SpaceTimeSettings:
    """Settings of the space-time search (module docstring)."""

    budget: float = 60.0
    """Wall-clock time of the whole search [s]: paths are tried until it is spent."""
    step: float = 0.1
    """Time step of the timing search [s], rounded to whole control periods (at least one)."""
    increments: int = 3
    """Path points covered by one step at full speed: a move goes at most this many forward or back."""
    speed_scale: float = 0.95
    """Fraction of each joint's velocity limit the arm moves at, at most (0, 1]."""
    planner: str = "ompl-rrtconnect"
    """The registered static planner of the geometric paths."""
    plan_time: float = 1.0
    """Time limit of one geometric plan [s]."""
    sweep_interval: float = 0.2
    """Time between the copies of a moving obstacle in a path that avoids its swept volume [s]."""
    improve: int = 3
    """Further paths timed when the first certificate waits (holds the arm still longer than
    ``patience``), each bounded to arrive sooner; the one that arrives first is kept: a path
    around the obstacles may beat waiting for them to go."""
    patience: float = 0.5
    """Total time [s] a certificate may hold the arm still before other paths are tried."""
    improve_time: float = 10.0
    """Wall-clock time [s] after the first certificate that further paths may take, at most."""
    repairs: int = 5
    """Times the timing of one path is searched again after its control ticks failed a step."""
    seed: int = 0
    """Seed of the first geometric plan; each further path takes the next."""

    def __post_init__(self) -> None:
        for name in ("budget", "step", "plan_time", "sweep_interval", "patience", "improve_time"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be a finite number > 0 [s], got {v!r}")
        if not 0 < self.speed_scale <= 1:
            raise InvalidConfigError(f"speed_scale must be in (0, 1], got {self.speed_scale!r}")
        if int(self.increments) < 1 or int(self.repairs) < 0 or int(self.improve) < 0:
            raise InvalidConfigError("increments must be >= 1, repairs and improve >= 0")


@dataclass(frozen=True)
class CertificateSearch:
    """What a search found: a ``certificate`` that passed verification (its ``metrics``), or None
    and ``reason``. ``paths``: geometric paths planned; ``elapsed`` [s]."""

    certificate: Certificate | None
    metrics: RunMetrics | None
    reason: str
    paths: int
    elapsed: float


def find_certificate(scenario: Scenario, settings: SpaceTimeSettings | None = None) -> CertificateSearch:
    """Search a certificate for ``scenario`` within ``settings.budget`` (module docstring)."""
    s = settings or SpaceTimeSettings()
    t0 = time.perf_counter()
    deadline = t0 + s.budget
    problem = scenario.problem
    checker = TickChecker(scenario)
    start = np.asarray(problem.start, dtype=float)

    def done(cert: Certificate | None, metrics: RunMetrics | None, reason: str, paths: int) -> CertificateSearch:
        return CertificateSearch(cert, metrics, reason, paths, time.perf_counter() - t0)

    if checker.clearance(start, 0.0) <= 0:
        return done(None, None, "the arm is in collision at its start at t = 0 s", 0)
    from planbench.registry import REGISTRY  # the plugins' registry, on use

    planner = REGISTRY.make(s.planner)
    windows = _windows(scenario)
    reason, paths = "no geometric path found", 0
    best: tuple[Certificate, RunMetrics] | None = None
    tries, first = 0, 0.0  # attempts since the first certificate, and when it came
    for attempt in range(1_000_000):
        if best is not None:  # improving: within improve_time of the first certificate
            deadline = min(deadline, first + s.improve_time)
        left = deadline - time.perf_counter()
        if left <= 0 or (best is not None and tries >= 2 * s.improve):
            break
        tries += best is not None
        window = windows[(attempt // 2) % len(windows)] if attempt % 2 and windows else None
        plan_problem = problem if window is None else _avoiding(scenario, window, s.sweep_interval)
        planner.setup(plan_problem)
        rng = np.random.default_rng(s.seed + attempt)
        result = planner.plan(plan_problem, time_limit=min(s.plan_time, left), rng=rng)
        if result.status is not PlanStatus.SUCCESS or result.path is None or len(result.path) < 1:
            if window is None and result.status in (PlanStatus.INVALID_START, PlanStatus.INVALID_GOAL):
                return done(None, None, f"{s.planner}: {result.message or result.status.value} (static scene)", paths)
            continue
        paths += 1
        sooner = scenario.horizon if best is None else best[0].time_to_goal
        found = _timed(scenario, checker, np.asarray(result.path, dtype=float), s, deadline, t0, sooner)
        if isinstance(found, str):
            reason = found
            continue
        if best is None:
            first = time.perf_counter()
        best = found
        if s.improve == 0 or _still(found[0]) <= s.patience:
            break
    if best is not None:
        return done(*best, "", paths)
    return done(None, None, f"none found within the budget of {s.budget:g} s ({reason}; {paths} paths timed)", paths)


def _still(cert: Certificate) -> float:
    """How long [s] the certificate holds the arm still (between equal knots)."""
    same = np.all(cert.path[1:] == cert.path[:-1], axis=1)
    return float(np.sum(np.diff(cert.times)[same]))


# --- paths ----------------------------------------------------------------------------------
def _windows(scenario: Scenario) -> list[tuple[float, float]]:
    """Time windows whose swept volume a path may avoid: the whole horizon, then shorter starts."""
    if not scenario.moving:
        return []
    H = scenario.horizon
    return [(0.0, H), (0.0, min(H, 3.0)), (0.0, min(H, 1.5))]


def _avoiding(scenario: Scenario, window: tuple[float, float], interval: float) -> Problem:
    """The scenario's problem with the moving obstacles added at their poses every ``interval``
    [s] of ``window``, but for the copies touching the start or the goal configuration."""
    problem = scenario.problem
    robot = problem.robot
    reach = robot.reach() + 0.5
    copies = []
    for m in scenario.moving:
        for i, t in enumerate(np.arange(window[0], window[1] + 1e-9, interval)):
            if not m.present(float(t)):
                continue
            o = m.at(float(t))
            if np.linalg.norm(np.asarray(o.position)) > reach + float(np.linalg.norm(o.local_half_extents())):
                continue
            copies.append(replace(o, name=f"{o.name}@{i}"))
    if not copies:
        return problem
    touching: set[str] = set()
    near = CollisionChecker(robot, Scene(tuple(copies)))
    for q in (problem.start, problem.goal.q):
        if q is not None:
            touching |= {b.removeprefix("obstacle:") for _, b in near.collisions(np.asarray(q, dtype=float))}
    kept: tuple[Obstacle, ...] = tuple(o for o in copies if o.name not in touching)
    scene = Scene(tuple(problem.scene.obstacles) + kept, problem.scene.name)
    return Problem.create(
        robot, scene, problem.start, goal_q=problem.goal.q, goal_pose=problem.goal.pose, tolerances=problem.tolerances
    )


# --- timing ---------------------------------------------------------------------------------
def _resample(path: np.ndarray, vmax: np.ndarray, spacing: float, lower: Any, upper: Any) -> np.ndarray:
    """Points along ``path`` at most ``spacing`` [s] apart at speed ``vmax`` (every joint within
    its share), rounded as a certificate is written (the first point, the start, whole). The
    path's vertices are among them: a move may cut a corner where that is certified free, and can
    always stop at the vertex (in a bookshelf every cut was refused)."""
    keep = np.concatenate([[True], np.abs(np.diff(path, axis=0)).max(axis=1) > 0])
    path = path[keep]
    pieces = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        n = max(1, math.ceil(float(np.max(np.abs(b - a) / vmax)) / spacing))
        pieces.append(a + np.outer(np.arange(1, n + 1) / n, b - a))
    rounded = np.clip(np.round(np.concatenate(pieces), ANGLE_DECIMALS), lower, upper)
    rounded[0] = path[0]
    return rounded


def _timed(
    scenario: Scenario,
    checker: TickChecker,
    path: np.ndarray,
    s: SpaceTimeSettings,
    deadline: float,
    t0: float,
    sooner: float,
) -> tuple[Certificate, RunMetrics] | str:
    """A verified certificate along ``path`` arriving in fewer steps than ``sooner`` [s] takes
    (the horizon: any), or why there is none."""
    robot = scenario.problem.robot
    T = scenario.period
    m = max(1, round(s.step / T))
    dt = m * T
    R = int(s.increments)
    vmax = np.asarray(robot.velocity_limit, dtype=float) * s.speed_scale
    points = _resample(path, vmax, dt / R, robot.lower, robot.upper)
    steps = math.floor(scenario.horizon / dt + 1e-9)
    if sooner < scenario.horizon:
        steps = min(steps, math.ceil(sooner / dt - 1e-9) - 1)
    cache: dict[tuple[int, int, int], bool] = {}
    for _ in range(s.repairs + 1):
        moves = _astar(checker, points, steps, dt, R, cache, deadline)
        if moves is None:
            return "no timing along a path reaches the goal within the horizon"
        if isinstance(moves, str):
            return moves
        cert = _knots(moves, points, dt, t0)
        record = certificate_record(scenario, cert)
        cert = replace(cert, time_to_goal=round(float(record.times[-1]), TIME_DECIMALS))
        k = _first_bad_step(checker, record.times, record.path, m)
        if k is None:
            metrics = verify_certificate(scenario, cert)
            if not metrics.success:  # never seen: the ticks were certified just above
                return f"verification refused the timing: {metrics.failure}"
            return cert, metrics
        cache[(k, moves[k], moves[k + 1])] = False
    return "the control ticks failed every timing found"


def _astar(
    checker: TickChecker,
    points: np.ndarray,
    steps: int,
    dt: float,
    R: int,
    cache: dict[tuple[int, int, int], bool],
    deadline: float,
) -> list[int] | str | None:
    """The path point at each step, from the start to the last point, arriving first; None when
    no timing reaches it within ``steps`` steps."""
    N = len(points) - 1
    if N == 0:
        return [0]
    heap: list[tuple[int, int, int, int, int]] = [(_h(0, N, R), -0, 0, 0, -1)]  # f, -point, step, point, parent
    parent: dict[tuple[int, int], int] = {}
    clear: dict[tuple[float, bytes], bool] = {}
    pops = 0
    while heap:
        _, _, k, n, p = heapq.heappop(heap)
        if (k, n) in parent:
            continue
        if p >= 0:
            key = (k - 1, p, n)
            free = cache.get(key)
            if free is None:
                pops += 1
                if pops % 64 == 0 and time.perf_counter() > deadline:
                    return "the budget ran out while timing a path"
                free = cache[key] = _free(checker, points[p], points[n], (k - 1) * dt, k * dt, clear)
            if not free:
                continue
        parent[(k, n)] = p
        if n == N:
            moves = [n]
            while k > 0:
                n = parent[(k, n)]
                k -= 1
                moves.append(n)
            return moves[::-1]
        if k >= steps:
            continue
        for n2 in range(max(0, n - R), min(N, n + R) + 1):
            if (k + 1, n2) not in parent and cache.get((k, n, n2)) is not False:
                heapq.heappush(heap, (k + 1 + _h(n2, N, R), -n2, k + 1, n2, n))
    return None


def _free(
    checker: TickChecker, q0: np.ndarray, q1: np.ndarray, t0: float, t1: float, clear: dict[tuple[float, bytes], bool]
) -> bool:
    """Whether the move ``q0 -> q1`` during ``[t0, t1]`` is certified free. Its end and its middle
    are tested first (exact distances at those times, remembered): a move through an obstacle is
    refused for two distance queries instead of the certified check's bisection."""
    for q, t in ((q1, t1), (0.5 * (q0 + q1), 0.5 * (t0 + t1))):
        key = (t, q.tobytes())
        if key not in clear:
            clear[key] = checker.clearance(q, t) > 0
        if not clear[key]:
            return False
    return checker.check_tick(q0, q1, t0, t1).free


def _h(n: int, N: int, R: int) -> int:
    return -(-(N - n) // R)


def _knots(moves: list[int], points: np.ndarray, dt: float, t0: float) -> Certificate:
    """The certificate of the point at each step, the knots inside a wait dropped (the same
    configurations at every tick)."""
    keep = [i for i in range(len(moves)) if i in (0, len(moves) - 1) or not moves[i - 1] == moves[i] == moves[i + 1]]
    times = np.round(np.asarray(keep, dtype=float) * dt, TIME_DECIMALS)
    q = points[[moves[i] for i in keep]]
    return Certificate(times, q, float(times[-1]), PLANNER_NAME, math.nan, time.perf_counter() - t0)


def _first_bad_step(checker: TickChecker, times: np.ndarray, path: np.ndarray, m: int) -> int | None:
    """The search step (of ``m`` ticks) holding the first control tick not certified free."""
    for k in range(len(path) - 1):
        if not checker.check_tick(path[k], path[k + 1], times[k], times[k + 1]).free:
            return k // m
    return None
