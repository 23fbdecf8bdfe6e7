"""Checks to a path: one RRT-Connect query searched in slices, exact against bounded overrun.

    python benchmarks/sliced_queries.py [--problems "mbm:*/0001-0020"] [--seeds 3] [--slice 50] [--cap 60000]

A controller that plans a slice per tick (``matrix-field-guided``, ``ompl-replan``) restarts a
query that finds no path within its check budget, so what decides how soon it moves is how many
checks a query needs. For each problem (its true scene, its start and goal configurations) and
seed, one :class:`~planbench_plugins.ompl_planners.SlicedRRTConnect` query runs in slices of
``--slice`` checks until it has a path or ``--cap`` checks, once with ``exact=True`` (a slice makes
exactly its checks: the search waits on a thread of its own) and once with the bounded overrun
(``overrun_motions = 1``: a slice refuses states and motions one motion past its end, which cuts
a connect short, as at an obstacle). Printed per mode: queries with a path within the cap and
within 20,000 checks (the controllers' default budget), and the median checks to a path (the cap
where none was found). Shortening is off: the search alone is compared.
"""

from __future__ import annotations

import argparse
import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # one core, as the closed-loop benchmark charges it

import numpy as np  # noqa: E402

import planbench  # noqa: E402
from planbench.checking.collision import CollisionChecker  # noqa: E402
from planbench_plugins.ompl_planners import SlicedRRTConnect  # noqa: E402

BUDGET = 20000
"""The controllers' default ``plan_check_budget``."""


def checks_to_path(
    checker: CollisionChecker, start: np.ndarray, goal: np.ndarray, seed: int, exact: bool, per_slice: int, cap: int
) -> int | None:
    """Checks the query made when its path was found; None when it had none within ``cap``."""
    query = SlicedRRTConnect(
        checker, start, goal, seed=seed, shorten=False, exact=exact, overrun_motions=None if exact else 1.0
    )
    try:
        while query.checks < cap:
            if query.advance(per_slice):
                return query.checks
            if query.failed:
                return None
        return None
    finally:
        query.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default="mbm:*/0001-0020")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--slice", type=int, default=50)
    ap.add_argument("--cap", type=int, default=60000)
    args = ap.parse_args()
    results: dict[str, list[int | None]] = {"exact": [], "bounded overrun": []}
    for problem in planbench.load_problems(args.problems):
        if problem.goal.q is None:
            continue
        checker = CollisionChecker(problem.robot, problem.scene)
        start, goal = np.asarray(problem.start, float), np.asarray(problem.goal.q, float)
        if checker.in_collision(start) or checker.in_collision(goal):
            continue
        row = []
        for seed in range(1, args.seeds + 1):
            for mode, exact in (("exact", True), ("bounded overrun", False)):
                n = checks_to_path(checker, start, goal, seed, exact, args.slice, args.cap)
                results[mode].append(n)
                row.append(f"{mode[0]}:{n if n is not None else '-'}")
        print(problem.id, " ".join(row), flush=True)
    print(f"\n| mode | queries | path within {args.cap} checks | within {BUDGET} | median checks to a path |")
    print("| --- | --- | --- | --- | --- |")
    for mode, found in results.items():
        counts = np.array([args.cap if x is None else x for x in found], dtype=float)
        ok = sum(x is not None for x in found)
        within = sum(x is not None and x <= BUDGET for x in found)
        print(f"| {mode} | {len(found)} | {ok} | {within} | {np.median(counts):.0f} |")


if __name__ == "__main__":
    main()
