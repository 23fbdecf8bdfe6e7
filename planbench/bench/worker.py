"""The worker process: receive runs over a pipe, plan and validate each, send the records back.

Started by :mod:`planbench.bench.runner` with the ``spawn`` method, so it is a fresh interpreter
that imports planners by name or ``"module:Attr"``. Messages to the parent:

- ``("ready", pid)`` once imports are done;
- ``("phase", key, "plan")`` when setup has finished and the timed query starts;
- ``("phase", key, "validate")`` when the query has returned;
- ``("done", key, record)`` with the run's record (see :func:`run_one`).

The worker ignores SIGINT (the parent decides what Ctrl-C does), writes its stderr to the file the
parent gives (so a crash's last words, e.g. faulthandler's traceback of a segfault, are kept) and
exits when the pipe closes.
"""

from __future__ import annotations

import faulthandler
import os
import signal
import socket
import time
import traceback
from typing import Any

__all__ = ["worker_main", "run_one"]


class _PhaseReporter:
    """Wraps a planner instance to tell the parent when setup ends and planning starts."""

    def __init__(self, inner: Any, notify: Any) -> None:
        self._inner = inner
        self._notify = notify

    def setup(self, problem: Any) -> None:
        self._inner.setup(problem)
        self._notify("plan")

    def plan(self, problem: Any, **kwargs: Any) -> Any:
        return self._inner.plan(problem, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


_PROBLEMS: dict[str, Any] = {}


def _problem(ref: str) -> Any:
    if ref not in _PROBLEMS:
        from planbench.datasets import load_problems

        found = load_problems(ref)
        if len(found) != 1:
            raise RuntimeError(f"problem reference {ref!r} names {len(found)} problems, not one")
        _PROBLEMS[ref] = found[0]
    return _PROBLEMS[ref]


def _set_memory_limit(mib: float) -> None:
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    want = int(mib * 2**20) if mib > 0 else hard
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    resource.setrlimit(resource.RLIMIT_AS, (want, hard))


def run_one(task: dict[str, Any], notify: Any = lambda phase: None) -> dict[str, Any]:
    """Plan and validate one run in this process; never raises for a planner's fault.

    ``task`` holds ``problem_ref``, ``planner`` (name or ``"module:Attr"``), ``settings``,
    ``seed``, ``time_limit`` [s] and ``validation`` (ValidationSettings fields). The record holds
    ``evaluation`` (``Evaluation.as_dict()``), ``message``, ``traceback``, ``path`` and ``times``
    (arrays or None), ``info`` (planner diagnostics, JSON-friendly) and ``wall_time`` [s].
    """
    import numpy as np

    import planbench
    from planbench.bench.suite import make_planner_instance
    from planbench.planner import PlanResult, PlanStatus
    from planbench.validate import ValidationSettings

    t0 = time.perf_counter()
    tb = ""
    problem = None
    try:
        problem = _problem(task["problem_ref"])
        instance = make_planner_instance(task["planner"], dict(task["settings"]))
    except Exception as exc:  # a problem or planner that cannot be built is an ERROR of this run
        result = PlanResult(PlanStatus.ERROR, message=f"could not prepare the run: {type(exc).__name__}: {exc}")
        tb = traceback.format_exc()
    else:
        result = planbench.plan(
            problem, _PhaseReporter(instance, notify), seed=int(task["seed"]), time_limit=float(task["time_limit"])
        )
        tb = str(result.info.get("traceback", ""))
    notify("validate")
    t1 = time.perf_counter()
    if problem is not None:
        evaluation = planbench.evaluate(problem, result, ValidationSettings(**task["validation"])).as_dict()
    else:
        from planbench.validate import Evaluation

        evaluation = Evaluation(False, result.message, result.status.value, np.nan, np.nan).as_dict()
    return {
        "evaluation": evaluation,
        "message": result.message,
        "traceback": tb,
        "path": None if result.path is None else np.asarray(result.path),
        "times": None if result.times is None else np.asarray(result.times),
        "info": _jsonable({k: v for k, v in result.info.items() if k != "traceback"}),
        "wall_time": time.perf_counter() - t0,
        "validation_time": time.perf_counter() - t1,
        "pid": os.getpid(),
        "host": socket.gethostname(),
    }


def _jsonable(x: Any) -> Any:
    """Planner diagnostics reduced to JSON types (small arrays as lists, the rest as text)."""
    import numpy as np

    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist() if x.size <= 1000 else f"<array {x.shape} {x.dtype}>"
    if isinstance(x, np.generic):
        return x.item()
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return repr(x)


THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def worker_main(conn: Any, stderr_path: str, threads: int = 1) -> None:
    """Entry point of a worker process (see the module docstring).

    ``threads`` caps the thread pools of OpenMP, BLAS and numba in this worker (set before any of
    them is imported), so parallel workers do not oversubscribe the cores and a run's arithmetic
    (e.g. the order of a parallel reduction) does not depend on ``--jobs``.
    """
    for name in THREAD_VARIABLES:
        os.environ[name] = str(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    fd = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 2)
    os.close(fd)
    faulthandler.enable()
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # the parent asks where a run hangs
    import planbench  # noqa: F401  (import before saying ready, so startup is not run time)

    conn.send(("ready", os.getpid()))
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        os.ftruncate(2, 0)
        os.lseek(2, 0, os.SEEK_SET)
        _set_memory_limit(float(task.get("memory_limit", 0.0)))
        key = task["key"]
        record = run_one(task, lambda phase, key=key: conn.send(("phase", key, phase)))
        conn.send(("done", key, record))
