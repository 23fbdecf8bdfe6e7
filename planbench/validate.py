"""Independent validation of a returned path, and the metrics of every run.

A planner's claim of success is never trusted: :func:`evaluate` re-checks the path against the
problem's TRUE geometry (the scene's primitives with coal, never a voxel grid) and the robot's
limits, and success means every check holds:

- the path is an (N, nq) array of finite values starting at the problem's start;
- every waypoint is inside the joint limits;
- no configuration collides with the scene or with the robot itself, checked at every waypoint and
  along every segment so that no joint moves more than ``collision_resolution`` [rad] between two
  checked configurations (linear interpolation in joint space);
- for a trajectory with time stamps, the joint velocities of every segment are within the limits;
- the final end-effector pose is within the position and orientation tolerances of the goal pose,
  and, when the planner says it drove to the goal configuration, the final joint error too.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from planbench import metrics
from planbench.collision import CollisionChecker
from planbench.planner import PlanResult, PlanStatus
from planbench.problem import Problem, pose_error

__all__ = ["ValidationSettings", "Evaluation", "evaluate"]


@dataclass(frozen=True)
class ValidationSettings:
    """How densely paths are checked. Units: rad (or m for prismatic joints)."""

    collision_resolution: float = 0.01
    """Largest joint motion between two configurations checked for collision [rad]."""
    clearance_resolution: float = 0.05
    """Largest joint motion between two configurations where clearance is measured [rad]
    (distance queries cost ~30x a collision query, so clearance is sampled more coarsely)."""
    start_tolerance: float = 1e-6
    """How far path[0] may be from the problem's start [rad]."""
    limit_tolerance: float = 1e-9
    """Slack on joint position limits [rad] (float round-off at a limit is not a violation)."""
    velocity_tolerance: float = 1e-6
    """Relative slack on velocity limits (|qd| <= vmax * (1 + tol))."""

    def __post_init__(self) -> None:
        for name in ("collision_resolution", "clearance_resolution"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0 [rad], got {v}")


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
    min_clearance: float = math.nan
    mean_clearance: float = math.nan
    duration: float = math.nan  # at the velocity limits, see metrics.execution_duration
    trajectory_duration: float = math.nan  # the planner's own time stamps, when given
    smoothness: float = math.nan  # total turning angle, see metrics.turning_angle
    final_position_error: float = math.nan
    final_orientation_error: float = math.nan
    final_joint_error: float = math.nan
    max_limit_violation: float = math.nan  # [rad] beyond the position limits (0 when inside)
    max_velocity_ratio: float = math.nan  # max |qd| / vmax over segments, when timed
    collision_checks: int | None = None  # the planner's own count, when it reports info["collision_checks"]
    validation_checks: int = 0  # configurations this validation checked (it stops at the first collision)
    checks: dict[str, bool] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def evaluate(problem: Problem, result: PlanResult, settings: ValidationSettings | None = None) -> Evaluation:
    """Check ``result`` against ``problem`` independently and measure it (see module docstring)."""
    settings = settings or ValidationSettings()
    robot = problem.robot
    status, planning_time, setup_time = result.status.value, float(result.planning_time), float(result.setup_time)

    planner_checks = _reported_checks(result)

    def unusable(failure: str, n_waypoints: int = 0) -> Evaluation:
        return Evaluation(
            False, failure, status, planning_time, setup_time, n_waypoints=n_waypoints, collision_checks=planner_checks
        )

    path = result.path
    if path is None or len(path) == 0:
        reason = result.status.value if result.status is not PlanStatus.SUCCESS else "no path returned"
        return unusable(f"{reason}: {result.message}" if result.message else reason)
    if path.shape[1] != robot.nq:
        return unusable(f"path has {path.shape[1]} columns, robot plans {robot.nq} joints", len(path))
    if not np.all(np.isfinite(path)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(path), axis=1))[0])
        return unusable(f"path has NaN or infinite values (waypoint {bad})", len(path))

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

    checker = CollisionChecker.for_problem(problem)
    dense, segment = metrics.densify(path, settings.collision_resolution)
    n_checks = 0
    hit = -1
    for i, q in enumerate(dense):
        n_checks += 1
        if checker.in_collision(q):
            hit = i
            break
    checks["collision_free"] = hit < 0
    if hit >= 0:
        pairs = ", ".join(f"{a} with {b}" for a, b in checker.collisions(dense[hit])[:3])
        failures.append(f"collision on segment {int(segment[hit])} (dense state {hit}): {pairs}")

    coarse, _ = metrics.densify(path, settings.clearance_resolution)
    clearances = np.array([checker.clearance(q) for q in coarse])
    ee_points = np.array([robot.frame_pose(q).translation for q in dense])

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

    success = not failures
    failure = "; ".join(failures)
    if success and result.status is not PlanStatus.SUCCESS:
        failure = ""  # the path is valid whatever the planner said; its claim stays in `status`
    return Evaluation(
        success=success,
        failure=failure,
        status=status,
        planning_time=planning_time,
        setup_time=setup_time,
        n_waypoints=len(path),
        joint_path_length=metrics.joint_path_length(path),
        ee_path_length=metrics.polyline_length(ee_points),
        min_clearance=float(clearances.min()),
        mean_clearance=float(clearances.mean()),
        duration=metrics.execution_duration(path, robot.velocity_limit),
        trajectory_duration=trajectory_duration,
        smoothness=metrics.turning_angle(path),
        final_position_error=pos_err,
        final_orientation_error=rot_err,
        final_joint_error=joint_err,
        max_limit_violation=max_violation,
        max_velocity_ratio=max_ratio,
        collision_checks=planner_checks,
        validation_checks=n_checks,
        checks=checks,
    )


def _reported_checks(result: PlanResult) -> int | None:
    """The planner's own collision-check count, or None when it does not report a usable one."""
    n = result.info.get("collision_checks")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        return None
    return int(n)
