"""Run many benchmark runs in parallel worker processes, each run isolated, each with hard limits.

Design (asv's and OMPL Benchmark's idea, our own code):

- **Processes, started with ``spawn``.** Every worker is a fresh interpreter. ``fork`` would copy a
  parent that holds threads (rich's progress refresher, BLAS / numba / OpenMP pools) and forked
  children of a threaded process can deadlock; ``spawn`` costs ~1 s per worker, paid once per worker
  and not counted in any run. Planners are passed by registered name or ``"module:Attr"`` string,
  so a worker imports exactly what the run needs (decorator registrations made in the parent do not
  exist in a spawned worker).
- **Long-lived workers, one run at a time each.** A worker plans and validates a run and sends the
  record back. Runs of a planner marked ``fresh_process`` (a process-wide RNG, as in OMPL, or any
  global state) get a worker that has run nothing before, so their result depends only on the run.
- **Hard limits in the parent, per phase.** Setup (problem loading, planner construction and
  ``setup()``): ``setup_timeout``; planning: ``time_limit + grace``; validation:
  ``validation_timeout`` [s]. Past its deadline the worker is killed (SIGKILL) and the run is
  recorded as ``timeout`` with the phase in its message. A worker that dies during a run (segfault,
  ``os._exit``, the OOM killer, SIGKILL) gives a ``crash`` record with the exit code or signal and
  the tail of the worker's stderr (faulthandler prints the Python traceback of a fatal signal
  there). An exception in the planner is the harness's ``error`` record with its traceback.
  ``memory_limit`` [MiB] caps a worker's address space (``RLIMIT_AS``), so exhausting it raises
  ``MemoryError`` in the planner (an ``error``) instead of taking the machine down.
- **One thread per worker by default** (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
  ``MKL_NUM_THREADS``, ``NUMBA_NUM_THREADS`` set in the worker): ``--jobs`` workers use ``--jobs``
  cores, and results do not depend on how many threads a parallel reduction had.
- The parent is the only database writer: it hands each record to ``on_record`` as soon as the run
  ends.
"""

from __future__ import annotations

import logging
import math
import multiprocessing as mp
import multiprocessing.connection
import os
import shutil
import signal
import tempfile
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from planbench.errors import PlanbenchError

log = logging.getLogger(__name__)

__all__ = ["Runner", "default_jobs", "failure_record"]

Record = dict[str, Any]
Task = dict[str, Any]


def default_jobs() -> int:
    """All the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (not Linux)
        return max(1, os.cpu_count() or 1)


def failure_record(status: str, message: str, traceback: str = "", planning_time: float = math.nan) -> Record:
    """A record for a run that produced none itself (killed or crashed)."""
    from planbench.validate import Evaluation

    evaluation = Evaluation(False, f"{status}: {message}", status, planning_time, math.nan).as_dict()
    return {
        "evaluation": evaluation,
        "message": message,
        "traceback": traceback,
        "path": None,
        "times": None,
        "info": {},
        "wall_time": math.nan,
        "validation_time": math.nan,
        "elapsed": math.nan,
        "pid": None,
        "host": "",
    }


@dataclass
class _Slot:
    """One worker process and the run it is doing."""

    proc: Any
    conn: Any
    stderr_path: str
    ready: bool = False
    runs: int = 0
    task: Task | None = None
    phase: str = ""
    phase_start: float = 0.0
    deadline: float = math.inf
    dispatched: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    closed: bool = False


class Runner:
    """Runs tasks (dicts built by :mod:`planbench.bench.benchmark`) on ``jobs`` worker processes."""

    def __init__(self, jobs: int | None = None, start_method: str = "spawn", threads_per_worker: int = 1) -> None:
        self.jobs = default_jobs() if not jobs else int(jobs)
        self.threads = int(threads_per_worker)
        if self.jobs < 1:
            raise PlanbenchError(f"--jobs must be >= 1, got {jobs}")
        self.ctx = mp.get_context(start_method)
        self._tmp = ""
        self._count = 0

    def run(self, tasks: Sequence[Task], on_record: Callable[[Task, Record], None]) -> None:
        """Run every task; call ``on_record(task, record)`` in this process as each one ends.

        On KeyboardInterrupt (or any exception) the workers are killed and the exception goes on;
        records already handed to ``on_record`` are kept, runs in flight are not recorded.
        """
        if not tasks:
            return
        pending: deque[Task] = deque(tasks)
        self._tmp = tempfile.mkdtemp(prefix="planbench-workers-")
        slots: list[_Slot] = []
        try:
            slots = [self._start() for _ in range(min(self.jobs, len(pending)))]
            start_failures = 0
            while pending or any(s.task is not None for s in slots):
                for i, slot in enumerate(slots):
                    if slot.task is None and slot.ready and pending:
                        if pending[0].get("fresh_process") and slot.runs > 0:
                            self._stop(slot)
                            slots[i] = self._start()
                            continue
                        self._dispatch(slot, pending.popleft())
                self._wait(slots)
                kept: list[_Slot] = []
                for slot in slots:
                    self._drain(slot, on_record)
                    now = time.monotonic()
                    if slot.task is not None and now > slot.deadline:
                        self._kill(slot, dump_stack=True)
                        record = self._timeout_record(slot, now)
                        record["elapsed"] = now - slot.dispatched
                        on_record(slot.task, record)
                        slot.task = None
                    elif not slot.proc.is_alive():
                        self._drain(slot, on_record)
                        if slot.task is not None:
                            record = self._crash_record(slot)
                            record["elapsed"] = now - slot.dispatched
                            on_record(slot.task, record)
                            slot.task = None
                        elif not slot.ready:
                            start_failures += 1
                            if start_failures > 3:
                                raise PlanbenchError(
                                    "benchmark worker processes die before they start (a script that runs a "
                                    "benchmark needs an `if __name__ == '__main__':` guard: workers are "
                                    "spawned and import the main module); last stderr:\n" + _tail(slot.stderr_path)
                                )
                    else:
                        kept.append(slot)
                        continue
                    # the worker is gone: replace it while there is work left
                    self._close(slot)
                    if pending:
                        kept.append(self._start())
                slots = kept
        finally:
            for slot in slots:
                self._stop(slot)
            shutil.rmtree(self._tmp, ignore_errors=True)

    # -- workers -------------------------------------------------------------------------------

    def _start(self) -> _Slot:
        from planbench.bench.worker import worker_main

        self._count += 1
        path = os.path.join(self._tmp, f"worker-{self._count}.stderr")
        parent, child = self.ctx.Pipe(duplex=True)
        proc = self.ctx.Process(  # type: ignore[attr-defined]
            target=worker_main, args=(child, path, self.threads), daemon=True, name=f"planbench-worker-{self._count}"
        )
        proc.start()
        child.close()
        return _Slot(proc, parent, path)

    def _dispatch(self, slot: _Slot, task: Task) -> None:
        now = time.monotonic()
        slot.task = task
        slot.runs += 1
        slot.dispatched = now
        slot.timings = {}
        self._enter(slot, "setup", now)
        slot.conn.send(task)

    def _enter(self, slot: _Slot, phase: str, now: float) -> None:
        task = slot.task or {}
        limits = {
            "setup": float(task.get("setup_timeout", 120.0)),
            "plan": float(task.get("time_limit", 5.0)) + float(task.get("grace", 5.0)),
            "validate": float(task.get("validation_timeout", 300.0)),
        }
        slot.timings[slot.phase] = now - slot.phase_start
        slot.phase = phase
        slot.phase_start = now
        slot.deadline = now + limits[phase]

    def _wait(self, slots: list[_Slot]) -> None:
        waitables = [s.conn for s in slots] + [s.proc.sentinel for s in slots]
        deadlines = [s.deadline for s in slots if s.task is not None]
        timeout = 1.0
        if deadlines:
            timeout = min(timeout, max(0.0, min(deadlines) - time.monotonic()) + 0.01)
        multiprocessing.connection.wait(waitables, timeout)

    def _drain(self, slot: _Slot, on_record: Callable[[Task, Record], None]) -> None:
        try:
            while slot.conn.poll():
                msg = slot.conn.recv()
                if msg[0] == "ready":
                    slot.ready = True
                elif msg[0] == "phase" and slot.task is not None and msg[1] == slot.task["key"]:
                    self._enter(slot, msg[2], time.monotonic())
                elif msg[0] == "done" and slot.task is not None and msg[1] == slot.task["key"]:
                    task, slot.task = slot.task, None
                    slot.deadline = math.inf
                    record = msg[2]
                    record["elapsed"] = time.monotonic() - slot.dispatched
                    on_record(task, record)
        except (EOFError, OSError):
            pass  # the worker died; its slot is handled by the caller

    def _timeout_record(self, slot: _Slot, now: float) -> Record:
        task = slot.task or {}
        elapsed = now - slot.phase_start
        if slot.phase == "plan":
            msg = (
                f"planning ran {elapsed:.1f} s, past the time limit of {task.get('time_limit')} s "
                f"+ {task.get('grace')} s grace; worker process killed"
            )
            planning_time = elapsed
        elif slot.phase == "setup":
            msg = (
                f"setup (problem loading, planner setup) ran past {task.get('setup_timeout')} s; worker process killed"
            )
            planning_time = math.nan
        else:
            msg = f"validation ran past {task.get('validation_timeout')} s; worker process killed"
            planning_time = slot.timings.get("plan", math.nan)
        return failure_record("timeout", msg, _tail(slot.stderr_path), planning_time)

    def _crash_record(self, slot: _Slot) -> Record:
        code = slot.proc.exitcode
        if code is not None and code < 0:
            try:
                how = f"signal {signal.Signals(-code).name} ({-code})"
            except ValueError:
                how = f"signal {-code}"
        else:
            how = f"exit code {code}"
        msg = f"worker process died with {how} during {slot.phase}"
        return failure_record("crash", msg, _tail(slot.stderr_path))

    def _kill(self, slot: _Slot, dump_stack: bool = False) -> None:
        if slot.proc.is_alive():
            if dump_stack and slot.proc.pid is not None:  # faulthandler writes the stack to stderr
                try:
                    os.kill(slot.proc.pid, signal.SIGUSR1)
                    slot.proc.join(0.3)
                except OSError:
                    pass
            slot.proc.kill()
        slot.proc.join(5)

    def _stop(self, slot: _Slot) -> None:
        if slot.closed:
            return
        if slot.proc.is_alive() and slot.task is None and slot.ready:
            try:
                slot.conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            slot.proc.join(2)
        self._kill(slot)
        self._close(slot)

    def _close(self, slot: _Slot) -> None:
        if slot.closed:
            return
        slot.closed = True
        try:
            slot.conn.close()
        except OSError:
            pass
        if slot.proc.exitcode is not None:
            slot.proc.close()


def _tail(path: str, limit: int = 8000) -> str:
    """The last ``limit`` characters of a worker's stderr file."""
    try:
        with open(path, errors="replace") as f:
            text = f.read()
    except OSError:
        return ""
    return text[-limit:]
