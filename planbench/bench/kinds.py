"""The two kinds of benchmark run behind one seam: what the worker does, what the validator does.

The runner (:mod:`planbench.bench.runner`), the worker and the validator know runs only through a
:class:`RunKind`, found by the task's ``kind`` in :data:`KINDS`:

- **static** (a planner plans a problem): the worker plans and sends the raw result; the parent
  checks it and hands it to the validator, which computes the verdict.
- **dynamic** (a controller runs closed-loop on a scenario): the worker and the validator are
  joined by a socket pair the parent makes (:mod:`planbench.reactive.remote`). The worker becomes
  the controller's process (fresh for every run, confined, ended after it); once the controller is
  set up, the parent asks the validator to *simulate* the run against it there, and the
  validator's answer is the run's record and verdict at once. Nothing the worker sends can
  become a record, except that it could not prepare the run.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["KINDS", "RunKind", "expand", "kind_of", "registry_of"]

Notify = Callable[[str], None]


@dataclass(frozen=True)
class RunKind:
    """How a kind of run crosses the benchmark's processes."""

    name: str
    entry: str
    """What its ``planner`` entries are: ``"planner"`` or ``"controller"`` (entry-point group
    ``planbench.controllers``, and then its ``problems`` are scenarios)."""
    channel: bool
    """The worker and the validator talk directly during the run, and the validator's answer to
    the plan phase is the record (else: the worker's result is validated after the plan phase)."""
    fresh_worker: bool
    """Every run gets a worker that has run nothing, and the worker ends after it."""
    answer_in_time: bool
    """Success needs the plan phase to end within ``time_limit`` (+ the hand-off tolerance); else
    ``time_limit`` is only the wall-clock limit past which the run is killed (a closed loop's time
    is charged inside the simulation)."""
    work: Callable[[Any, Notify, socket.socket | None], dict[str, Any] | None]
    """In the worker: ``work(task, notify, channel)`` -> the raw result fields, or None when the
    run's record comes from the validator."""
    judge: Callable[
        [dict[str, Any], dict[str, Any], socket.socket | None], tuple[dict[str, Any] | None, dict[str, Any]]
    ]
    """In the validator: ``judge(request, arrays, channel)`` -> (the run's raw fields when the
    validator made them, else None; the evaluation as a dict)."""


def _static_work(task: Any, notify: Notify, channel: socket.socket | None) -> dict[str, Any]:
    from planbench.bench.worker import plan_one

    return plan_one(task, notify)


def _static_judge(
    request: dict[str, Any], arrays: dict[str, Any], channel: socket.socket | None
) -> tuple[None, dict[str, Any]]:
    from planbench.bench.snapshot import SnapshotChanged, restore
    from planbench.bench.validator import validate_fields
    from planbench.bench.wire import clean_result
    from planbench.validate import Evaluation

    fields = clean_result({**request["result"], "path": arrays.get("path"), "times": arrays.get("times")})
    try:
        problem = restore(request["snapshot"])
    except SnapshotChanged as exc:  # the run's problem is not the one the benchmark read: no verdict
        failure = f"error: {exc}; no verdict"
        return None, Evaluation(False, failure, "error", fields["planning_time"], fields["setup_time"]).as_dict()
    return None, validate_fields(problem, fields, request["validation"])


def _dynamic_work(task: Any, notify: Notify, channel: socket.socket | None) -> dict[str, Any] | None:
    from planbench.bench.wire import BadField, clean_result
    from planbench.reactive.bench import serve_run

    if channel is None:
        raise ValueError("a closed-loop run needs its channel to the simulation")
    fields = serve_run(task.problem_ref, task.planner, task.settings, task.seed, channel, notify)
    if fields is None:
        return None
    try:
        return clean_result(fields)
    except BadField as bad:  # e.g. an exception text that is not valid text
        fields.update(message=f"the run could not be prepared ({bad})", traceback="")
        return clean_result(fields)


def _dynamic_judge(
    request: dict[str, Any], arrays: dict[str, Any], channel: socket.socket | None
) -> tuple[dict[str, Any], dict[str, Any]]:
    from planbench.bench.snapshot import restore
    from planbench.bench.wire import clean_info
    from planbench.reactive.bench import simulate_run

    if channel is None:
        raise ValueError("a closed-loop run needs its channel to the controller")
    scenario = restore(request["snapshot"])
    cpu = request.get("cpu")
    fields, evaluation = simulate_run(
        scenario, int(request["seed"]), str(request["timing"]), channel, int(request["pid"]), cpu
    )
    info = fields["info"]
    try:
        info["controller"] = clean_info(info.get("controller", {}))
    except Exception as exc:  # the controller's diagnostics are its own: they never cost the run
        info["controller"] = {"info_error": f"not kept: {exc}"}
    return fields, evaluation


def registry_of(kind: RunKind) -> Any:
    """The registry of ``kind``'s entries."""
    from planbench.registry import CONTROLLERS, REGISTRY

    return CONTROLLERS if kind.entry == "controller" else REGISTRY


def expand(kind: RunKind, selectors: Any) -> list[Any]:
    """The problem references of ``kind``'s selectors (problems or scenarios)."""
    from planbench.bench.suite import expand_problems, expand_scenarios

    return expand_scenarios(selectors) if kind.entry == "controller" else expand_problems(selectors)


KINDS: dict[str, RunKind] = {
    "static": RunKind(
        "static",
        entry="planner",
        channel=False,
        fresh_worker=False,
        answer_in_time=True,
        work=_static_work,
        judge=_static_judge,
    ),
    "dynamic": RunKind(
        "dynamic",
        entry="controller",
        channel=True,
        fresh_worker=True,
        answer_in_time=False,
        work=_dynamic_work,
        judge=_dynamic_judge,
    ),
}


def kind_of(name: str) -> RunKind:
    """The :class:`RunKind` called ``name`` (a ``ValueError`` naming the kinds otherwise)."""
    try:
        return KINDS[name]
    except KeyError:
        raise ValueError(f"unknown run kind {name!r}: one of {sorted(KINDS)}") from None
