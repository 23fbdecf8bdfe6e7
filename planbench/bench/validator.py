"""The validator process: computes verdicts where no planner code has ever run.

Started by :mod:`planbench.bench.runner` with ``spawn`` (a fresh interpreter that imports
planbench's core and never a planner or plugin), one per worker slot. A planner that patches
planbench, numpy or coal in its own worker cannot reach this process, so it cannot change its own
verdict or a later run's. The runner kills it (and starts another) when a validation passes
``validation_timeout``, which keeps its own loop free to enforce the other workers' deadlines.

It also runs the closed loop of a ``dynamic`` run (:mod:`planbench.bench.kinds`): the simulation
against the controller in the run's worker, over a socket pair the parent hands both of them.
The process is marked undumpable, so a confined controller cannot reach into its memory.

It never reads a problem or scenario file: the parent sends the problem's or scenario's data as
it read it before any plugin ran (:mod:`planbench.bench.snapshot`), and the files that data
points to (robot, meshes, clouds) are checked against their hashes from then.

Messages, all data-only (:mod:`planbench.bench.wire`), never pickles:

- in: ``{"type": "validate", "run": id, "kind": "static", "snapshot": ..., "validation":
  {...}, "postprocess": {...}, "seed": n, "result": {...}}`` with the result's ``path`` and
  ``times`` arrays, already checked by the parent; or ``{"type": "validate", "run": id, "kind":
  "dynamic", "snapshot": ..., "seed": n, "timing": ..., "pid": the controller's, "cpu": core or
  null}`` followed by the socket (``SCM_RIGHTS``);
- out: ``{"type": "ready"}`` once imports are done, then per run
  ``{"type": "verdict", "run": id, "evaluation": {...}, "validation_time": s}`` (with the run's
  ``result`` fields and its ``path`` and ``times`` arrays for a closed-loop run), or ``"error"``
  (the traceback) where validation itself raised.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import signal
import socket
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.reduction import recv_handle
from typing import Any

from planbench.bench.kinds import kind_of
from planbench.bench.postprocess import PostprocessSettings
from planbench.bench.postprocess import apply as apply_postprocess
from planbench.bench.procs import OutputFile, detach, limit_threads, watch_parent
from planbench.bench.snapshot import SnapshotChanged, restore
from planbench.bench.wire import clean_info, clean_result, decode, encode
from planbench.checking.certified import CertifiedChecker
from planbench.planner import PlanResult, PlanStatus
from planbench.problems.datasets import load_problem
from planbench.reactive.isolation import make_undumpable
from planbench.validate import Evaluation, ValidationSettings, evaluate, not_validated

__all__ = ["JUDGE", "validate_fields", "validator_main"]


def _problem(ref: str) -> Any:
    return load_problem(ref)


def validate_fields(
    problem: Any,
    fields: dict[str, Any],
    validation: dict[str, Any],
    postprocess: dict[str, Any] | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """``planbench.evaluate`` of a static run's checked raw result (see
    :func:`planbench.bench.wire.clean_result`); ``problem`` is a problem or its reference. With a
    ``postprocess`` stage (:class:`planbench.bench.postprocess.PostprocessSettings` fields), a valid path
    is then post-processed here, with the run's ``seed``, and its processed metrics added."""
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
    settings = ValidationSettings(**validation)
    limit = settings.validation_memory_limit if _IN_VALIDATOR else 0.0
    size = _address_space_mib()
    try:
        with _address_space_limit(size + limit if limit > 0 else 0.0):
            evaluation = evaluate(problem, result, settings)
            return _postprocessed(problem, result, evaluation, settings, postprocess or {}, seed).as_dict()
    except MemoryError:
        CertifiedChecker.forget(problem)  # its buffers may be half-built
        where = (
            f"past the validator's limit of {size:.0f} + {limit:g} MiB (ValidationSettings.validation_memory_limit); "
            "raise it in the suite's [validation] table, or return a shorter path"
            if limit > 0
            else "(no memory limit was set)"
        )
        return not_validated(result, f"not validated: validation ran out of memory, {where}").as_dict()


def _postprocessed(
    problem: Any,
    result: PlanResult,
    evaluation: Evaluation,
    settings: ValidationSettings,
    stage: dict[str, Any],
    seed: int,
) -> Evaluation:
    """``evaluation`` with the suite's post-processing stage applied; the stage never costs a run
    its verdict: where it raises (out of memory included), the run keeps its raw metrics, the
    reason in ``postprocess_note``."""
    try:
        return apply_postprocess(problem, result, evaluation, settings, PostprocessSettings(**stage), seed)
    except Exception as exc:
        if isinstance(exc, MemoryError):
            CertifiedChecker.forget(problem)  # its buffers may be half-built
        return dataclasses.replace(evaluation, postprocess_note=f"post-processing raised {type(exc).__name__}: {exc}")


# -- bounded validation: the validator's address space during one validation -----------------------

_IN_VALIDATOR = False
"""Set by :func:`validator_main`: only a validator process limits its own address space, never the
process of another caller of :func:`validate_fields` (:func:`planbench.bench.worker.run_one`)."""


def _address_space_mib() -> float:
    """This process's address space [MiB] (imports such as numpy, coal, pinocchio and toppra
    reserve far more than validation touches, so a limit is set above it, not absolutely)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * resource.getpagesize() / 2**20


@contextmanager
def _address_space_limit(mib: float) -> Iterator[None]:
    """``RLIMIT_AS`` at ``mib`` MiB (never above the current limit) while in the block; 0: unchanged."""
    saved = resource.getrlimit(resource.RLIMIT_AS)
    if mib > 0:
        lower = [x for x in saved if x != resource.RLIM_INFINITY]
        resource.setrlimit(resource.RLIMIT_AS, (min([int(mib * 2**20), *lower]), saved[1]))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, saved)


def _answer(conn: Any, msg: dict[str, Any], arrays: dict[str, Any]) -> bytes:
    """The verdict message for request ``msg`` (its kind's ``judge``), with the run's raw fields
    and arrays when this process made them (a closed-loop run)."""
    run = msg.get("run")
    t0 = time.perf_counter()
    channel = None
    try:
        kind = kind_of(str(msg.get("kind", "static")))
        if kind.channel:
            channel = socket.socket(fileno=recv_handle(conn))
        fields, evaluation = JUDGE[kind.name](msg, arrays, channel)
    except Exception:
        return encode({"type": "verdict", "run": run, "error": traceback.format_exc()[-8000:]})
    finally:
        if channel is not None:
            channel.close()
    answer = {"type": "verdict", "run": run, "evaluation": evaluation, "validation_time": time.perf_counter() - t0}
    if fields is None:
        return encode(answer)
    answer["result"] = {k: v for k, v in fields.items() if k not in ("path", "times")}
    return encode(answer, {"path": fields["path"], "times": fields["times"]})


def validator_main(conn: Any, output_path: str, parent_pid: int, threads: int = 1) -> None:
    """Entry point of a validator process (see the module docstring)."""
    global _IN_VALIDATOR
    _IN_VALIDATOR = True
    detach(parent_pid)
    make_undumpable()  # no confined controller may read or write this process's memory
    watch_parent(parent_pid)
    limit_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    OutputFile(output_path).open_for_child()
    # Validation imports toppra on first use (metrics.limited_duration), and toppra maps matplotlib:
    # imported now, they count in the address space a validation's limit is set above, not in the
    # share one validation may add (validate_fields).
    import toppra.algorithm  # noqa: F401
    import toppra.constraint  # noqa: F401

    conn.send_bytes(encode({"type": "ready", "pid": os.getpid()}))
    while True:
        try:
            data = conn.recv_bytes()
        except (EOFError, OSError):
            return
        header, arrays = decode(data)
        if header.get("type") == "stop":
            return
        conn.send_bytes(_answer(conn, header, arrays))


Judgement = tuple[dict[str, Any] | None, dict[str, Any]]


def _static_judge(request: dict[str, Any], arrays: dict[str, Any], channel: socket.socket | None) -> Judgement:
    fields = clean_result({**request["result"], "path": arrays.get("path"), "times": arrays.get("times")})
    try:
        problem = restore(request["snapshot"])
    except SnapshotChanged as exc:  # the run's problem is not the one the benchmark read: no verdict
        failure = f"error: {exc}; no verdict"
        return None, Evaluation(False, failure, "error", fields["planning_time"], fields["setup_time"]).as_dict()
    stage, seed = request.get("postprocess") or {}, int(request.get("seed", 0))
    return None, validate_fields(problem, fields, request["validation"], stage, seed)


def _dynamic_judge(request: dict[str, Any], arrays: dict[str, Any], channel: socket.socket | None) -> Judgement:
    from planbench.reactive.bench import simulate_run  # on use: a closed-loop validator only

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


JUDGE: dict[str, Callable[[dict[str, Any], dict[str, Any], socket.socket | None], Judgement]] = {
    "static": _static_judge,
    "dynamic": _dynamic_judge,
}
"""What each run kind (:data:`planbench.bench.kinds.KINDS`) does in the validator:
``judge(request, arrays, channel)`` -> (the run's raw fields when the validator made them, else
None; the evaluation as a dict)."""
