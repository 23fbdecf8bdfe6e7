"""The two kinds of benchmark run behind one seam: what the worker does, what the validator does.

The runner (:mod:`planbench.bench.runner`), the worker and the validator know runs only through a
:class:`RunKind`, found by the task's ``kind`` in :data:`KINDS`; what a kind does in the worker is
:data:`planbench.bench.worker.WORK`, in the validator :data:`planbench.bench.validator.JUDGE`:

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

from dataclasses import dataclass
from typing import Any

__all__ = ["KINDS", "RunKind", "expand", "kind_of", "registry_of"]


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
    ),
    "dynamic": RunKind(
        "dynamic",
        entry="controller",
        channel=True,
        fresh_worker=True,
        answer_in_time=False,
    ),
}


def kind_of(name: str) -> RunKind:
    """The :class:`RunKind` called ``name`` (a ``ValueError`` naming the kinds otherwise)."""
    try:
        return KINDS[name]
    except KeyError:
        raise ValueError(f"unknown run kind {name!r}: one of {sorted(KINDS)}") from None
