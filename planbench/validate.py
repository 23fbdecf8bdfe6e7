"""Independent validation of a returned path, and the metrics of every run.

A planner's claim of success is never trusted: :func:`evaluate` re-checks the path against the
problem's TRUE geometry (the scene's primitives and the robot's collision meshes with coal, never a
voxel grid) and the robot's limits, and success means every check holds:

- the path is an (N, nq) array of finite values starting at the problem's start;
- validating it needs at most ``max_validation_states`` interpolated configurations, counted from the
  path before any is built (:func:`validation_states`), so a huge path costs no more than counting;
- every waypoint is inside the joint limits (so is every point between them: the limits are a box);
- every segment (linear interpolation in joint space) is *proven* free of collisions with the scene
  and of self-collisions, by :class:`planbench.checking.certified.CertifiedChecker`: distance-based
  conservative advancement, no sampling resolution, every distance at least ``required_clearance``;
- for a trajectory with time stamps, the joint velocities of every segment are within the limits;
- the final end-effector pose is within the position and orientation tolerances of the goal pose,
  and, when the planner says it drove to the goal configuration, the final joint error too;
- the planner itself reported success (``checks["claimed_success"]``): a valid path that comes with
  a failure status (``timeout``, ``step_limit``, ...) is kept and measured but not counted, since a
  caller acts on the planner's status and would discard it. So ``success`` implies ``status ==
  "success"``: a row never says both "solved" and "failed".

The benchmark adds one condition where it timed the plan itself: the answer came within the time
limit (``checks["in_time"]``, :data:`planbench.harness.HANDOFF_TOLERANCE`).

Clearance is measured along the whole path: ``min_clearance`` is the smallest robot-obstacle
distance found, ``min_clearance_bound`` a certified lower bound of it (the true minimum is between
the two, at most ``clearance_gap`` apart unless the refinement's budget ran out).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from planbench import metrics
from planbench.checking.certified import CertificationSettings, CertifiedChecker
from planbench.planner import PlanResult, PlanStatus
from planbench.problem import Problem, pose_error

__all__ = [
    "CLAIMED_SUCCESS",
    "IN_TIME",
    "VALIDATOR",
    "ValidationSettings",
    "Evaluation",
    "evaluate",
    "not_validated",
    "validation_states",
    "verdict_checker",
]

VALIDATOR = "certified/1"
"""What "validated" means, by version: stored with every benchmark's settings, so results judged by
an earlier validator (``sampled`` every 0.01 rad, before this one) are never mixed with these."""

CLAIMED_SUCCESS = "claimed_success"
"""The ``checks`` key that says whether the planner reported success (set with every path)."""
IN_TIME = "in_time"
"""The ``checks`` key the benchmark sets False on an answer that came after the time limit."""


@dataclass(frozen=True)
class ValidationSettings:
    """How paths are checked. Units: m, rad, s."""

    required_clearance: float = 0.0
    """Smallest distance [m] allowed between the robot and an obstacle, or between two of its links,
    anywhere along the path, on top of the certified checker's 1 um tolerance: with 0, touching
    (closer than 1 um) is a collision (:class:`planbench.checking.certified.CertificationSettings`)."""
    clearance_gap: float = 1e-3
    """The certified lower bound of the path's clearance is refined to within this [m] of the
    smallest distance found (a measurement setting; it never changes a verdict)."""
    max_distance_queries: int = 500_000
    """Distance queries one path may take; a path that needs more is refused as not certifiable."""
    clearance_samples: int = 16
    """Configurations, evenly spaced by joint-space length, where ``mean_clearance`` is measured."""
    ee_resolution: float = 0.01
    """Largest joint motion [rad] between configurations where the end-effector path length is
    measured (a metric only; collision checking has no resolution)."""
    start_tolerance: float = 1e-6
    """How far path[0] may be from the problem's start [rad]."""
    limit_tolerance: float = 1e-9
    """Slack on joint position limits [rad] (float round-off at a limit is not a violation)."""
    velocity_tolerance: float = 1e-6
    """Relative slack on velocity limits (|qd| <= vmax * (1 + tol))."""
    max_validation_states: int = 250_000
    """Interpolated configurations [count] validating one path may need, estimated from the path
    before any is built (:func:`validation_states`); a path that needs more is refused. Validation
    time and memory grow with it (the end-effector length, toppra's spline): at the default, about
    10 s and 0.3 GiB. The shipped planners' MotionBenchMaker paths need up to 15,000 (25,000 for a
    field planner stopped at its step limit)."""
    validation_memory_limit: float = 2048.0
    """Address space [MiB] one validation may add to the benchmark's validator process (``RLIMIT_AS``
    at its size when the validation starts plus this); a validation that runs out is refused, the
    failure naming this limit. 0: no limit. Set only in a validator process, never in a caller's."""

    def __post_init__(self) -> None:
        for name in ("required_clearance", "clearance_gap", "ee_resolution", "validation_memory_limit"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v}")
        if not (self.clearance_gap > 0 and self.ee_resolution > 0):
            raise ValueError("clearance_gap [m] and ee_resolution [rad] must be > 0")
        if self.validation_memory_limit < 0:
            raise ValueError("validation_memory_limit [MiB] must be >= 0 (0: no limit)")
        if self.max_distance_queries < 1 or self.clearance_samples < 1 or self.max_validation_states < 1:
            raise ValueError("max_distance_queries, clearance_samples and max_validation_states must be >= 1")

    def certification(self, measure_clearance: bool = True) -> CertificationSettings:
        return CertificationSettings(
            required_clearance=self.required_clearance,
            clearance_gap=self.clearance_gap,
            max_queries=self.max_distance_queries,
            measure_clearance=measure_clearance,
        )


@dataclass(frozen=True)
class Evaluation:
    """Validated outcome and metrics of one run. Lengths [m], angles [rad], times [s].

    ``failure`` names the first check that failed (or the planner's own failure status), with
    details; it is empty on success. Metrics that need a path are NaN without one.
    """

    success: bool
    failure: str
    status: str  # what the planner claimed
    planning_time: float
    setup_time: float
    n_waypoints: int = 0
    joint_path_length: float = math.nan
    ee_path_length: float = math.nan
    min_clearance: float = math.nan  # smallest robot-obstacle distance found along the path [m]
    min_clearance_bound: float = math.nan  # certified lower bound of it [m] (valid paths)
    mean_clearance: float = math.nan  # over ValidationSettings.clearance_samples configurations [m]
    duration: float = math.nan  # at the velocity limits, see metrics.execution_duration
    duration_limited: float = math.nan  # under velocity and acceleration limits (toppra), see metrics.limited_duration
    trajectory_duration: float = math.nan  # the planner's own time stamps, when given
    smoothness: float = math.nan  # total turning angle, see metrics.turning_angle
    final_position_error: float = math.nan
    final_orientation_error: float = math.nan
    final_joint_error: float = math.nan
    max_limit_violation: float = math.nan  # [rad] beyond the position limits (0 when inside)
    max_velocity_ratio: float = math.nan  # max |qd| / vmax over segments, when timed
    collision_checks: int | None = None  # the planner's own count, when it reports info["collision_checks"]
    validation_checks: int = 0  # distance queries this validation made (it stops at the first collision)
    collision_segment: int = -1  # first segment found in collision (-1: none)
    collision_fraction: float = math.nan  # where along it (0: its first waypoint, 1: its last)
    collision_pair: str = ""  # "<robot link> / <link or obstacle:name>"
    penetration_depth: float = math.nan  # [m] deepest found for that pair (0: too close, not provably free)
    checks: dict[str, bool] = field(default_factory=dict)
    # the suite's post-processing stage (planbench.bench.postprocess; NaN / None where it did not run):
    # the validated path shortened on the harness's side, validated again, the same metrics
    processed_n_waypoints: int | None = None
    processed_joint_path_length: float = math.nan  # [rad]
    processed_ee_path_length: float = math.nan  # [m]
    processed_min_clearance: float = math.nan  # [m] smallest robot-obstacle distance found
    processed_duration: float = math.nan  # [s] at the velocity limits, as duration
    processed_duration_limited: float = math.nan  # [s] toppra, as duration_limited
    postprocess_time: float = math.nan  # [s] the shortcutting itself (not the planner's time, not its re-validation)
    postprocess_shortcuts: int | None = None  # shortcuts taken
    postprocess_note: str = ""  # why the stage kept no processed path, or that its time budget cut it short
    # closed-loop runs only (planbench.reactive.runner.RunMetrics; NaN / None for a static plan)
    time_to_goal: float = math.nan  # [s] when the goal tolerance was met
    tick_time_median: float = math.nan  # [s] the controller's compute time per control tick
    tick_time_p99: float = math.nan  # [s]
    deadline_misses: int | None = None  # control ticks on which no new command was ready
    field_update_time: float = math.nan  # [s] median per sensor frame taken in
    stalled_time: float = math.nan  # [s] the arm commanded slower than the stall speed, goal not reached
    path_length: float = math.nan  # [rad] joint-space length of the executed trajectory
    unobserved_motion: float = math.nan  # [s] the arm moving through cells its latest observation did not know
    collision_observed: bool | None = None  # the obstacle hit had been shown to the controller (None: no such hit)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def evaluate(problem: Problem, result: PlanResult, settings: ValidationSettings | None = None) -> Evaluation:
    """Check ``result`` against ``problem`` independently and measure it (see module docstring)."""
    settings = settings or ValidationSettings()
    robot = problem.robot
    status, planning_time, setup_time = result.status.value, float(result.planning_time), float(result.setup_time)

    planner_checks = _reported_checks(result)

    path = result.path
    if path is None or len(path) == 0:
        reason = result.status.value if result.status is not PlanStatus.SUCCESS else "no path returned"
        return not_validated(result, f"{reason}: {result.message}" if result.message else reason)
    if path.shape[1] != robot.nq:
        return not_validated(result, f"path has {path.shape[1]} columns, robot plans {robot.nq} joints")
    if not np.all(np.isfinite(path)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(path), axis=1))[0])
        return not_validated(result, f"path has NaN or infinite values (waypoint {bad})")
    needed = validation_states(path, settings.ee_resolution)
    if needed > settings.max_validation_states:
        return not_validated(
            result,
            f"path needs {needed:.3g} interpolated states to validate ({len(path)} waypoints, about one state "
            f"per {settings.ee_resolution:g} rad of joint motion), above the validation limit of "
            f"{settings.max_validation_states:.3g} (ValidationSettings.max_validation_states): return a path "
            "with less joint motion or fewer waypoints, or raise the limit in the suite's [validation] table",
        )

    failures: list[str] = []
    checks: dict[str, bool] = {}

    start_err = float(np.abs(path[0] - problem.start).max())
    checks["starts_at_start"] = start_err <= settings.start_tolerance
    if not checks["starts_at_start"]:
        failures.append(f"path does not start at the start (max joint difference {start_err:.3g} rad)")

    below = np.maximum(robot.lower - path, 0.0).max()
    above = np.maximum(path - robot.upper, 0.0).max()
    max_violation = float(max(below, above))
    checks["joint_limits"] = max_violation <= settings.limit_tolerance
    if not checks["joint_limits"]:
        k = int(np.argmax(np.maximum(robot.lower - path, path - robot.upper).max(axis=1)))
        failures.append(f"waypoint {k} outside joint limits: " + "; ".join(robot.limit_violations(path[k])))

    max_ratio = math.nan
    trajectory_duration = math.nan
    if result.times is not None:
        t = result.times
        dt = np.diff(t)
        if len(t) and (t[0] != 0 or np.any(dt <= 0)):
            checks["velocity_limits"] = False
            failures.append("time stamps must start at 0 and increase strictly")
        else:
            trajectory_duration = float(t[-1]) if len(t) else 0.0
            if len(dt):
                ratio = np.abs(np.diff(path, axis=0)) / dt[:, None] / robot.velocity_limit
                max_ratio = float(ratio.max())
                checks["velocity_limits"] = max_ratio <= 1.0 + settings.velocity_tolerance
                if not checks["velocity_limits"]:
                    k, j = (int(i) for i in np.unravel_index(np.argmax(ratio), ratio.shape))
                    failures.append(
                        f"segment {k} too fast: {robot.joint_names[j]} at {ratio[k, j]:.3f}x its "
                        f"velocity limit of {robot.velocity_limit[j]:.3f} rad/s"
                    )
            else:
                checks["velocity_limits"] = True

    checker = CertifiedChecker.for_problem(problem, settings.certification())
    verdict = checker.check_path(path)
    n_checks = verdict.queries
    checks["collision_free"] = verdict.free
    if not verdict.free:
        failures.append(verdict.describe() if verdict.segment >= 0 else verdict.reason)

    final = path[-1]
    pos_err, rot_err = pose_error(robot, final, problem.goal.pose)
    tol = problem.tolerances
    checks["goal_pose"] = pos_err <= tol.position and rot_err <= tol.orientation
    if not checks["goal_pose"]:
        failures.append(
            f"goal not reached: position error {pos_err * 1000:.1f} mm (tolerance {tol.position * 1000:.1f} mm), "
            f"orientation error {rot_err:.3f} rad (tolerance {tol.orientation:.3f} rad)"
        )
    joint_err = math.nan
    if problem.goal.q is not None:
        joint_err = float(np.abs(final - problem.goal.q).max())
        if result.target == "configuration":
            checks["goal_configuration"] = joint_err <= tol.joint
            if not checks["goal_configuration"]:
                failures.append(
                    f"goal configuration not reached: max joint error {joint_err:.4f} rad "
                    f"(tolerance {tol.joint:.4f} rad)"
                )

    checks[CLAIMED_SUCCESS] = result.status is PlanStatus.SUCCESS
    success = not failures and checks[CLAIMED_SUCCESS]
    failure = "; ".join(failures)
    if not failures and not success:
        failure = _claimed_failure(result)
    return Evaluation(
        success=success,
        failure=failure,
        status=status,
        planning_time=planning_time,
        setup_time=setup_time,
        n_waypoints=len(path),
        joint_path_length=metrics.joint_path_length(path),
        ee_path_length=_ee_path_length(robot, path, settings.ee_resolution),
        min_clearance=float(verdict.clearance_found),
        min_clearance_bound=float(verdict.clearance_lower),
        mean_clearance=_mean_clearance(checker, path, settings.clearance_samples) if verdict.free else math.nan,
        duration=metrics.execution_duration(path, robot.velocity_limit),
        duration_limited=metrics.limited_duration(path, robot.velocity_limit, robot.acceleration_limit),
        trajectory_duration=trajectory_duration,
        smoothness=metrics.turning_angle(path),
        final_position_error=pos_err,
        final_orientation_error=rot_err,
        final_joint_error=joint_err,
        max_limit_violation=max_violation,
        max_velocity_ratio=max_ratio,
        collision_checks=planner_checks,
        validation_checks=n_checks,
        collision_segment=verdict.segment,
        collision_fraction=verdict.fraction,
        collision_pair=" / ".join(verdict.pair) if not verdict.free and verdict.pair[0] else "",
        penetration_depth=verdict.depth,
        checks=checks,
    )


EE_CHUNK = 65_536
"""Segments, or interpolated states, handled at once when a path is counted or its end-effector
length measured, so that memory stays flat however long the path is."""


def not_validated(result: PlanResult, failure: str) -> Evaluation:
    """The evaluation of a result whose path is not validated (none, unusable, or too costly to
    check): never a success, with the planner's claimed status and ``failure`` saying why."""
    return Evaluation(
        False,
        failure,
        result.status.value,
        float(result.planning_time),
        float(result.setup_time),
        n_waypoints=0 if result.path is None else len(result.path),
        collision_checks=_reported_checks(result),
    )


def validation_states(path: np.ndarray, ee_resolution: float) -> float:
    """Configurations :func:`evaluate` interpolates along ``path`` (an (N, nq) array), counted from
    its joint motion without building any: one per ``ee_resolution`` of each segment's largest
    joint motion (at least one per segment: the end-effector length), plus one per
    :data:`metrics.TIMING_SPACING` of joint-space length (toppra's spline for
    ``duration_limited``). The certification's own work is bounded by its distance-query budget.
    Counted :data:`EE_CHUNK` segments at a time, so it needs little memory beside the path; a float,
    ``inf`` for a path of huge values."""
    path = np.asarray(path, dtype=float)
    ee = length = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(0, len(path) - 1, EE_CHUNK):
            delta = np.abs(np.diff(path[i : i + EE_CHUNK + 1], axis=0))
            ee += float(np.maximum(1.0, np.ceil(delta.max(axis=1) / ee_resolution)).sum())
            length += float(np.sqrt(np.einsum("ij,ij->i", delta, delta)).sum())
    timing = length / metrics.TIMING_SPACING
    return float(min(len(path), 1) + ee + math.ceil(timing)) if math.isfinite(timing) else math.inf


def _ee_path_length(robot: Any, path: np.ndarray, resolution: float) -> float:
    """End-effector path length [m] through :func:`metrics.densify`'s states, built a block of
    segments (about :data:`EE_CHUNK` states) at a time rather than all at once."""
    steps = np.maximum(1, np.ceil(np.abs(np.diff(path, axis=0)).max(axis=1, initial=0.0) / resolution))
    ends = np.cumsum(steps)  # states up to the end of each segment (densify's, or one more)
    length, i = 0.0, 0
    while True:
        before = ends[i - 1] if i else 0.0
        j = max(i + 1, int(np.searchsorted(ends, before + EE_CHUNK, side="right")))  # segments i .. j-1
        dense, _ = metrics.densify(path[i : j + 1], resolution)
        length += metrics.polyline_length(np.array([robot.frame_pose(q).translation for q in dense]))
        if j >= len(path) - 1:
            return length
        i = j


def _claimed_failure(result: PlanResult) -> str:
    """The failure of a valid path whose planner did not report success (not counted: see the
    module docstring)."""
    said = f"{result.status.value}: {result.message}" if result.message else result.status.value
    return f"{said} (the path is valid, but the planner did not report success: not counted)"


def verdict_checker(problem: Problem) -> CertifiedChecker:
    """The harness's certified checker for ``problem`` (default settings, cached on the problem)
    without the clearance refinement of a free path: the same verdicts, which is all a planner
    checking its own path needs."""
    return CertifiedChecker.for_problem(problem, ValidationSettings().certification(measure_clearance=False))


def _mean_clearance(checker: CertifiedChecker, path: np.ndarray, n: int) -> float:
    """Mean clearance [m] at ``n`` configurations evenly spaced by joint-space length along ``path``."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if len(path) == 1 or cum[-1] == 0:
        return checker.clearance(path[0])
    at = np.linspace(0.0, cum[-1], n)
    q = np.stack([np.interp(at, cum, path[:, j]) for j in range(path.shape[1])], axis=1)
    return float(np.mean([checker.clearance(c) for c in q]))


def _reported_checks(result: PlanResult) -> int | None:
    """The planner's own collision-check count, or None when it does not report a usable one."""
    n = result.info.get("collision_checks")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        return None
    return int(n)
