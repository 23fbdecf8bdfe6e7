"""Judging a solvability certificate: the certificate's trajectory run as a controller's run is.

The certificate (:mod:`planbench.reactive.certificate`) is sampled at the scenario's control ticks
``k / control_rate`` up to its last knot, and cut at the first tick at which the end effector is
within the goal's tolerances (where a closed-loop run ends). That record is judged by
:func:`~planbench.reactive.runner.evaluate_run`, the judge of every controller's run: each tick
certified against the true moving geometry, the joint limits, the horizon, the goal. Two rules a
run gets from the runner instead are checked here: the trajectory starts at the problem's start,
and no joint moves faster than its velocity limit, between knots or between ticks.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from planbench.problem import pose_error
from planbench.reactive.certificate import Certificate
from planbench.reactive.runner import RunMetrics, RunRecord, evaluate_run
from planbench.reactive.scenario import Scenario

__all__ = ["certificate_record", "verify_certificate"]

_EPS = 1e-9
SPEED_TOLERANCE = 1e-6
"""Relative excess over a velocity limit still accepted (the rounding of knots and times)."""


def certificate_record(scenario: Scenario, certificate: Certificate) -> RunRecord:
    """The run a certificate makes: its configurations at the control ticks through its last knot
    (past the horizon if it runs so long), cut at the first tick within the goal's tolerances."""
    problem = scenario.problem
    T = scenario.period
    last = max(0, math.ceil(float(certificate.times[-1]) / T - _EPS))
    times = np.arange(last + 1) * T
    path = certificate.at(times)
    path[0] = certificate.path[0]
    tol_p, tol_r = problem.tolerances.position, problem.tolerances.orientation
    end = last
    for k in range(1, last + 1):
        err_p, err_r = pose_error(problem.robot, path[k], problem.goal.pose)
        if err_p <= tol_p and err_r <= tol_r:
            end = k
            break
    times, path = times[: end + 1], path[: end + 1]
    n = len(times) - 1
    return RunRecord(
        scenario.name,
        f"certificate:{certificate.planner}",
        "success",
        "",
        times,
        path,
        np.diff(path, axis=0) / T,
        np.zeros(n),
        np.full(n, np.nan),
    )


def verify_certificate(scenario: Scenario, certificate: Certificate | None = None) -> RunMetrics:
    """Judge ``certificate`` (default: the scenario's own) as a controller's run is judged (module
    docstring): ``success`` says whether it proves the scenario solvable, ``failure`` why not."""
    cert = certificate if certificate is not None else scenario.certificate
    if cert is None:
        raise ValueError(f"scenario {scenario.name!r} has no certificate (planbench check-scenario finds one)")
    robot = scenario.problem.robot
    if cert.nq != robot.nq:
        raise ValueError(f"the certificate's configurations have {cert.nq} joint values, the robot has {robot.nq}")
    record = certificate_record(scenario, cert)
    metrics = evaluate_run(scenario, record)
    failure = _rules(scenario, cert, record) or metrics.failure
    if not failure and abs(metrics.time_to_goal - cert.time_to_goal) > 1e-6:
        claim, real = cert.time_to_goal, metrics.time_to_goal
        failure = f"the certificate says it reaches the goal at {claim:g} s; it does at {real:g} s"
    if failure == metrics.failure:
        return metrics
    return dataclasses.replace(metrics, success=False, failure=failure, time_to_goal=math.nan)


def _rules(scenario: Scenario, cert: Certificate, record: RunRecord) -> str:
    """The first of the runner's rules the certificate breaks (start, velocity limits), or ''."""
    start = np.asarray(scenario.problem.start, dtype=float)
    if np.abs(cert.path[0] - start).max() > _EPS:
        return "the certificate does not start at the problem's start"
    vmax = np.asarray(scenario.problem.robot.velocity_limit, dtype=float) * (1 + SPEED_TOLERANCE)
    names = scenario.problem.robot.joint_names
    steps = [(np.diff(cert.path, axis=0), np.diff(cert.times), "between knots")]
    steps.append((np.diff(record.path, axis=0), np.diff(record.times), "between control ticks"))
    for dq, dt, where in steps:
        if not len(dt):
            continue
        speed = np.abs(dq) / dt[:, None]
        over = np.argwhere(speed > vmax)
        if len(over):
            k, j = over[0]
            t = float(cert.times[k] if where == "between knots" else record.times[k])
            return (
                f"joint {names[j]} moves at {speed[k, j]:.4g} rad/s {where} at t = {t:.3f} s, above its velocity "
                f"limit of {scenario.problem.robot.velocity_limit[j]:.4g} rad/s"
            )
    return ""
