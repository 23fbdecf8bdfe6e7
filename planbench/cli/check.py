"""``planbench check NAME``: the conformance checker of a planner (or a controller) in a process of
its own.

A third-party plugin may crash the interpreter (a segfault in its C++), hang, or call ``exit``;
checked in the caller's process, it would take the caller down with it (a whole pytest session).
Here the check runs in a spawned process that answers with data only; a process that dies, or does
not answer within ``timeout`` seconds, is a verdict of its own, not a crash of the caller. Planners and
controllers answer with the same :class:`~planbench.conformance.ConformanceReport` (each named check
passed, failed or not run), printed the same way (:meth:`CheckOutcome.lines`).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from dataclasses import dataclass
from typing import Any

from planbench.bench.procs import detach, kill_group
from planbench.conformance import ConformanceReport

__all__ = ["CheckOutcome", "check_in_subprocess"]

KINDS = ("planner", "controller")


@dataclass(frozen=True)
class CheckOutcome:
    """What the check found: its ``report`` (every named check passed: conformant), or ``failure``,
    why there is none (the process crashed or timed out, or the name is unknown)."""

    name: str
    kind: str
    report: ConformanceReport | None = None
    failure: str = ""
    unknown: bool = False

    @property
    def findings(self) -> list[str]:
        """Each finding as ``check: message``."""
        return [str(f) for f in self.report.findings] if self.report is not None else []

    @property
    def conformant(self) -> bool:
        return not self.failure and self.report is not None and self.report.conformant

    def lines(self) -> list[str]:
        """The verdict, then the report (or why there is none), as ``planbench check`` prints it."""
        verdict = "conformant" if self.conformant else "NOT conformant"
        detail = [f"- {self.failure}"] if self.failure or self.report is None else self.report.lines()
        return [f"{self.kind} {self.name}: {verdict}", *(f"  {line}" for line in detail)]


def _check_main(conn: Any, name: str, kind: str, parent_pid: int) -> None:
    detach(parent_pid)
    from planbench.errors import PlanbenchError

    try:
        if kind == "controller":
            from planbench.reactive.conformance import controller_report
            from planbench.registry import CONTROLLERS

            CONTROLLERS.resolve(name)  # an unknown name is an error (exit code 2), not a finding
            report = controller_report(name)
        else:
            from planbench.conformance import planner_report

            report = planner_report(name)
        conn.send({"report": report.to_data()})
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
        if isinstance(answer, dict) and "error" in answer:
            return CheckOutcome(name, kind, failure=str(answer["error"]), unknown=bool(answer.get("planbench_error")))
        try:
            return CheckOutcome(name, kind, ConformanceReport.from_data(answer["report"]))
        except (TypeError, KeyError):
            return CheckOutcome(name, kind, failure="the check's process answered with something else than a report")
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
