"""Does a closed-loop record obey the control model? A check of the trajectory and compute record alone.

The validator certifies every tick of a run against the moving geometry, but collision-freedom says
nothing about *how* the arm got there: a worker that sent a trajectory faster than the velocity
limits, off the control clock, or with a schedule of controller turns that the compute it reports
could not have produced would still pass. :func:`check_control_model` checks that a record is one
the closed loop (:mod:`planbench.reactive.runner`, ``docs/reactive.md``) can produce:

- at tick ``k`` (time ``k T``) the command is clipped to ``robot.velocity_limit``, the arm moves
  ``q + T qd`` and is clamped to ``robot.lower`` / ``robot.upper``;
- a turn of the controller charged ``c`` [s] misses ``max(0, ceil(c / T - 1e-9) - 1)`` deadlines and
  the controller starts its next turn on tick ``k + missed + 1`` (whatever the run does meanwhile).

The rules, checked in the order of :data:`RULES`; the first broken one is reported, at its first tick:

``times``
    one time per state, finite, ``times[k] == k T`` to ``TIME_RTOL * max(k, 1) * T``. The expected
    value is ``float(k) * T`` (what the runner's ``np.arange(n + 1) * T`` gives, so its records pass
    exactly); the relative slack lets ``np.linspace(0, n T, n + 1)``, ``k / rate`` and a running sum
    of ``T`` (up to about 10^5 ticks) pass, while a time 1e-6 s off (5e-8 of 20 s) or a skipped tick
    does not.
``start``
    ``path[0]`` is the problem's start exactly (float64): the runner copies it, and a float64 survives
    the JSON transport of the record, so any difference is a different start.
``velocity``
    every tick's motion per joint ``|path[k+1] - path[k]| <= velocity_limit T (1 + rtol)``, plus
    ``2**-52 (|path[k]| + |path[k+1]|)`` for the rounding of ``q + T qd`` itself, which only matters when
    ``velocity_limit T`` is tiny. The bound is computed as the simulation computes ``T qd`` at the limit.
``joint_limits``
    every state after the start inside ``[lower, upper]`` exactly (the runner clamps with ``np.clip``,
    which gives the limit itself); the start to ``START_LIMIT_TOL``, the tolerance problems are
    validated with (:meth:`~planbench.robot.Robot.limit_violations`). NaN is outside.
``horizon``
    ``times[-1] <= horizon + HORIZON_TOL`` (``evaluate_run``'s tolerance).
``schedule``
    one ``compute`` entry per tick (``n`` for ``n + 1`` states); turns start on tick 0 and then exactly
    on each tick the previous turn's charge frees the controller, with a finite charge ``>= 0``
    [s]; NaN on the ticks between. A run may end while a turn's command is still late.
``deadline_misses``
    the reported count equals :func:`recount_deadline_misses` of ``compute``; the tick is the turn
    where the recount first exceeds the report, or ``n`` (the end of the run) when it never does.

The runner counts all the deadlines a turn will miss on the tick the turn starts, so a run that ends
(goal, collision, horizon) while a command is late still counts the misses of ticks it never ran;
the recount does the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from planbench.reactive.runner import RunRecord
    from planbench.reactive.scenario import Scenario
    from planbench.robot import Robot

__all__ = [
    "RULES",
    "ControlModelViolation",
    "check_control_model",
    "check_record",
    "recount_deadline_misses",
]

RULES = ("times", "start", "velocity", "joint_limits", "horizon", "schedule", "deadline_misses")
"""The rules, in the order they are checked."""

TIME_RTOL = 1e-12
"""Relative tolerance of ``times[k]`` against ``k T``: far above the rounding of any honest way of
computing the clock (a running sum of ``T`` drifts 2e-13 in 20,000 ticks of 1 ms), far below a
shifted tick."""
HORIZON_TOL = 1e-9
"""[s] How far past the horizon the last state may lie (``evaluate_run`` uses the same)."""
START_LIMIT_TOL = 1e-9
"""[rad or m] How far outside the joint limits the start may lie (what a problem is validated with)."""
MISS_EPS = 1e-9
"""The runner's slack in ``ceil(c / T - MISS_EPS)``: a charge of exactly ``m T`` misses ``m - 1`` deadlines."""
_ROUNDING = 2.0**-52


@dataclass(frozen=True)
class ControlModelViolation:
    """The first broken rule of a record: its name (one of :data:`RULES`), the first tick (or state
    index, for ``times``, ``start``, ``joint_limits`` and ``horizon``) that breaks it, and what was
    expected and found, with numbers and units."""

    rule: str
    tick: int
    detail: str

    def __post_init__(self) -> None:
        if self.rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {self.rule!r}")

    def __str__(self) -> str:
        return f"control model broken ({self.rule}) at tick {self.tick}: {self.detail}"


def recount_deadline_misses(compute: Any, period: float) -> int:
    """The deadline misses a per-tick compute record implies: ``max(0, ceil(c / T - 1e-9) - 1)`` summed
    over the ticks where a turn started (finite entries; NaN elsewhere). Counted from the record so
    that the reported count need not be trusted. Raises ``ValueError`` on an infinite or negative
    charge, which no turn can have."""
    c = np.asarray(compute, dtype=float).ravel()
    if np.any(np.isinf(c)) or np.any(c < 0):
        raise ValueError("charged compute must be finite and >= 0 [s] where a turn started (NaN elsewhere)")
    return sum(_missed(float(x), period) for x in c[np.isfinite(c)])


def check_control_model(
    robot: Robot,
    start: Any,
    period: float,
    horizon: float,
    times: Any,
    path: Any,
    compute: Any,
    deadline_misses: int,
    *,
    rtol: float = 1e-9,
) -> ControlModelViolation | None:
    """The first rule of the control model (module docstring) that the record breaks, None when it
    obeys them all. ``times`` (n + 1,) [s], ``path`` (n + 1, nq) [rad or m], ``compute`` (n,) [s]
    charged per tick (NaN where no turn started), ``deadline_misses`` as reported. ``rtol``: relative
    slack of the velocity bound. Raises ``ValueError`` for arrays of the wrong dimension or a period
    that is not a positive number, which no record can be checked against."""
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f"period must be > 0 [s], got {period}")
    t = np.asarray(times, dtype=float)
    q = np.asarray(path, dtype=float)
    c = np.asarray(compute, dtype=float)
    if t.ndim != 1 or q.ndim != 2 or c.ndim != 1:
        raise ValueError(f"times must be (n + 1,), path (n + 1, nq), compute (n,); got {t.shape}, {q.shape}, {c.shape}")
    for rule in (
        lambda: _times(t, len(q), period),
        lambda: _start(robot, start, q),
        lambda: _velocity(robot, q, period, rtol),
        lambda: _joint_limits(robot, q),
        lambda: _horizon(t, horizon),
        lambda: _schedule(c, len(q) - 1, period),
        lambda: _deadline_misses(c, period, deadline_misses),
    ):
        found = rule()
        if found is not None:
            return found
    return None


def check_record(scenario: Scenario, record: RunRecord) -> ControlModelViolation | None:
    """:func:`check_control_model` of a :class:`~planbench.reactive.runner.RunRecord` of ``scenario``."""
    problem = scenario.problem
    return check_control_model(
        problem.robot,
        problem.start,
        scenario.period,
        scenario.horizon,
        record.times,
        record.path,
        record.compute,
        record.deadline_misses,
    )


def _missed(c: float, period: float) -> int:
    return max(0, math.ceil(c / period - MISS_EPS) - 1)


def _num(x: float) -> str:
    return f"{x:.12g}"


def _times(t: np.ndarray, n_states: int, period: float) -> ControlModelViolation | None:
    if len(t) != n_states:
        return ControlModelViolation(
            "times", min(len(t), n_states), f"{len(t)} times for {n_states} states: one time per state expected"
        )
    expected = np.arange(len(t)) * period
    slack = TIME_RTOL * np.maximum(np.arange(len(t)), 1) * period
    bad = np.flatnonzero(~(np.abs(t - expected) <= slack))
    if len(bad) == 0:
        return None
    k = int(bad[0])
    if not math.isfinite(t[k]):
        return ControlModelViolation("times", k, f"times[{k}] = {t[k]}: times must be finite")
    return ControlModelViolation(
        "times",
        k,
        f"times[{k}] = {_num(t[k])} s, expected {k} x {_num(period)} s = {_num(expected[k])} s "
        f"(off by {t[k] - expected[k]:.3g} s, tolerance {slack[k]:.3g} s)",
    )


def _start(robot: Robot, start: Any, q: np.ndarray) -> ControlModelViolation | None:
    s = np.asarray(start, dtype=float)
    if len(q) == 0:
        return ControlModelViolation("start", 0, "the path has no state")
    if q.shape[1] != robot.nq or s.shape != (robot.nq,):
        return ControlModelViolation(
            "start",
            0,
            f"path states have {q.shape[1]} joints and the start {s.shape}, robot {robot.name} has {robot.nq}",
        )
    differ = np.flatnonzero(~(q[0] == s))
    if len(differ) == 0:
        return None
    j = int(differ[0])
    return ControlModelViolation(
        "start",
        0,
        f"joint {robot.joint_names[j]} starts at {float(q[0, j])!r} rad, the problem's start is {float(s[j])!r} rad "
        f"(off by {q[0, j] - s[j]:.3g} rad; {len(differ)} joint(s) differ)",
    )


def _velocity(robot: Robot, q: np.ndarray, period: float, rtol: float) -> ControlModelViolation | None:
    if len(q) < 2:
        return None
    vmax = np.asarray(robot.velocity_limit, dtype=float)
    limit = vmax * period
    step = np.abs(np.diff(q, axis=0))
    allowed = limit * (1.0 + rtol) + _ROUNDING * (np.abs(q[:-1]) + np.abs(q[1:]))
    bad = np.flatnonzero(np.any(~(step <= allowed), axis=1))
    if len(bad) == 0:
        return None
    k = int(bad[0])
    if not (np.isfinite(q[k]).all() and np.isfinite(q[k + 1]).all()):
        j = int(np.flatnonzero(~np.isfinite(q[k + 1]))[0])
        return ControlModelViolation(
            "velocity", k, f"joint {robot.joint_names[j]} went to {q[k + 1, j]} in tick {k}: states must be finite"
        )
    j = int(np.argmax(step[k] / limit))
    name = robot.joint_names[j]
    return ControlModelViolation(
        "velocity",
        k,
        f"joint {name} moved {_num(step[k, j])} rad in {_num(period)} s, limit {_num(vmax[j])} rad/s x "
        f"{_num(period)} s = {_num(limit[j])} rad ({step[k, j] / limit[j]:.10g} x the limit)",
    )


def _joint_limits(robot: Robot, q: np.ndarray) -> ControlModelViolation | None:
    lower = np.asarray(robot.lower, dtype=float)
    upper = np.asarray(robot.upper, dtype=float)
    tol = np.zeros((len(q), 1))
    tol[:1] = START_LIMIT_TOL
    outside = ~((q >= lower - tol) & (q <= upper + tol))
    bad = np.flatnonzero(outside.any(axis=1))
    if len(bad) == 0:
        return None
    k = int(bad[0])
    j = int(np.flatnonzero(outside[k])[0])
    x, lo, hi = float(q[k, j]), float(lower[j]), float(upper[j])
    where = (
        f"below its lower limit {lo!r} rad by {lo - x:.3g} rad"
        if x < lo
        else f"above its upper limit {hi!r} rad by {x - hi:.3g} rad"
    )
    if not math.isfinite(x):
        where = f"not within [{lo!r}, {hi!r}] rad"
    allowance = (
        f"the start may lie {START_LIMIT_TOL:g} rad outside" if k == 0 else "states after the start are clamped exactly"
    )
    return ControlModelViolation("joint_limits", k, f"joint {robot.joint_names[j]} at {x!r} rad, {where} ({allowance})")


def _horizon(t: np.ndarray, horizon: float) -> ControlModelViolation | None:
    bad = np.flatnonzero(~(t <= horizon + HORIZON_TOL))
    if len(bad) == 0:
        return None
    k = int(bad[0])
    return ControlModelViolation(
        "horizon",
        k,
        f"state {k} at {_num(t[k])} s, past the horizon of {_num(horizon)} s (tolerance {HORIZON_TOL:g} s)",
    )


def _schedule(c: np.ndarray, n_ticks: int, period: float) -> ControlModelViolation | None:
    if len(c) != n_ticks:
        return ControlModelViolation(
            "schedule",
            min(len(c), n_ticks),
            f"compute has {len(c)} entries for {n_ticks} ticks ({n_ticks + 1} states): one per tick expected",
        )
    free_at, last = 0, -1
    for k in range(n_ticks):
        x = float(c[k])
        if k < free_at:
            if not math.isnan(x):
                busy = f"the turn started at tick {last} (charged {_num(float(c[last]))} s"
                return ControlModelViolation(
                    "schedule",
                    k,
                    f"a turn charged {_num(x)} s is recorded at tick {k}, but {busy} = "
                    f"{float(c[last]) / period:.6g} periods of {_num(period)} s) keeps the controller busy "
                    f"until tick {free_at}",
                )
            continue
        if math.isnan(x):
            after = (
                f"its turn at tick {last} freed it for tick {free_at}" if last >= 0 else "its first turn is on tick 0"
            )
            return ControlModelViolation(
                "schedule", k, f"no turn is recorded at tick {k} (compute NaN), but the controller was free: {after}"
            )
        if not (math.isfinite(x) and x >= 0):
            return ControlModelViolation(
                "schedule", k, f"the turn at tick {k} is charged {x} s: a charge must be finite and >= 0 s"
            )
        last, free_at = k, k + _missed(x, period) + 1
    return None


def _deadline_misses(c: np.ndarray, period: float, reported: Any) -> ControlModelViolation | None:
    recount = recount_deadline_misses(c, period)
    if reported == recount:
        return None
    running, tick = 0, len(c)
    for k in np.flatnonzero(np.isfinite(c)):
        running += _missed(float(c[k]), period)
        if running > reported:
            tick = int(k)
            break
    return ControlModelViolation(
        "deadline_misses",
        tick,
        f"{reported} deadline misses reported, the compute record gives {recount} "
        f"(ceil(c / {_num(period)} s - {MISS_EPS:g}) - 1 per turn)",
    )
