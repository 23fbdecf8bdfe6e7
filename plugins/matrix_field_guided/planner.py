"""``matrix-field-guided``: track a global planner's path with the matrix field keeping clearance.

1. **Global plan** (timed, ``global_time_share`` of the limit): the ``global_planner``
   (``ompl-rrtconnect`` by default, built through the registry with ``global_settings``) plans on
   the same scene with the same ``rng``, so its path is the one that planner returns alone.
2. **Tracking**: the waypoints become a reference ``r(t)`` (:class:`.reference.Reference`; a step
   ends on a waypoint rather than cut its corner), and per step ``dt``, from ``q``:

       qd = (r_k+1 - r_k) / dt + K (r_k - q) + w sum_i J_i^T f_i

   ``f_i`` the matrix field's push at the control points (as in ``matrix-field``: the same grid,
   kernels and stand-off gain), ``J_i`` their Jacobians, ``w`` a smoothstep of ``1 - lag /
   max_lag`` (the push fades out as the arm departs from the reference, so the tracking always
   wins) times a smoothstep of the joint path length left over ``goal_fade``; then the velocity
   limits (one factor, direction kept) and the position limits (per joint). Without a push the arm
   stays on the global path exactly. Once the reference has arrived and the arm is within
   ``goal_tolerance`` of the last waypoint, the path ends on it.
3. **Verdict**: the tracked trajectory is certified whole with the harness's checker
   (:func:`planbench.validate.verdict_checker`). A collision at reference time ``t_c`` switches the
   push off from ``t_c - quiet_before`` to ``t_c + quiet_after`` and the tracking runs again, at
   most ``retries`` times; then (or when the tracking ran out of steps or time) the global path
   itself is returned and ``info["fallback"]`` says why.

``info``: ``global_planner``, ``global_status``, ``global_time`` [s], ``global_path`` (K, n),
``fallback`` (``None``, ``"collision"``, ``"step_limit"`` or ``"time_limit"``), ``attempts`` (each
try's verdict), ``quiet`` (intervals of reference time [s] with the push off), ``departure_max``
and ``departure_median`` [rad] (distance of the returned configurations from the global path's
polyline), ``push_max`` [rad/s] (largest ``|sum J_i^T f_i|``), ``lag_max`` [rad],
``tracking_steps``, ``tracking_time`` [s].
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from planbench.field.scene_field import scene_repulsion
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem
from planbench.registry import make_planner
from planbench.validate import verdict_checker
from planbench_plugins.ik_loop import ArmKinematics, ArmRepulsion, Repulsion, ZeroRepulsion, place_control_points
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field_guided.config import MatrixFieldGuidedConfig
from planbench_plugins.matrix_field_guided.reference import Reference, departure
from planbench_plugins.matrix_field_guided.tracking import push_weight, tracking_velocity

__all__ = ["MatrixFieldGuidedPlanner"]


class MatrixFieldGuidedPlanner(Planner):
    """A global path tracked reactively in the matrix field. See the module docstring."""

    name = "matrix-field-guided"
    Config = MatrixFieldGuidedConfig

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self._problem: Problem | None = None  # the problem of the last setup
        self._global: Planner | None = None
        self._arm: ArmRepulsion | None = None

    def setup(self, problem: Problem) -> None:
        """The global planner's setup, the control points, the field and the certified checker."""
        cfg = self.config
        robot = problem.robot
        global_planner = make_planner(cfg.global_planner, **cfg.global_settings)
        global_planner.setup(problem)
        overrides = dict(robot.settings.control_points)
        overrides.update(dict(cfg.control_points or {}))
        points = place_control_points(robot, cfg.control_point_spacing, list(overrides.items()))
        kin = ArmKinematics(robot, robot.frame_id(problem.goal.pose.frame), points)
        repulsion: Repulsion = scene_repulsion(problem, cfg) or ZeroRepulsion()
        arm = ArmRepulsion(robot, kin, repulsion)
        arm.at(np.asarray(problem.start, dtype=float))  # first-call costs (the compiled sampler) out of the query
        verdict_checker(problem)
        self._problem, self._global, self._arm = problem, global_planner, arm

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        if self._problem is not problem:
            self.setup(problem)
        assert self._global is not None
        cfg = self.config
        t0 = time.perf_counter()
        found = self._global.plan(problem, time_limit=cfg.global_time_share * time_limit, rng=rng)
        info: dict[str, Any] = {
            "global_planner": cfg.global_planner,
            "global_status": found.status.value,
            "global_time": time.perf_counter() - t0,
        }
        if found.status is not PlanStatus.SUCCESS or found.path is None or len(found.path) == 0:
            return PlanResult(
                found.status,
                found.path,
                found.times,
                found.target,
                f"global plan ({cfg.global_planner}): {found.message}",
                {**info, "global_info": _json_info(found.info)},
            )
        waypoints = np.array(found.path, dtype=float)
        info["global_path"] = waypoints
        t1 = time.perf_counter()
        checker = verdict_checker(problem)
        attempts: list[str] = []
        quiet: list[tuple[float, float]] = []
        path = waypoints
        why: str | None = "no_attempt"
        for _ in range(cfg.retries + 1):
            path, stamps, why, stats = self._track(problem, waypoints, quiet, deadline=t0 + time_limit)
            if why is None:
                verdict = checker.check_path(path)
                if not verdict.free:
                    why = "collision"
                    t_hit = float(stamps[min(max(verdict.segment, 0) + 1, len(stamps) - 1)])
                    quiet = _merged([*quiet, (t_hit - cfg.quiet_before, t_hit + cfg.quiet_after)])
            attempts.append(why or "free")
            if why is None or why == "time_limit":
                break
        info.update(stats, attempts=attempts, quiet=[list(w) for w in quiet])
        info["tracking_time"] = time.perf_counter() - t1
        info["fallback"] = why
        dep = departure(path if why is None else waypoints, waypoints)
        info["departure_max"], info["departure_median"] = float(dep.max()), float(np.median(dep))
        if why is not None:
            return PlanResult(
                PlanStatus.SUCCESS,
                waypoints,
                None,
                found.target,
                f"the tracked path was refused ({why}): the global path is returned",
                info,
            )
        times = np.arange(len(path)) * cfg.dt
        message = f"global path ({len(waypoints)} waypoints) tracked in {len(path) - 1} steps"
        return PlanResult(PlanStatus.SUCCESS, path, times, found.target, message, info)

    def _track(
        self, problem: Problem, waypoints: np.ndarray, quiet: list[tuple[float, float]], deadline: float
    ) -> tuple[np.ndarray, np.ndarray, str | None, dict[str, Any]]:
        """``(path, reference times, reason it failed or None, stats)``: the tracking loop of the
        module docstring, without a push while the reference time lies in a ``quiet`` interval."""
        arm = self._arm
        assert arm is not None
        cfg = self.config
        robot = problem.robot
        lower, upper = np.asarray(robot.lower, dtype=float), np.asarray(robot.upper, dtype=float)
        qd_max = np.asarray(robot.velocity_limit, dtype=float)
        reference = Reference(waypoints, cfg.velocity_scale * qd_max)
        dt, gain, lag_max = cfg.dt, cfg.tracking_gain, cfg.max_lag
        push = cfg.repulsion_gain > 0 and not isinstance(arm.repulsion, ZeroRepulsion)
        path = np.empty((cfg.max_steps + 2, robot.nq))
        stamps = np.zeros(cfg.max_steps + 2)  # the reference time of each path row
        q = path[0] = np.array(problem.start, dtype=float)
        t, push_max, lag_seen = 0.0, 0.0, 0.0
        why: str | None = "step_limit"
        k = 0
        while k < cfg.max_steps:
            if t >= reference.duration and np.max(np.abs(q - reference.end)) <= cfg.goal_tolerance:
                k += 1
                path[k], stamps[k] = reference.end, t
                why = None
                break
            t_next = reference.next_time(t, dt)
            r, _, remaining = reference.at(t)
            r_next, _, _ = reference.at(t_next)
            # feed-forward to where the reference will be, feedback on where it is: without a push
            # the arm lands on the reference (its error shrinks by 1 - K dt per step)
            lag = float(np.max(np.abs(q - r)))
            lag_seen = max(lag_seen, lag)
            w = push_weight(lag, lag_max, remaining, cfg.goal_fade)
            if any(a <= t <= b for a, b in quiet):
                w = 0.0
            weighted = None
            if push and w > 0:
                points, F, support, _ = arm.at(q)
                qd_rep = T.repulsion_joint_velocity(arm.kin.S, points, F, support)
                push_max = max(push_max, float(np.linalg.norm(qd_rep)))
                weighted = w * qd_rep
            qd = tracking_velocity(q, r, r_next, dt, gain, weighted, qd_max, lower, upper)
            k += 1
            q = path[k] = np.clip(q + qd * dt, lower, upper)
            t = stamps[k] = t_next
            if k % 16 == 0 and time.perf_counter() > deadline:
                why = "time_limit"
                break
        stats = {"tracking_steps": k, "push_max": push_max, "lag_max": lag_seen}
        return path[: k + 1].copy(), stamps[: k + 1].copy(), why, stats


def _merged(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Overlapping intervals joined, in order."""
    out: list[tuple[float, float]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _json_info(info: Any) -> dict[str, Any]:
    """The global planner's scalar diagnostics (arrays left out)."""
    return {k: v for k, v in dict(info).items() if isinstance(v, (str, int, float, bool)) or v is None}
