"""Run one planner on one problem: check the problem, time setup and planning apart, catch bugs.

This is the in-process path (``planbench.plan``). It cannot stop a planner that hangs or crashes
the interpreter; the benchmark (and ``planbench plan``) runs each query in its own process for
that. It does make a late answer honest: a result that comes after ``time_limit`` (plus
:data:`HANDOFF_TOLERANCE`) is returned as ``TIMEOUT``, so it never validates as a success.
"""

from __future__ import annotations

import time
import traceback
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.planner import PlanResult, PlanStatus
from planbench.problem import Problem
from planbench.registry import REGISTRY, Registry

__all__ = ["DEFAULT_TIME_LIMIT", "HANDOFF_TOLERANCE", "answered_late", "late_message", "plan", "resolve_planner"]

DEFAULT_TIME_LIMIT = 10.0
"""[s] planning time of one ``planbench.plan`` call (and of ``planbench plan``) unless one is given.
A benchmark suite has its own default, :data:`planbench.bench.suite.DEFAULT_TIME_LIMIT`."""

HANDOFF_TOLERANCE = 0.05
"""[s] how far past its time limit an answer may arrive and still count. An answer is timed from
the start of the query to its arrival where it is judged: in a benchmark that is the parent
process, so the time holds, besides planning, sending the result across processes and the parent's
wake-up (measured under full CPU load: docs/measurements.md#time-limits), and in-process the
harness's own bookkeeping. A planner that stops at its limit is never failed by those; one that
answers later than this is (a ``timeout``, path kept but not counted), however good its path."""


def answered_late(planning_time: float, time_limit: float) -> bool:
    """Whether an answer after ``planning_time`` [s] missed ``time_limit`` [s] (see
    :data:`HANDOFF_TOLERANCE`)."""
    return planning_time > time_limit + HANDOFF_TOLERANCE


def late_message(planning_time: float, time_limit: float) -> str:
    """How a late answer is described in its row."""
    return (
        f"answered at {planning_time:.3f} s, past the time limit of {time_limit:g} s "
        f"(+{HANDOFF_TOLERANCE:g} s hand-off tolerance)"
    )


def resolve_planner(planner: Any, registry: Registry | None = None, **settings: Any) -> Any:
    """A planner instance from a registered name, a planner class (both built by
    :meth:`~planbench.registry.Registry.make`), or an instance."""
    if isinstance(planner, (str, type)):
        return (registry or REGISTRY).make(planner, **settings)
    if settings:
        raise InvalidConfigError(
            f"settings {sorted(settings)} can only be given with a planner name or class, not an instance "
            f"of {type(planner).__name__}"
        )
    return planner


def plan(
    problem: Problem,
    planner: Any = "straight-line",
    *,
    seed: int = 0,
    time_limit: float = DEFAULT_TIME_LIMIT,
    registry: Registry | None = None,
    **settings: Any,
) -> PlanResult:
    """Plan ``problem`` with ``planner`` (a registered name, a class or an instance) and its
    ``settings`` (keywords; see :meth:`~planbench.registry.Registry.configure`).

    The problem is checked first: a start that is NaN, outside the limits or in collision gives
    ``INVALID_START``, an unusable goal pose ``INVALID_GOAL``, without calling the planner. Setup
    and planning are timed apart with a monotonic clock; an exception raised by the planner gives
    ``ERROR`` with its traceback in ``info["traceback"]``. ``seed`` seeds the planner's
    ``numpy.random.Generator``. A result returned after ``time_limit`` + :data:`HANDOFF_TOLERANCE`
    becomes ``TIMEOUT`` (its path kept, the planner's own status in the message), unless it is an
    ``ERROR``.
    """
    if not (np.isfinite(time_limit) and time_limit > 0):
        raise InvalidConfigError(f"time_limit must be a finite number > 0 [s], got {time_limit}")
    instance = resolve_planner(planner, registry, **settings)
    check = problem.check()
    if check.start:
        return PlanResult(PlanStatus.INVALID_START, message="; ".join(check.start), planning_time=0.0, setup_time=0.0)
    if check.goal_pose:
        return PlanResult(
            PlanStatus.INVALID_GOAL, message="; ".join(check.goal_pose), planning_time=0.0, setup_time=0.0
        )
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    try:
        instance.setup(problem)
    except Exception as exc:
        return _error(exc, "setup", setup_time=time.perf_counter() - t0)
    setup_time = time.perf_counter() - t0
    t1 = time.perf_counter()
    try:
        result = instance.plan(problem, time_limit=float(time_limit), rng=rng)
    except Exception as exc:
        return _error(exc, "plan", setup_time=setup_time, planning_time=time.perf_counter() - t1)
    planning_time = time.perf_counter() - t1
    if not isinstance(result, PlanResult):
        return PlanResult(
            PlanStatus.ERROR,
            message=f"plan() returned {type(result).__name__}, not a PlanResult",
            setup_time=setup_time,
            planning_time=planning_time,
        )
    result = result.replace(planning_time=planning_time, setup_time=setup_time)
    return _late(result, float(time_limit))


def _late(result: PlanResult, time_limit: float) -> PlanResult:
    """``result`` as ``TIMEOUT`` when it came after the time limit (an exception stays an ``ERROR``)."""
    if result.status is PlanStatus.ERROR or not answered_late(result.planning_time, time_limit):
        return result
    said = f"{result.status.value}: {result.message}" if result.message else result.status.value
    message = f"{late_message(result.planning_time, time_limit)}; the planner said {said}"
    return result.replace(status=PlanStatus.TIMEOUT, message=message)


def _error(exc: BaseException, where: str, setup_time: float, planning_time: float = 0.0) -> PlanResult:
    return PlanResult(
        PlanStatus.ERROR,
        message=f"planner raised in {where}(): {type(exc).__name__}: {exc}",
        info={"traceback": traceback.format_exc()},
        setup_time=setup_time,
        planning_time=planning_time,
    )
