"""``python -m planbench.cli.compile``: fill numba's cache with planbench's compiled kernels.

Started in the background by a ``planbench plan`` that found the cache cold, and by the benchmark
before its workers start (:mod:`planbench.runtime.compile_cache`). It plans with each field planner
on a small problem, which compiles (or loads) every kernel those plans use with the argument types
they use, then leaves the marker.
"""

from __future__ import annotations

import fcntl
import os

import numpy as np

from planbench.geometry.views import mark_seen
from planbench.runtime import compile_cache

__all__ = ["main", "warm_up"]

PLANNERS = ("matrix-field", "matrix-field:calibrated", "edt-field", "distance-field")
"""The planners whose plans use every compiled kernel (the field's and the IK loop's)."""


def warm_up() -> None:
    """Compile (or load) the kernels of one plan of each of :data:`PLANNERS` on a small
    MotionBenchMaker problem, and the depth sensor's view marking, then write the marker."""
    import planbench  # the whole library: this is a command

    problem = planbench.load_problems("mbm:box/0001")[0]
    for planner in PLANNERS:
        planbench.plan(problem, planner, seed=0, time_limit=30.0, backend="numba", max_steps=50)
    mark_seen(
        np.zeros((4, 4, 4), bool), -np.ones(3), 0.5, np.zeros(3), np.eye(3), 0.1, 2, 2, np.ones(4), backend="numba"
    )
    compile_cache.mark_warm()


def main() -> None:
    """Compile at low priority unless another process is at it or it is done."""
    os.nice(10)
    lock_path = compile_cache.marker_path().with_suffix(".lock")
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    with open(lock_path, "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # another one is compiling
            return
        if not compile_cache.is_warm():
            warm_up()


if __name__ == "__main__":
    main()
