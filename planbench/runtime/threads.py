"""Threads of the field's compiled kernels, and of the BLAS / OpenMP pools in the same process.

Two rules keep the field's timings honest when a process shares its cores with others (a benchmark
with ``--jobs`` equal to the core count always does):

1. **Small lazy calls never go parallel.** :func:`serial_lazy` routes a
   :func:`~planbench.field.lazy.lazy_field` call to the serial compiled kernel when its work, the
   number of grid cells it reads (``points * (2 * support + 2)^3``), is at most
   :data:`SERIAL_MAX_CELLS`. See that constant for the measurements behind it.
2. **Workers run one thread.** :func:`limit_threads` (call it first thing in a worker) sets numba's
   thread count and layer and the OpenMP / BLAS pools for this process and the processes it starts.

Why: a parallel region is only as fast as its slowest thread, and libgomp (numba's default
layer here) keeps idle threads spinning on a core. When another process wants that core (or
the host takes it: these 2 cores are shared), a thread of the region waits a whole time slice.
Measured with ``python benchmarks/threads.py --rounds 5`` on 2 shared cores, 128^3 grid, L = 21,
30 points; medians per call, "contended" = 2 busy-loop processes (3 in brackets):

=====================  ================  ======================  ===========================
policy                 30-pt lazy, par.  lazy_field (serial)     full 128^3, float32
=====================  ================  ======================  ===========================
numba default (omp)    8.0 ms / 12 (20)  0.29 ms / 0.18 (0.24)   72 ms / 132 (173)
omp, passive wait      0.22 / 0.20       0.20 / 0.18             43 / 93 (120)
workqueue              0.32 / 0.33       0.29 / 0.20             41 / 89 (121)
limit_threads(1)       0.17 / 0.16       0.18 / 0.18             46 / 133 (189)
=====================  ================  ======================  ===========================

(quiet / contended.) The spinning default layer loses whole 8 ms slices even "quiet"; passive
waiting or workqueue removes that. One thread is the workers' policy: a worker does not take
another worker's core (the 2-thread rows are faster contended only by taking a larger share of
the cores from the busy processes, i.e. from the other worker), and its arithmetic does not
depend on ``--jobs``. :func:`limit_threads` also sets passive waiting, so a worker given more
threads gets the "omp, passive wait" row.

Without numba nothing here imports it: :func:`limit_threads` then only sets the environment and
the BLAS pools, and :func:`serial_lazy` is not consulted (the numpy path has no threads).
"""

from __future__ import annotations

import os
import sys
from typing import Any

__all__ = [
    "SERIAL_MAX_CELLS",
    "THREAD_VARIABLES",
    "WAIT_VARIABLES",
    "lazy_cells",
    "limit_threads",
    "serial_lazy",
    "thread_report",
]

SERIAL_MAX_CELLS = 2**23
"""Largest lazy call (grid cells read: ``points * (2 * support + 2)^3``) run on one thread.

8.4 M cells take about 4.5 ms on one thread here (0.5-0.6 ns per cell, float64: 30 points with a
21-cell kernel, 318 k cells, take 160-180 us). Quiet, a parallel call saves at most
``(1 - 1/cores)`` of that: 2.3 ms on 2 cores. Contended, it loses up to a scheduler time slice
(8 ms measured, in whole steps) whenever one of its threads is descheduled, even for one point.
Below this size the possible saving is smaller than one lost slice, so serial is the better bet;
above it the call is long enough that the slice is a fraction of it. A planner's control points
(tens of points, kernels of 15-25 cells: 0.1-0.5 M cells) are far below it.
"""

THREAD_VARIABLES = (
    "NUMBA_NUM_THREADS",
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)
"""Thread-count variables that :func:`limit_threads` sets (read by each library when it loads)."""

WAIT_VARIABLES = {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": "0", "KMP_BLOCKTIME": "0"}
"""OpenMP runtimes' idle-thread settings that :func:`limit_threads` sets: idle threads sleep
instead of spinning (libgomp: ``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT``; Intel/LLVM:
``KMP_BLOCKTIME``), so a pool that is not working does not take a core from another process."""


def lazy_cells(n_points: int, support: int) -> int:
    """Grid cells a lazy call reads: ``n_points`` blocks of ``(2 * support + 2)^3`` cells."""
    return int(n_points) * (2 * int(support) + 2) ** 3


def serial_lazy(n_points: int, support: int) -> bool:
    """Whether a compiled lazy call on ``n_points`` points (kernels of ``support`` cells) should
    run serially: when it is small (:data:`SERIAL_MAX_CELLS`) or numba has one thread anyway."""
    if lazy_cells(n_points, support) <= SERIAL_MAX_CELLS:
        return True
    import numba  # on use, here and below: numba is optional, and limit_threads must run before its import

    return bool(numba.get_num_threads() <= 1)


def limit_threads(threads: int = 1, layer: str | None = None) -> dict[str, Any]:
    """Limit this process's compute threads to ``threads`` (call at the start of a worker).

    - Sets :data:`THREAD_VARIABLES` to ``threads`` and :data:`WAIT_VARIABLES` (idle threads sleep)
      in ``os.environ``: libraries loaded later, and child processes, read them.
    - numba: ``NUMBA_NUM_THREADS`` before it is imported; if it already is, ``numba.config`` and
      ``numba.set_num_threads`` (for the calling thread, which is the one that runs the kernels).
      ``layer`` (``"workqueue"``, ``"omp"``, ``"tbb"``; ``None`` keeps numba's choice) sets
      ``NUMBA_THREADING_LAYER``; it cannot change once numba has started its pool (a
      ``RuntimeError`` then, unless it is the layer in use).
    - BLAS and OpenMP libraries already loaded (numpy's OpenBLAS is loaded by ``import numpy``,
      before this call in a worker, and reads ``OPENBLAS_NUM_THREADS`` only then): threadpoolctl's
      ``threadpool_limits``, which finds them in the process and calls each one's own setter.

    Returns :func:`thread_report` after the change.
    """
    threads = int(threads)
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    for name in THREAD_VARIABLES:
        os.environ[name] = str(threads)
    os.environ.update(WAIT_VARIABLES)
    if layer is not None:
        os.environ["NUMBA_THREADING_LAYER"] = layer
    if sys.modules.get("numba") is not None:
        _limit_numba(threads, layer)
    from threadpoolctl import threadpool_limits  # on use: 12 ms, which `import planbench` need not pay

    threadpool_limits(limits=threads)  # the BLAS and OpenMP libraries loaded already
    return thread_report()


def _limit_numba(threads: int, layer: str | None) -> None:
    import numba
    from numba.np.ufunc import parallel

    started = bool(getattr(parallel, "_is_initialized", False))
    if layer is not None:
        if started:
            in_use = parallel.threading_layer()
            if in_use != layer:
                raise RuntimeError(
                    f"numba's threading layer is already {in_use!r}; set "
                    f"NUMBA_THREADING_LAYER={layer} before the first parallel call"
                )
        else:
            numba.config.THREADING_LAYER = layer  # type: ignore[attr-defined]
    if started:  # the pool keeps its size; this thread's regions use ``threads`` of it
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    else:  # the pool will be started with ``threads`` (without starting it now)
        numba.config.NUMBA_NUM_THREADS = threads  # type: ignore[attr-defined]
        parallel.NUM_THREADS = threads


def thread_report() -> dict[str, Any]:
    """What this process runs with: the variables above, numba's threads for the calling thread
    and its layer (``None`` where numba is not imported; the layer is ``None`` until its pool has
    started: this does not start it) and each loaded OpenBLAS's thread count (by file name)."""
    report: dict[str, Any] = {
        "env": {n: os.environ.get(n) for n in (*THREAD_VARIABLES, *WAIT_VARIABLES, "NUMBA_THREADING_LAYER")},
        "numba_threads": None,
        "numba_layer": None,
        "openblas": {},
    }
    if sys.modules.get("numba") is not None:
        import numba
        from numba.np.ufunc import parallel

        if getattr(parallel, "_is_initialized", False):
            report["numba_threads"] = int(numba.get_num_threads())
            report["numba_layer"] = parallel.threading_layer()
        else:  # the size its pool will start with (asking numba would start it)
            report["numba_threads"] = int(parallel.NUM_THREADS)
    from threadpoolctl import threadpool_info

    for pool in threadpool_info():
        if pool.get("internal_api") == "openblas":
            report["openblas"][os.path.basename(pool["filepath"])] = int(pool["num_threads"])
    return report
