"""``planbench check NAME``: the conformance checker of a planner (or a controller) in a process of
its own.

A third-party plugin may crash the interpreter (a segfault in its C++), hang, or call ``exit``;
checked in the caller's process, it would take the caller down with it (a whole pytest session).
Here the check runs in a spawned process that answers with data only; a process that dies, or does
not answer within ``timeout`` seconds, is a verdict of its own, not a crash of the caller.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from dataclasses import dataclass, field
from typing import Any

from planbench.bench.procs import detach, kill_group

__all__ = ["CheckOutcome", "check_in_subprocess"]

KINDS = ("planner", "controller")


@dataclass(frozen=True)
class CheckOutcome:
    """What the check found: ``findings`` (empty and ``failure`` empty: conformant), or
    ``failure``, why there is no answer (the process crashed or timed out, or the name is unknown)."""

    name: str
    kind: str
    findings: list[str] = field(default_factory=list)
    failure: str = ""
    unknown: bool = False

    @property
    def conformant(self) -> bool:
        return not self.findings and not self.failure


def _check_main(conn: Any, name: str, kind: str, parent_pid: int) -> None:
    detach(parent_pid)
    from planbench.errors import PlanbenchError

    try:
        if kind == "controller":
            from planbench.reactive.conformance import check_controller
            from planbench.registry import CONTROLLERS

            CONTROLLERS.resolve(name)  # an unknown name is an error (exit code 2), not a finding
            findings = [f"{f.check}: {f.message}" for f in check_controller(name)]
        else:
            from planbench.conformance import check_planner

            findings = list(check_planner(name))
        conn.send({"findings": [str(f) for f in findings]})
    except PlanbenchError as exc:  # an unknown name, a plugin that cannot be loaded
        conn.send({"error": str(exc), "planbench_error": True})
    except Exception as exc:  # the plugin raised where the checker does not catch it
        conn.send({"error": f"the check raised {type(exc).__name__}: {exc}", "planbench_error": False})


def check_in_subprocess(name: str, kind: str = "planner", timeout: float = 300.0) -> CheckOutcome:
    """Run the conformance checker of ``name`` (a registered name or ``module:Attr``) in a spawned
    process and say what it found (:class:`CheckOutcome`)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_check_main, args=(child, name, kind, os.getpid()), daemon=True, name="planbench-check")
    proc.start()
    child.close()
    try:
        if not parent.poll(timeout):
            proc.join(0.5)
            if proc.exitcode is None:
                return CheckOutcome(name, kind, failure=f"the check did not finish within {timeout:g} s")
            return CheckOutcome(name, kind, failure=_death(proc.exitcode))
        try:
            answer = parent.recv()
        except (EOFError, OSError):
            proc.join(5)
            return CheckOutcome(name, kind, failure=_death(proc.exitcode))
        if "error" in answer:
            return CheckOutcome(name, kind, failure=str(answer["error"]), unknown=bool(answer.get("planbench_error")))
        return CheckOutcome(name, kind, findings=[str(f) for f in answer.get("findings", [])])
    finally:
        kill_group(proc.pid)
        proc.join(5)
        parent.close()


def _death(code: int | None) -> str:
    if code is None:
        return "the check's process gave no answer"
    if code < 0:
        try:
            sig = signal.Signals(-code).name
        except ValueError:
            sig = f"signal {-code}"
        return f"the plugin crashed the check's process ({sig})"
    return f"the check's process ended with exit code {code} before answering"
