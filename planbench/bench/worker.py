"""The worker process: receive runs, plan each, send back the raw result as data. It never validates.

A closed-loop run (:mod:`planbench.bench.kinds`) makes the worker a controller's process instead:
fresh, confined before the controller is imported, answering the simulation in the slot's
validator over the socket it received with the run, and ended after it; it sends the parent only
"planning starts", or an ``error`` when the controller could not be set up.

Started by :mod:`planbench.bench.runner` with the ``spawn`` method, so it is a fresh interpreter
that imports planners by name or ``"module:Attr"``. This is the only process where planner code
runs, so nothing it says is trusted:

- **No verdicts here.** A planner could patch planbench, numpy or coal in this process; a verdict
  computed here would be the planner's to choose (its own, and a later run's in the same worker).
  The worker sends the raw result (status, path, times, target, message, info, times measured,
  traceback, pid); the verdict comes from :mod:`planbench.bench.validator`, a process no planner
  code has touched.
- **Data, not pickles.** Messages are :mod:`planbench.bench.wire` bytes (JSON + float64 arrays),
  so the parent only parses them: a ``__reduce__`` in a planner's object cannot run there.
- **Checked before sending.** :func:`planbench.bench.wire.clean_result` turns what the planner
  returned into plain values or names the field it cannot keep (an integer past 64 bits, an
  exception as ``message``, an object in ``info``, an ``info`` of megabytes, a path of the wrong
  shape); such a run is sent as an ``error`` naming the field. The parent checks again.
- **Contained before the first plugin import** (:func:`planbench.bench.sandbox.enter`): its
  scratch folder is its current folder, ``TMPDIR`` and numba's cache, and the only place it may
  write; it signals no process outside its sandbox; it joined its cgroup before forking its reaper.
  It runs code of one plugin only (the parent sees to it).
- **Process hygiene** (:mod:`planbench.bench.procs`): a session of its own (its group is its pid,
  so the parent's ``killpg`` takes a planner's subprocesses too), ``PR_SET_PDEATHSIG`` and a
  parent watch so it dies with the benchmark (kill -9 included), and a forked reaper that kills
  the group once the worker is gone. fds 1 and 2 go to a file the parent keeps bounded and reads
  the tail of into each row, so C code's output is caught too and nothing reaches the terminal.
- ``memory_limit`` [MiB] caps the address space (``RLIMIT_AS``) during each run; a run that met
  ``MemoryError`` ends the worker after its result is sent (its heap may be in any state).

Messages to the parent: ``{"type": "ready"}`` once imports are done; ``{"type": "phase", "run":
id, "phase": "plan"}`` when setup has finished and the timed query starts; ``{"type": "done",
"run": id, "result": {...}}`` with the ``path`` and ``times`` arrays. The parent's messages are
data too: ``{"type": "run", "run": id, "task": {...}}`` (a :class:`~planbench.bench.task.RunTask`
as :meth:`~planbench.bench.task.RunTask.to_wire` gives it) and ``{"type": "stop"}``.
"""

from __future__ import annotations

import faulthandler
import math
import os
import resource
import signal
import socket
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Mapping
from multiprocessing.reduction import recv_handle
from typing import Any

from planbench.bench import sandbox
from planbench.bench.kinds import kind_of
from planbench.bench.procs import (
    OutputFile,
    detach,
    join_cgroup,
    limit_threads,
    start_reaper,
    watch_parent,
)
from planbench.bench.records import ran_out_of_memory, record_from
from planbench.bench.task import RunTask
from planbench.bench.validator import validate_fields
from planbench.bench.wire import BadField, BadMessage, clean_result, decode, encode
from planbench.harness import plan
from planbench.planner import PlanResult, PlanStatus
from planbench.problems.datasets import load_problem
from planbench.registry import REGISTRY

__all__ = ["WORK", "error_fields", "plan_one", "run_one", "worker_main"]


class _PhaseReporter:
    """Wraps a planner instance to tell the parent when setup ends and planning starts."""

    def __init__(self, inner: Any, notify: Callable[[str], None]) -> None:
        self._inner = inner
        self._notify = notify

    def setup(self, problem: Any) -> None:
        self._inner.setup(problem)
        self._notify("plan")

    def plan(self, problem: Any, **kwargs: Any) -> Any:
        return self._inner.plan(problem, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def _problem(ref: str) -> Any:
    return load_problem(ref)


def _set_memory_limit(mib: float) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    want = int(mib * 2**20) if mib > 0 else hard
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    resource.setrlimit(resource.RLIMIT_AS, (want, hard))


def error_fields(message: str, tb: str = "", **known: Any) -> dict[str, Any]:
    """Raw-result fields of an ``error`` run (plain values, so they pass :func:`clean_result`)."""
    fields: dict[str, Any] = {
        "status": "error",
        "message": message,
        "target": "pose",
        "info": {},
        "planning_time": math.nan,
        "setup_time": math.nan,
        "wall_time": math.nan,
        "traceback": tb,
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "prepared": True,
        "path": None,
        "times": None,
    }
    fields.update(known)
    return fields


def _result_fields(result: Any) -> dict[str, Any]:
    """The fields of a planner's result, as they are (checked afterwards by :func:`clean_result`)."""
    if not isinstance(result, PlanResult):
        raise BadField("result", f"plan() gave a {type(result).__name__}, not a PlanResult")
    status = result.status
    info = result.info
    tb = ""
    if isinstance(info, Mapping) and "traceback" in info:
        tb = info["traceback"]
        info = {k: v for k, v in info.items() if k != "traceback"}
    return {
        "status": status.value if isinstance(status, PlanStatus) else status,
        "message": result.message,
        "target": result.target,
        "info": info,
        "planning_time": result.planning_time,
        "setup_time": result.setup_time,
        "traceback": tb,
        "path": result.path,
        "times": result.times,
    }


def plan_one(task: RunTask, notify: Callable[[str], None] = lambda phase: None) -> dict[str, Any]:
    """Plan one static run in this process and return its checked raw-result fields; never raises
    for a planner's fault (a bad result is an ``error`` run naming the bad field).

    The planner is built from ``task.planner`` and ``task.settings`` by
    :meth:`~planbench.registry.Registry.make`, as everywhere else.
    """
    t0 = time.perf_counter()
    base = {"pid": os.getpid(), "host": socket.gethostname()}
    try:
        problem = _problem(task.problem_ref)
        instance = REGISTRY.make(task.planner, **task.settings)
    except Exception as exc:  # a problem or planner that cannot be built is an ERROR of this run
        message = f"could not prepare the run: {type(exc).__name__}: {exc}"
        return error_fields(message, traceback.format_exc(), prepared=False, wall_time=time.perf_counter() - t0)
    _warm(instance, problem)
    try:
        result = plan(problem, _PhaseReporter(instance, notify), seed=task.seed, time_limit=task.time_limit)
    except Exception as exc:  # the harness could not take what the planner gave (e.g. a path patched in)
        message = f"the planner's result is unusable: {type(exc).__name__}: {exc}"
        return error_fields(message, traceback.format_exc(), wall_time=time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    timing: dict[str, Any] = {}
    try:
        fields = _result_fields(result)
        timing = {k: fields[k] for k in ("planning_time", "setup_time")}
        return clean_result({**fields, **base, "wall_time": wall, "prepared": True})
    except BadField as bad:
        return error_fields(f"the planner's result is unusable: {bad}", "", wall_time=wall, **_timing(timing))
    except Exception as exc:  # the planner's objects raised while being read
        message = f"the planner's result could not be read: {type(exc).__name__}"
        return error_fields(message, traceback.format_exc(), wall_time=wall, **_timing(timing))


_WARMED: set[type] = set()


def _warm(instance: Any, problem: Any) -> None:
    """Compile the planner's numba code (or load it from numba's on-disk cache) before the timed
    setup of its first run in this worker, so that no run's setup time holds compilation: one
    untimed ``setup`` of the run's own problem, for planners that say they run numba code
    (``use_numba``, the IK-loop planners). A failure here is left to the timed run to meet."""
    cls = type(instance)
    if cls in _WARMED or not getattr(instance, "use_numba", False):
        return
    _WARMED.add(cls)
    try:
        instance.setup(problem)
    except Exception:  # the timed setup will raise it again, as the run's own error
        pass


def _timing(timing: dict[str, Any]) -> dict[str, float]:
    """The measured times that are plain numbers (the harness's own, unless a planner patched it)."""
    return {k: float(v) for k, v in timing.items() if type(v) in (float, int)}


def run_one(task: RunTask) -> dict[str, Any]:
    """Plan and validate one static run in *this* process and return its record (as the runner
    builds it).

    For tools and tests that need a record without worker processes; the benchmark itself never
    validates where a planner ran (see the module docstring).
    """
    fields = plan_one(task)
    evaluation, validation_time = None, math.nan
    if fields["prepared"]:
        t0 = time.perf_counter()
        evaluation = validate_fields(task.problem_ref, fields, task.validation, task.postprocess, task.seed)
        validation_time = time.perf_counter() - t0
    return record_from(fields, evaluation, validation_time)


def _send(conn: Any, header: dict[str, Any], arrays: dict[str, Any] | None = None) -> None:
    conn.send_bytes(encode(header, arrays))


def _send_result(conn: Any, run: Any, fields: dict[str, Any]) -> None:
    head = {k: v for k, v in fields.items() if k not in ("path", "times")}
    try:
        data = encode({"type": "done", "run": run, "result": head}, {"path": fields["path"], "times": fields["times"]})
    except Exception as exc:  # e.g. MemoryError under the run's memory limit
        small = error_fields(f"could not send the result: {type(exc).__name__}: {exc}")
        small.pop("path"), small.pop("times")
        data = encode({"type": "done", "run": run, "result": small})
    conn.send_bytes(data)


def _out_of_memory(fields: dict[str, Any]) -> bool:
    message, tb = fields.get("message"), fields.get("traceback")
    return ran_out_of_memory(message if isinstance(message, str) else "", tb if isinstance(tb, str) else "")


class _Stopped(Exception):
    """The parent ended the run instead of letting planning start."""


def _await_go(conn: Any, run: Any) -> None:
    """Block until the parent says planning may start (it stamps the phase's start just before)."""
    header, _ = decode(conn.recv_bytes())
    if header.get("type") != "go" or header.get("run") != run:
        raise _Stopped(f"expected the parent's go for run {run}, got {str(header)[:80]}")


def worker_main(
    conn: Any,
    output_path: str,
    parent_pid: int,
    threads: int = 1,
    scratch: str = "",
    sandboxed: bool = False,
    cgroup: str = "",
    writable: tuple[str, ...] = (),
) -> None:
    """Entry point of a worker process (see the module docstring)."""
    detach(parent_pid)
    join_cgroup(cgroup)  # before the reaper is forked, so that it and every later process is in the cgroup
    start_reaper()  # before any thread starts, and outside the sandbox: the plugin cannot signal it
    OutputFile(output_path).open_for_child()
    state = sandbox.enter(scratch or tempfile.mkdtemp(prefix="planbench-scratch-"), sandboxed, tuple(writable))
    watch_parent(parent_pid)
    limit_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    faulthandler.enable()
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # the parent asks where a run hangs
    _send(conn, {"type": "ready", "pid": os.getpid(), "sandbox": state})
    while True:
        try:
            header, _ = decode(conn.recv_bytes())
        except (EOFError, OSError, BadMessage):  # the parent is gone (or broken): nothing more to do
            return
        if header.get("type") != "run":
            return
        run = header.get("run")
        channel = None
        try:
            if header.get("channel"):  # a closed-loop run: its end of the socket pair follows
                channel = socket.socket(fileno=recv_handle(conn))
            task = RunTask.from_wire(header.get("task"))
        except (BadMessage, OSError) as exc:  # planbench's own fault: still a row
            _send_result(conn, run, error_fields(f"the worker received a malformed task: {exc}", prepared=False))
            return
        _set_memory_limit(task.memory_limit)

        kind = kind_of(task.kind)

        def notify(phase: str, run: Any = run, wait: bool = kind.answer_in_time) -> None:
            _send(conn, {"type": "phase", "run": run, "phase": phase})
            if wait:  # the parent's clock starts the plan phase: planning starts on its word
                _await_go(conn, run)

        try:
            fields = WORK[kind.name](task, notify, channel)
        except Exception as exc:  # planbench's own fault, or a planner that broke it: still a row
            fields = error_fields(f"the worker failed: {type(exc).__name__}: {exc}", traceback.format_exc())
        if channel is not None:
            channel.close()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # a planner may have replaced or closed them
                pass
        if fields is not None:
            _send_result(conn, run, fields)
        if kind.fresh_worker or fields is None or _out_of_memory(fields):
            return  # one run only, or its heap may be in any state: the runner starts a fresh worker


Notify = Callable[[str], None]


def _static_work(task: RunTask, notify: Notify, channel: socket.socket | None) -> dict[str, Any]:
    return plan_one(task, notify)


def _dynamic_work(task: RunTask, notify: Notify, channel: socket.socket | None) -> dict[str, Any] | None:
    from planbench.reactive.bench import serve_run  # on use: a closed-loop worker only

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


WORK: dict[str, Callable[[RunTask, Notify, socket.socket | None], dict[str, Any] | None]] = {
    "static": _static_work,
    "dynamic": _dynamic_work,
}
"""What each run kind (:data:`planbench.bench.kinds.KINDS`) does in the worker:
``work(task, notify, channel)`` -> the raw result fields, or None when the run's record comes from
the validator (a closed loop, simulated there)."""
