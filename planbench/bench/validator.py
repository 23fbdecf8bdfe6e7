"""The validator process: computes verdicts where no planner code has ever run.

Started by :mod:`planbench.bench.runner` with ``spawn`` (a fresh interpreter that imports
planbench's core and never a planner or plugin), one per worker slot. A planner that patches
planbench, numpy or coal in its own worker cannot reach this process, so it cannot change its own
verdict or a later run's. The runner kills it (and starts another) when a validation passes
``validation_timeout``, which keeps its own loop free to enforce the other workers' deadlines.

Messages, all data-only (:mod:`planbench.bench.wire`), never pickles:

- in: ``{"type": "validate", "run": id, "problem_ref": ..., "validation": {...}, "kind": "static"
  or "dynamic", "result": {...}}``
  with the result's ``path`` and ``times`` arrays; already checked by the parent;
- out: ``{"type": "ready"}`` once imports are done, then per run
  ``{"type": "verdict", "run": id, "evaluation": {...}, "validation_time": s}``, or ``"error"``
  (the traceback) where validation itself raised.
"""

from __future__ import annotations

import os
import signal
import time
import traceback
from typing import Any

from planbench.bench.procs import OutputFile, detach, limit_threads, watch_parent
from planbench.bench.wire import clean_result, decode, encode
from planbench.datasets import load_problem
from planbench.planner import PlanResult, PlanStatus
from planbench.validate import ValidationSettings, evaluate

__all__ = ["validate_fields", "validator_main"]


def _problem(ref: str) -> Any:
    return load_problem(ref)


def validate_fields(
    problem: Any, fields: dict[str, Any], validation: dict[str, Any], kind: str = "static"
) -> dict[str, Any]:
    """``planbench.evaluate`` of a checked raw result (see :func:`planbench.bench.wire.clean_result`);
    ``problem`` is a problem or its reference. ``kind="dynamic"``: ``problem`` is a scenario's
    reference and the result a closed-loop run's (:func:`planbench.reactive.bench.validate_run_fields`)."""
    if kind == "dynamic":
        from planbench.reactive.bench import validate_run_fields
        from planbench.reactive.sets import load_scenario

        return validate_run_fields(load_scenario(problem), fields)
    if isinstance(problem, str):
        problem = _problem(problem)
    result = PlanResult(
        PlanStatus(fields["status"]),
        path=fields["path"],
        times=fields["times"],
        target=fields["target"],
        message=fields["message"],
        info=fields["info"],
        planning_time=fields["planning_time"],
        setup_time=fields["setup_time"],
    )
    return evaluate(problem, result, ValidationSettings(**validation)).as_dict()


def _answer(msg: dict[str, Any], arrays: dict[str, Any]) -> dict[str, Any]:
    run = msg.get("run")
    t0 = time.perf_counter()
    try:
        fields = clean_result({**msg["result"], "path": arrays.get("path"), "times": arrays.get("times")})
        evaluation = validate_fields(msg["problem_ref"], fields, msg["validation"], msg.get("kind", "static"))
    except Exception:
        return {"type": "verdict", "run": run, "error": traceback.format_exc()[-8000:]}
    return {"type": "verdict", "run": run, "evaluation": evaluation, "validation_time": time.perf_counter() - t0}


def validator_main(conn: Any, output_path: str, parent_pid: int, threads: int = 1) -> None:
    """Entry point of a validator process (see the module docstring)."""
    detach(parent_pid)
    watch_parent(parent_pid)
    limit_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    OutputFile(output_path).open_for_child()
    conn.send_bytes(encode({"type": "ready", "pid": os.getpid()}))
    while True:
        try:
            data = conn.recv_bytes()
        except (EOFError, OSError):
            return
        header, arrays = decode(data)
        if header.get("type") == "stop":
            return
        conn.send_bytes(encode(_answer(header, arrays)))
