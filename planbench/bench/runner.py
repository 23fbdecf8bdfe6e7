"""Run many benchmark runs in parallel worker processes, each run isolated, each with hard limits, each
verdict computed where no planner code has run.

Design (asv's and OMPL Benchmark's idea, our own code):

- **Processes, started with ``spawn``.** Every worker is a fresh interpreter. ``fork`` would copy a
  parent that holds threads (rich's progress refresher, BLAS / numba / OpenMP pools) and forked
  children of a threaded process can deadlock; ``spawn`` costs ~1 s per worker, paid once per worker
  and not counted in any run. Planners are passed by registered name or ``"module:Attr"`` string,
  so a worker imports exactly what the run needs (decorator registrations made in the parent do not
  exist in a spawned worker).
- **A slot is a worker and a validator.** The worker (:mod:`planbench.bench.worker`) only plans
  and sends the raw result back as data (:mod:`planbench.bench.wire`: JSON and float64 bytes, never
  a pickle, so nothing a planner built can run code here). This process checks the result again
  (it does not trust the worker's checks), then the slot's validator
  (:mod:`planbench.bench.validator`), a spawned process that imports planbench's core and never a
  planner, computes the verdict. A planner that patches planbench, numpy or coal in its worker
  therefore changes neither its own verdict nor a later run's. The slot takes its next run only
  once the verdict is in, so ``--jobs`` processes compute at a time.
- **One plugin per worker, one run at a time.** A worker runs code of one planner label of one
  suite in its lifetime (:func:`plugin_of`); a slot takes the next run of its worker's plugin
  first and replaces the worker when none is left. Runs of a planner marked ``fresh_process`` (a
  process-wide RNG, as in OMPL, or any global state) get a worker that has run nothing before.
- **Contained.** Before any plugin code, a worker enters a Landlock sandbox that leaves it only its
  scratch folder to write and no process outside to signal (:mod:`planbench.bench.sandbox`), in a
  cgroup of its own that is killed with it (:class:`~planbench.bench.procs.Cgroups`). Validators
  judge by the problems and scenarios as this process read them before any worker started
  (:mod:`planbench.bench.snapshot`), and none starts once the interpreter's start-up hooks changed.
- **An answer counts only in time.** The plan phase is timed here: after setup the worker says so
  and waits for the go, stamped here just before it is sent; the result is stamped with the moment
  this loop woke to read it (so that time this loop spent on other slots is not charged to the
  run). That is the run's planning time (the worker's own figure is kept in ``info``). A result
  later than ``time_limit`` +
  :data:`~planbench.harness.HANDOFF_TOLERANCE` (by this clock or the worker's) is a ``timeout``
  row with success false, its path and metrics kept (``checks["in_time"]`` false).
- **Hard limits here, per phase.** Setup (problem loading, planner construction and ``setup()``):
  ``setup_timeout``; planning: ``time_limit + grace``; validation: ``validation_timeout`` [s]. Past
  its deadline the worker's whole process group (the planner's subprocesses included) or the
  validator is killed (SIGKILL) and the run is recorded as ``timeout`` with the phase in its
  message; this loop keeps enforcing the other slots' deadlines meanwhile. A worker that dies
  during a run (segfault, ``os._exit``, the OOM killer, SIGKILL) gives a ``crash`` record with the
  exit code or signal and the tail of its output (faulthandler prints the Python traceback of a
  fatal signal there). An exception in the planner is the harness's ``error`` record with its
  traceback; a result with a field the benchmark cannot keep is an ``error`` naming the field.
  ``memory_limit`` [MiB] caps a worker's address space (``RLIMIT_AS``) during a run, so exhausting
  it raises ``MemoryError`` (an ``error`` that names the limit) instead of taking the machine down.
- **Processes die with the benchmark.** Workers and validators run in sessions of their own, die
  with this process (``PR_SET_PDEATHSIG``, kill -9 included) and a worker's reaper then kills the
  planner's children (:mod:`planbench.bench.procs`).
- **Output captured.** A worker's fds 1 and 2 go to a file, cut back to its tail past 16 MiB; the
  last 8 KiB of a run's output are appended to its ``traceback`` under ``--- worker output (tail)
  ---``.
- **One thread per worker by default** (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
  ``MKL_NUM_THREADS``, ``NUMBA_NUM_THREADS`` set in the worker): ``--jobs`` workers use ``--jobs``
  cores, and results do not depend on how many threads a parallel reduction had.
- This process is the only database writer: it hands each record to ``on_record`` as soon as the
  run ends.
"""

from __future__ import annotations

import contextlib
import logging
import math
import multiprocessing as mp
import multiprocessing.connection
import os
import shutil
import signal
import socket
import struct
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from multiprocessing.reduction import send_handle
from typing import Any

from planbench.bench import sandbox, snapshot
from planbench.bench.kinds import RunKind, kind_of
from planbench.bench.procs import OUTPUT_HEADER, Cgroups, OutputFile, kill_group, thread_environment, worker_dir
from planbench.bench.records import Record, failure_record, ran_out_of_memory, record_from
from planbench.bench.task import RunTask
from planbench.bench.wire import MAX_MESSAGE_BYTES, BadField, BadMessage, clean_result, decode, encode
from planbench.errors import PlanbenchError
from planbench.harness import answered_late, late_message
from planbench.reactive.isolation import make_undumpable
from planbench.runtime import compile_cache
from planbench.validate import CLAIMED_SUCCESS, IN_TIME

log = logging.getLogger(__name__)

__all__ = ["Runner", "default_jobs"]

RECV_TIMEOUT = 5.0
"""[s] a child that stops in the middle of a message for this long is treated as broken."""
MAX_MESSAGES_PER_WAIT = 64
"""A child sends at most three messages per run; one that floods its connection is treated as broken."""


def default_jobs() -> int:
    """All the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (not Linux)
        return max(1, os.cpu_count() or 1)


PLAN_TIME_SLACK = (0.5, 0.1)
"""A worker's planning time below ``ratio * observed - seconds`` of the plan phase the parent saw
itself is not believed (the slack covers sending the result; a clock patched in the worker does not
fit in it)."""


def _check_planning_time(record: Record, observed: float | None) -> None:
    """Replace a planning time the worker under-reports with the plan phase the parent timed.

    The harness times planning in the worker, where planner code runs and could patch the clock;
    the parent's own clock bounds it from above (the phase also holds the hand-off of the result).
    """
    evaluation = record.get("evaluation") or {}
    reported = evaluation.get("planning_time")
    if observed is None or type(reported) is not float or not math.isfinite(reported):
        return
    ratio, seconds = PLAN_TIME_SLACK
    if reported >= ratio * observed - seconds:
        return
    evaluation["planning_time"] = observed
    note = (
        f"planning time: the worker reported {reported:.3f} s, the parent saw a {observed:.3f} s plan phase; "
        "the parent's time is recorded"
    )
    record["message"] = f"{record.get('message') or ''} [{note}]".strip()


def _charge_parent_time(record: Record, observed: float | None) -> None:
    """Make a static run's planning time the plan phase this process timed; the worker's own
    figure (planner code ran there, and could have patched its clock) is kept in ``info`` as
    ``worker_planning_time``, for information only.

    The phase runs from the go this process sent the waiting worker after its setup to the result,
    stamped when this loop woke to read it: the planner's query, the harness's bookkeeping and the
    hand-off of the result (tens of microseconds; ``docs/measurements.md``).
    """
    evaluation = record.get("evaluation") or {}
    if observed is None or "planning_time" not in evaluation:
        return
    info = record.get("info")
    if isinstance(info, dict):
        info["worker_planning_time"] = evaluation["planning_time"]
    evaluation["planning_time"] = observed


def _check_time_limit(record: Record, observed: float | None, time_limit: float) -> None:
    """Make a static run that answered after its time limit a ``timeout`` that did not succeed,
    whatever its path (kept, with its metrics, for inspection).

    The answer's time is the later of the plan phase timed here and the worker's own measure
    (which a planner could only lower, by patching the clock). A run that raised stays an ``error``.
    """
    evaluation = record.get("evaluation") or {}
    if observed is None or evaluation.get("status") in ("error", "crash"):
        return  # no answer reached this process (the worker was killed or died), or it raised
    times = [t for t in (observed, evaluation.get("planning_time")) if type(t) is float and math.isfinite(t)]
    checks = evaluation.get("checks")
    checks = checks if isinstance(checks, dict) else {}
    if not answered_late(max(times), time_limit) or (evaluation.get("status") == "timeout" and not checks):
        return  # in time, or a timeout without a path or a verdict, which says why itself
    path = "no path"
    if checks:
        valid = all(v for k, v in checks.items() if k not in (CLAIMED_SUCCESS, IN_TIME))
        path = f"its path ({'valid' if valid else 'invalid'}) and metrics are kept, not counted"
    late = late_message(max(times), time_limit)
    evaluation.update(status="timeout", success=False, failure=f"timeout: {late}; {path}")
    evaluation["checks"] = {**checks, IN_TIME: False}
    if late not in str(record.get("message") or ""):  # the worker's harness may have said it already
        record["message"] = f"{record.get('message') or ''} [{late}]".strip()


@dataclass
class _Child:
    """A spawned worker or validator and its connection (read with ``recv_bytes`` only)."""

    kind: str
    proc: Any
    conn: Any
    output: OutputFile
    scratch: str = ""
    """A worker's scratch folder: the one place its sandbox lets it write."""
    cgroup: str = ""
    """A worker's cgroup ("" without cgroups): killing it kills every process the plugin started."""
    plugin: tuple[str, ...] | None = None
    """The plugin (suite, label, planner) whose code this worker has run; it runs no other."""
    ready: bool = False
    runs: int = 0
    closed: bool = False
    spent: bool = False
    """A worker that ends after its run (it met MemoryError): it takes no other run."""

    @property
    def usable(self) -> bool:
        return not self.closed and self.proc.is_alive()


@dataclass
class _Slot:
    """One worker, one validator and the run they are doing."""

    worker: _Child
    validator: _Child
    task: RunTask | None = None
    run: int = 0
    phase: str = ""
    phase_start: float = 0.0
    deadline: float = math.inf
    dispatched: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    fields: dict[str, Any] | None = None
    index: int = 0
    channel: socket.socket | None = None
    """The validator's end of a closed-loop run's socket pair, until the validator has it."""

    @property
    def kind(self) -> RunKind:
        assert self.task is not None
        return kind_of(self.task.kind)


def _pid(child: _Child) -> int | None:
    """The child's pid, None once its process object is closed."""
    try:
        return child.proc.pid  # type: ignore[no-any-return]
    except ValueError:  # closed
        return None


class _ChildFailed(Exception):
    """A child's message could not be read (too long, stalled, malformed); the child is killed."""


class Runner:
    """Runs tasks (:class:`~planbench.bench.task.RunTask`, built by :mod:`planbench.bench.benchmark`)
    on ``jobs`` worker slots."""

    def __init__(
        self,
        jobs: int | None = None,
        start_method: str = "spawn",
        threads_per_worker: int = 1,
        pin: bool = True,
        sandboxed: bool = True,
    ) -> None:
        self.jobs = default_jobs() if not jobs else int(jobs)
        self.threads = int(threads_per_worker)
        if self.jobs < 1:
            raise PlanbenchError(f"--jobs must be >= 1, got {jobs}")
        self.ctx = mp.get_context(start_method)
        self._tmp = ""  # the workers' folder (``procs.worker_dir``), made with the first slot
        self._tmp_lock = -1  # the descriptor of its lock, held while this runner has the folder
        self._count = 0
        self._runs = 0
        self._start_failures = 0
        self._host = socket.gethostname()
        self._slots: list[_Slot] = []
        self.pin = pin
        """Closed-loop runs of slot ``i`` on the ``i``-th core this process may use (else on the core
        the simulation happens to be on when the run starts)."""
        self._cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else [0]
        self._woke = time.monotonic()
        """When :meth:`_wait` last returned: the time stamp of every message read after it (it
        arrived by then, or while this loop served other slots, which is not the run's time)."""
        self.sandboxed = sandboxed
        """Workers write only to their scratch folders and signal no process outside
        (:mod:`planbench.bench.sandbox`); where the kernel cannot, they run without, with a warning."""
        self.writable = sandbox.writable_folders()
        """Folders plugins may write besides their scratch folder (:data:`WRITABLE_VARIABLE`)."""
        self._cgroups: Cgroups | None = None
        self._snapshots: dict[tuple[str, str], dict[str, Any]] = {}
        """(entry, reference) -> what the validators judge by (:func:`planbench.bench.snapshot.take`)."""
        self._hooks: dict[str, tuple[int, int, int]] = {}
        """The interpreter's start-up hooks when the first slot started (:func:`startup_hooks`)."""
        self._warned: set[str] = set()
        self.warm_numba = True
        """Fill numba's shared cache of planbench's kernels before the first worker starts (once per
        install: 5-8 s), since sandboxed workers compile into caches of their own."""
        self.keep_warm = False
        """Restart a slot's dead worker or validator at once even when no task is pending (the next
        :meth:`feed` is expected)."""

    def run(self, tasks: Sequence[RunTask], on_record: Callable[[RunTask, Record], None]) -> None:
        """Run every task; call ``on_record(task, record)`` in this process as each one ends.

        On KeyboardInterrupt (or any exception) the workers are killed and the exception goes on;
        records already handed to ``on_record`` are kept, runs in flight are not recorded.
        """
        if not tasks:
            return
        try:
            self.feed(tasks, on_record)
        finally:
            self.close()

    def start(self, slots: int | None = None) -> None:
        """Start ``slots`` slots (default: ``jobs``) ahead of any run, so their start (~1 s) overlaps
        with other work; used by a caller that keeps the runner warm (:meth:`feed`)."""
        self._grow(self.jobs if slots is None else min(self.jobs, slots))

    def feed(self, tasks: Sequence[RunTask], on_record: Callable[[RunTask, Record], None]) -> None:
        """Like :meth:`run`, but the slots stay warm for the next call (a Ray actor runs one task per
        call on a warm slot); :meth:`close` ends them. An exception closes them too."""
        pending: deque[RunTask] = deque(tasks)
        try:
            self._take_snapshots(pending)
            self._grow(min(self.jobs, len(pending)))
            slots = self._slots
            while pending or any(s.task is not None for s in slots):
                for slot in slots:
                    self._maybe_dispatch(slot, pending)
                self._wait(slots)
                for slot in slots:
                    self._service(slot, on_record, bool(pending) or self.keep_warm)
        except BaseException:
            self.close()
            raise

    def _take_snapshots(self, tasks: Sequence[RunTask]) -> None:
        """Read every problem and scenario of ``tasks`` not read yet (:mod:`planbench.bench.snapshot`):
        before any worker runs plugin code for them. One that cannot be read is the reason its
        runs get no verdict (its worker cannot prepare the run either)."""
        for task in tasks:
            key = (kind_of(task.kind).entry, task.problem_ref)
            if key not in self._snapshots:
                try:
                    self._snapshots[key] = snapshot.take(*key)
                except Exception as exc:
                    self._snapshots[key] = {"error": f"{type(exc).__name__}: {exc}"[:2000]}

    def _snapshot_of(self, task: RunTask) -> dict[str, Any]:
        return self._snapshots[(kind_of(task.kind).entry, task.problem_ref)]

    def close(self) -> None:
        """Stop every slot's processes and remove their output files."""
        slots, self._slots = self._slots, []
        try:
            for slot in slots:
                self._stop(slot.worker, idle=slot.task is None)
                self._stop(slot.validator, idle=slot.phase != "validate" or slot.task is None)
        finally:
            if self._cgroups is not None:
                self._cgroups.close()
                self._cgroups = None
            if self._tmp:
                shutil.rmtree(self._tmp, ignore_errors=True)
                self._tmp = ""
                os.close(self._tmp_lock)

    def _grow(self, n: int) -> None:
        if not self._tmp:
            self._tmp, self._tmp_lock = worker_dir()  # and those of benchmarks killed before they could remove theirs
            make_undumpable()  # no confined controller may read or write this process's memory
            if self.warm_numba:
                compile_cache.warm_now()  # trusted code, before any plugin's; its workers copy it
            self._hooks = startup_hooks()
            self._cgroups = Cgroups()
            if not self._cgroups.base:
                self._warn(
                    "cgroups",
                    "this process cannot make cgroups (v2): a plugin's process that leaves its "
                    "worker's session is found by tracking the worker's descendants instead",
                )
            if self.sandboxed and not sandbox.available():
                self._warn(
                    "sandbox",
                    "the kernel offers no Landlock: plugins run WITHOUT the file-system sandbox and can "
                    "write the problem, results and Python files (docs/benchmarking.md, threat model)",
                )
        while len(self._slots) < n:
            self._slots.append(_Slot(self._start("worker"), self._start("validator"), index=len(self._slots)))

    # -- the loop ----------------------------------------------------------------------------------

    def _maybe_dispatch(self, slot: _Slot, pending: deque[RunTask]) -> None:
        if slot.task is not None or not pending:
            return
        if not slot.worker.usable:
            self._close(slot.worker)
            slot.worker = self._start("worker")
            return
        if not slot.worker.ready:
            return
        index = _next_for(slot.worker.plugin, pending)
        task = pending[index]
        fresh = task.fresh_process or kind_of(task.kind).fresh_worker
        if slot.worker.runs > 0 and (fresh or slot.worker.spent or slot.worker.plugin != plugin_of(task)):
            self._stop(slot.worker, idle=True)  # one plugin per process: a fresh one for the next
            slot.worker = self._start("worker")
            return
        if not self._dispatch(slot, task):  # it died just now: the run goes to its successor
            self._kill(slot.worker)
            self._close(slot.worker)
            slot.worker = self._start("worker")
            return
        slot.worker.plugin = plugin_of(task)
        del pending[index]

    def _service(self, slot: _Slot, on_record: Callable[[RunTask, Record], None], more: bool) -> None:
        """Everything one slot needs after a wait: messages, deadlines, dead processes."""
        slot.worker.output.bound(_pid(slot.worker))  # its own session: the group is its pid
        finished = self._drain_worker(slot) or self._drain_validator(slot)
        if finished is not None:
            self._finish(slot, finished, on_record)
        now = time.monotonic()
        if slot.task is not None and now > slot.deadline:
            self._finish(slot, self._timeout(slot, now), on_record)
        self._check_worker(slot, on_record, more)
        self._check_validator(slot, on_record, more)

    def _check_worker(self, slot: _Slot, on_record: Callable[[RunTask, Record], None], more: bool) -> None:
        w = slot.worker
        if w.closed or w.proc.is_alive():
            return
        if slot.task is not None and (slot.phase == "setup" or (slot.phase == "plan" and not slot.kind.channel)):
            self._finish(slot, self._crash(slot, w), on_record)  # (a closed loop's record is the simulation's)
        elif not w.ready:
            self._start_failed(w)
        self._close(w)
        if more:
            slot.worker = self._start("worker")

    def _check_validator(self, slot: _Slot, on_record: Callable[[RunTask, Record], None], more: bool) -> None:
        v = slot.validator
        if v.closed or v.proc.is_alive():
            return
        if slot.task is not None and (slot.phase == "validate" or (slot.phase == "plan" and slot.kind.channel)):
            if slot.phase == "plan":  # the simulation is gone: so is the run's controller
                self._kill(slot.worker)
            self._finish(slot, self._crash(slot, v), on_record)
        elif not v.ready:
            self._start_failed(v)
        self._close(v)
        if more or slot.task is not None:
            slot.validator = self._start("validator")

    def _check_hooks(self) -> None:
        """Refuse to start a validator once the interpreter's start-up hooks changed: a plugin
        without a sandbox could have planted one to run in every later verdict's process."""
        now = startup_hooks()
        if now != self._hooks:
            changed = sorted(p for p in set(now) | set(self._hooks) if now.get(p) != self._hooks.get(p))
            raise PlanbenchError(
                f"the Python installation's start-up hooks changed during the benchmark ({', '.join(changed[:3])}): "
                "a plugin may have planted code to run in every new process, so no validator is started "
                "from this installation; remove the file(s), check the plugins, and run again with --resume"
            )

    def _warn(self, topic: str, message: str) -> None:
        if topic not in self._warned:
            self._warned.add(topic)
            log.warning("%s", message)

    def _check_sandbox(self, state: Any) -> None:
        """Warn (once) when a worker that should be sandboxed says it is not."""
        if self.sandboxed and not str(state).startswith("Landlock"):
            self._warn("sandbox", f"plugins run WITHOUT the file-system sandbox: {str(state)[:300]}")
        elif self.sandboxed and "NOT refused" in str(state):
            self._warn("signals", f"the sandbox cannot refuse signals (kernel before 6.12): {state}")

    def _start_failed(self, child: _Child) -> None:
        self._start_failures += 1
        if self._start_failures > 3:
            raise PlanbenchError(
                f"benchmark {child.kind} processes die before they start (a script that runs a "
                "benchmark needs an `if __name__ == '__main__':` guard: workers are "
                "spawned and import the main module); last output:\n" + child.output.tail()
            )

    def _finish(self, slot: _Slot, record: Record, on_record: Callable[[RunTask, Record], None]) -> None:
        task = slot.task
        assert task is not None
        record["elapsed"] = time.monotonic() - slot.dispatched
        _note_memory_limit(record, task)
        if kind_of(task.kind).answer_in_time:
            _check_time_limit(record, slot.timings.get("plan"), task.time_limit)
            _charge_parent_time(record, slot.timings.get("plan"))
        else:
            _check_planning_time(record, slot.timings.get("plan"))
        slot.task, slot.fields, slot.phase, slot.deadline = None, None, "", math.inf
        if slot.channel is not None:
            slot.channel.close()
            slot.channel = None
        on_record(task, record)

    # -- processes -------------------------------------------------------------------------------

    def _start(self, kind: str) -> _Child:
        # Imported here: the main process imports neither entry point's module until it starts one.
        from planbench.bench.validator import validator_main
        from planbench.bench.worker import worker_main

        if kind == "validator":
            self._check_hooks()
        self._count += 1
        output = OutputFile(os.path.join(self._tmp, f"{kind}-{self._count}.out"))
        parent, child = self.ctx.Pipe(duplex=True)
        args: tuple[Any, ...] = (child, output.path, os.getpid(), self.threads)
        scratch = cgroup = ""
        if kind == "worker":
            scratch = os.path.join(self._tmp, f"scratch-{self._count}")
            os.mkdir(scratch, 0o700)
            cgroup = self._cgroups.make(f"worker-{self._count}") if self._cgroups is not None else ""
            args += (scratch, self.sandboxed, cgroup, self.writable)
        proc = self.ctx.Process(  # type: ignore[attr-defined]
            target=worker_main if kind == "worker" else validator_main,
            args=args,
            daemon=True,
            name=f"planbench-{kind}-{self._count}",
        )
        with thread_environment(self.threads):
            proc.start()
        child.close()
        _set_recv_timeout(parent, RECV_TIMEOUT)
        return _Child(kind, proc, parent, output, scratch=scratch, cgroup=cgroup)

    def _kill(self, child: _Child, dump_stack: bool = False) -> None:
        if child.closed:  # already reaped and closed (the other process of a closed-loop run died first)
            return
        pid = child.proc.pid
        if dump_stack and child.proc.is_alive() and pid is not None:  # faulthandler writes the stack
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGUSR1)
                child.proc.join(0.3)
        kill_group(pid)
        Cgroups.kill(child.cgroup)
        child.proc.join(5)

    def _stop(self, child: _Child, idle: bool) -> None:
        if child.closed:
            return
        if child.proc.is_alive() and idle and child.ready:
            with contextlib.suppress(OSError):
                child.conn.send_bytes(encode({"type": "stop"}))
            child.proc.join(2)
        self._kill(child)
        self._close(child)

    def _close(self, child: _Child) -> None:
        if child.closed:
            return
        child.closed = True
        kill_group(child.proc.pid)  # a dead worker's group may still hold the planner's children
        Cgroups.kill(child.cgroup)  # and its cgroup those that left the group
        if child.scratch:
            shutil.rmtree(child.scratch, ignore_errors=True)
        with contextlib.suppress(OSError):
            child.conn.close()
        child.proc.join(5)
        if child.proc.exitcode is not None:
            child.proc.close()

    def _wait(self, slots: list[_Slot]) -> None:
        children = [c for s in slots for c in (s.worker, s.validator) if not c.closed]
        waitables = [c.conn for c in children] + [c.proc.sentinel for c in children]
        deadlines = [s.deadline for s in slots if s.task is not None]
        timeout = 0.5  # also how often output files are bounded
        if deadlines:
            timeout = min(timeout, max(0.0, min(deadlines) - time.monotonic()) + 0.01)
        multiprocessing.connection.wait(waitables, timeout)
        self._woke = time.monotonic()

    # -- a run's life ------------------------------------------------------------------------------

    def _dispatch(self, slot: _Slot, task: RunTask) -> bool:
        """Hand ``task`` to the slot's worker; False (the slot left free) when its connection is gone."""
        kind = kind_of(task.kind)
        message = encode({"type": "run", "run": self._runs + 1, "task": task.to_wire(), "channel": kind.channel})
        ours = None
        try:
            slot.worker.conn.send_bytes(message)
            if kind.channel:
                theirs, ours = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
                with theirs:
                    send_handle(slot.worker.conn, theirs.fileno(), slot.worker.proc.pid)
        except OSError:
            if ours is not None:
                ours.close()
            return False
        slot.channel = ours
        now = time.monotonic()
        self._runs += 1
        slot.task, slot.run, slot.fields = task, self._runs, None
        slot.worker.runs += 1
        slot.dispatched = now
        slot.timings = {}
        slot.phase = ""
        slot.worker.output.reset()
        self._enter(slot, "setup", now)
        return True

    def _enter(self, slot: _Slot, phase: str, now: float) -> None:
        task = slot.task
        assert task is not None
        limits = {
            "setup": task.setup_timeout,
            "plan": task.time_limit + task.grace,
            "validate": task.validation_timeout,
        }
        if slot.phase:
            slot.timings[slot.phase] = now - slot.phase_start
        slot.phase = phase
        slot.phase_start = now
        slot.deadline = now + limits[phase]

    def _receive(self, child: _Child) -> list[tuple[dict[str, Any], dict[str, Any]]]:
        """Every message waiting from ``child``, parsed (never unpickled); :class:`_ChildFailed` when
        one cannot be read."""
        out: list[tuple[dict[str, Any], dict[str, Any]]] = []
        try:
            while not child.closed and child.conn.poll():
                if len(out) >= MAX_MESSAGES_PER_WAIT:
                    raise _ChildFailed(f"sent more than {MAX_MESSAGES_PER_WAIT} messages at once")
                data = child.conn.recv_bytes(MAX_MESSAGE_BYTES)
                out.append(decode(data))
        except EOFError:
            pass  # the process ended; its slot is handled by the liveness checks
        except BlockingIOError as exc:
            raise _ChildFailed(f"stopped for {RECV_TIMEOUT:g} s in the middle of a message") from exc
        except OSError as exc:
            raise _ChildFailed(
                f"sent a message that could not be read ({exc}; limit {MAX_MESSAGE_BYTES} bytes)"
            ) from exc
        except BadMessage as exc:
            raise _ChildFailed(f"sent a malformed message ({exc})") from exc
        return out

    def _drain_worker(self, slot: _Slot) -> Record | None:
        """Handle the worker's messages; a record when its run ends here (a result not kept)."""
        try:
            messages = self._receive(slot.worker)
        except _ChildFailed as exc:
            self._kill(slot.worker)
            if slot.task is not None and slot.phase in ("setup", "plan"):
                return failure_record("error", f"the worker {exc}; worker process killed", slot.worker.output.tail())
            return None
        for header, arrays in messages:
            kind, run = header.get("type"), header.get("run")
            if kind == "ready":
                slot.worker.ready = True
                self._check_sandbox(header.get("sandbox"))
            elif slot.task is None or run != slot.run or slot.phase not in ("setup", "plan"):
                continue  # a late message of a run already recorded
            elif kind == "phase" and header.get("phase") == "plan" and slot.phase == "setup":
                now = time.monotonic()
                self._enter(slot, "plan", now if slot.kind.answer_in_time else self._woke)
                if slot.kind.channel:
                    self._start_simulation(slot)
                elif slot.kind.answer_in_time:  # the worker waits for this: the phase starts now
                    with contextlib.suppress(OSError):  # a dead worker is found by its liveness check
                        slot.worker.conn.send_bytes(encode({"type": "go", "run": slot.run}))
            elif kind == "done" and (slot.phase == "setup" or not slot.kind.channel):
                return self._on_result(slot, header, arrays)  # (a closed loop's record is the simulation's)
        return None

    def _on_result(self, slot: _Slot, header: dict[str, Any], arrays: dict[str, Any]) -> Record | None:
        """Check the worker's raw result again here, then hand it to the validator."""
        assert slot.task is not None
        tail = slot.worker.output.tail()
        try:
            fields = _fields_from(header, arrays)
        except BadField as bad:
            message = f"the planner's result is unusable: {bad} (found on receipt; the worker's check missed it)"
            record = failure_record("error", message, _with_output("", tail))
            record.update(pid=slot.worker.proc.pid, host=self._host)
            return record
        fields["pid"], fields["host"] = slot.worker.proc.pid, self._host  # what this process knows itself
        slot.worker.spent = ran_out_of_memory(fields["message"], fields["traceback"])  # the worker ends itself
        fields["traceback"] = _with_output(fields["traceback"], tail)
        if not fields["prepared"]:
            return record_from(fields, None, math.nan)
        if slot.kind.channel:  # only the simulation makes a closed loop's record
            return None
        slot.fields = fields
        self._enter(slot, "validate", self._woke)
        result = {k: v for k, v in fields.items() if k not in ("path", "times")}
        task = slot.task
        assert task is not None
        request = {
            "snapshot": self._snapshot_of(task),
            "validation": task.validation,
            "postprocess": task.postprocess,
            "seed": task.seed,
            "result": result,
        }
        self._ask_validator(slot, request, {"path": fields["path"], "times": fields["times"]})
        return None

    def _start_simulation(self, slot: _Slot) -> None:
        """Hand the validator a closed-loop run: the request, then its end of the socket pair."""
        task, channel = slot.task, slot.channel
        assert task is not None and channel is not None
        request = {
            "snapshot": self._snapshot_of(task),
            "seed": task.seed,
            "timing": task.timing,
            "pid": slot.worker.proc.pid,
            "cpu": self._cores[slot.index % len(self._cores)] if self.pin else None,
        }
        self._ask_validator(slot, request, channel=channel)
        channel.close()
        slot.channel = None

    def _ask_validator(
        self, slot: _Slot, request: dict[str, Any], arrays: dict[str, Any] | None = None, channel: Any = None
    ) -> None:
        """Send the slot's validator (started anew if it is gone) the run's request, and ``channel``
        after it when the run's kind has one."""
        assert slot.task is not None
        if not slot.validator.usable:
            self._close(slot.validator)
            slot.validator = self._start("validator")
        header = {"type": "validate", "run": slot.run, "kind": slot.task.kind, **request}
        try:
            slot.validator.conn.send_bytes(encode(header, arrays))
            if channel is not None:
                send_handle(slot.validator.conn, channel.fileno(), slot.validator.proc.pid)
        except OSError:
            pass  # the validator died: its liveness check records the crash

    def _drain_validator(self, slot: _Slot) -> Record | None:
        try:
            messages = self._receive(slot.validator)
        except _ChildFailed as exc:
            self._kill(slot.validator)
            if slot.task is not None and slot.phase == "validate":
                return failure_record("error", f"the validator {exc}; validator process killed")
            return None
        for header, arrays in messages:
            if header.get("type") == "ready":
                slot.validator.ready = True
            elif header.get("type") == "verdict" and header.get("run") == slot.run and self._judging(slot):
                return self._on_verdict(slot, header, arrays)
        return None

    def _judging(self, slot: _Slot) -> bool:
        """Whether the slot waits for its validator's verdict."""
        return slot.task is not None and (slot.phase == "validate" or (slot.phase == "plan" and slot.kind.channel))

    def _on_verdict(self, slot: _Slot, header: dict[str, Any], arrays: dict[str, Any]) -> Record:
        fields = slot.fields
        evaluation = header.get("evaluation")
        if not isinstance(evaluation, dict):
            message = "validation raised (a planbench bug, please report it)"
            if fields is None:  # a closed loop: the simulation raised
                message = "the closed-loop simulation raised (a planbench bug, please report it)"
                self._kill(slot.worker)
                return failure_record("error", message, str(header.get("error", ""))[-8000:])
            record = failure_record("error", message, str(header.get("error", ""))[-8000:], fields["planning_time"])
            record.update(info=fields["info"], pid=fields["pid"], host=fields["host"])
            return record
        if fields is None:  # the validator ran the closed loop: its record is the run's
            try:
                fields = _fields_from(header, arrays)
            except BadField as bad:
                return failure_record("error", f"the simulation's record is unusable: {bad} (a planbench bug)")
            fields["host"] = self._host
        validation_time = header.get("validation_time")
        if type(validation_time) is not float:
            validation_time = math.nan
        return record_from(fields, evaluation, validation_time)

    def _timeout(self, slot: _Slot, now: float) -> Record:
        task = slot.task
        assert task is not None
        elapsed = now - slot.phase_start
        if slot.phase == "validate":
            self._kill(slot.validator)
            self._close(slot.validator)
            msg = f"validation ran past {task.validation_timeout} s; validator process killed"
            fields = slot.fields or {}
            return failure_record("timeout", msg, "", fields.get("planning_time", math.nan))
        self._kill(slot.worker, dump_stack=True)
        if slot.phase == "plan" and slot.kind.channel:  # the simulation of a closed loop
            self._kill(slot.validator)
            self._close(slot.validator)
        if slot.phase == "plan":
            msg = (
                f"planning ran {elapsed:.1f} s, past the time limit of {task.time_limit} s "
                f"+ {task.grace} s grace; worker process killed"
            )
            planning_time = elapsed
        else:
            what = (
                "scenario loading, the controller's setup and warm-up"
                if slot.kind.channel
                else "problem loading, planner setup"
            )
            msg = f"setup ({what}) ran past {task.setup_timeout} s; worker process killed"
            planning_time = math.nan
        return failure_record("timeout", msg, _with_output("", slot.worker.output.tail()), planning_time)

    def _crash(self, slot: _Slot, child: _Child) -> Record:
        code = child.proc.exitcode
        if code is not None and code < 0:
            try:
                how = f"signal {signal.Signals(-code).name} ({-code})"
            except ValueError:
                how = f"signal {-code}"
        else:
            how = f"exit code {code}"
        phase = "validation" if slot.phase == "validate" else slot.phase
        msg = f"{child.kind} process died with {how} during {phase}"
        limit = slot.task.memory_limit if slot.task is not None else 0.0
        if limit > 0 and child.kind == "worker" and code is not None and code < 0:
            msg += f" (its memory limit was {limit:g} MiB: a failed allocation in C code can end a process this way)"
        return failure_record("crash", msg, _with_output("", child.output.tail()))


def startup_hooks() -> dict[str, tuple[int, int, int]]:
    """The files every new interpreter runs at start-up (``*.pth``, ``sitecustomize``,
    ``usercustomize`` in the site folders and on ``PYTHONPATH``) -> (inode, size, mtime)."""
    import site

    folders = [*site.getsitepackages(), site.getusersitepackages()]
    folders += [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    out: dict[str, tuple[int, int, int]] = {}
    for folder in folders:
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            if name.endswith(".pth") or name in ("sitecustomize.py", "usercustomize.py"):
                path = os.path.join(folder, name)
                with contextlib.suppress(OSError):
                    st = os.stat(path)
                    out[path] = (st.st_ino, st.st_size, st.st_mtime_ns)
    return out


def plugin_of(task: RunTask) -> tuple[str, ...]:
    """What a worker may run code of: one planner label of one suite (a plugin's code, with one
    set of settings), so that nothing a plugin does to its process reaches another's runs."""
    return (task.suite, task.label, task.planner)


def _next_for(plugin: tuple[str, ...] | None, pending: deque[RunTask]) -> int:
    """The index of the next task for a worker that has run ``plugin``: the first of that plugin
    (its warm worker goes on), else the first of all."""
    if plugin is not None:
        for i, task in enumerate(pending):
            if plugin_of(task) == plugin:
                return i
    return 0


def _fields_from(header: dict[str, Any], arrays: dict[str, Any]) -> dict[str, Any]:
    """The raw result of a ``done`` message, checked here as if the worker had checked nothing."""
    result = header.get("result")
    if not isinstance(result, dict):
        raise BadField("result", "the message holds no result")
    if set(arrays) - {"path", "times"}:
        raise BadField("result", f"unexpected arrays {sorted(arrays)[:5]}")
    return clean_result({**result, "path": arrays.get("path"), "times": arrays.get("times")})


def _with_output(traceback: str, tail: str) -> str:
    """``traceback`` with the run's output tail appended under :data:`OUTPUT_HEADER`."""
    if not tail:
        return traceback
    sep = "\n" if traceback and not traceback.endswith("\n") else ""
    return f"{traceback}{sep}{OUTPUT_HEADER}\n{tail}"


def _note_memory_limit(record: Record, task: RunTask) -> None:
    """Name the memory limit in an ``error`` that ran out of memory (the limit is the likely cause)."""
    limit = task.memory_limit
    evaluation = record["evaluation"]
    if limit <= 0 or evaluation.get("status") != "error":
        return
    if not ran_out_of_memory(str(record.get("message", "")), str(record.get("traceback", ""))):
        return
    note = (
        f" (MemoryError under the run's memory limit of {limit:g} MiB: "
        "suite memory_limit or --memory-limit; 'none' lifts it)"
    )
    record["message"] = str(record.get("message", "")) + note
    evaluation["failure"] = str(evaluation.get("failure", "")) + note


def _set_recv_timeout(conn: Any, seconds: float) -> None:
    """Make reads of ``conn`` give up after ``seconds`` when a sender stalls mid-message (a socket
    option, so ``poll`` then ``recv_bytes`` can never block this loop for long)."""
    try:
        sock = socket.socket(fileno=os.dup(conn.fileno()))
    except OSError:  # pragma: no cover (not a socket: a pipe on another platform)
        return
    try:
        sec = int(seconds)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("ll", sec, int((seconds - sec) * 1e6)))
    except OSError:  # pragma: no cover
        pass
    finally:
        sock.close()
