"""The field's compiled kernels, quiet and under CPU contention, per numba thread policy.

    python benchmarks/threads.py              # 3 rounds, 128^3, L = 21, 30 points
    python benchmarks/threads.py --rounds 5 --hogs 2

Each policy runs in a fresh process (numba's threading layer and pool size are fixed at its first
parallel call) and times, with warm caches, medians of repeated calls:

- ``lazy par``: 30-point lazy field through the parallel kernel (what every call did before the
  size threshold, and what a large call still does);
- ``lazy_field``: the same call through :func:`planbench.field.lazy_field` (serial below
  :data:`planbench.runtime.threads.SERIAL_MAX_CELLS`);
- ``full``: the full field of a 128^3 grid (about 10 % occupied), float32, default margin.

"quiet" is the machine as it is; "contended" adds one busy-loop process per core (``--hogs``),
started by this script and killed at its end: what a benchmark with ``--jobs`` equal to the
core count looks like to each worker (its parent, validator and planners add more). Two tables:
each call's median, and its mean (a stall of a whole time slice now and then shows in the mean,
and planning times add up calls); each the median over ``--rounds`` rounds, and contended / quiet.
Policies: numba's default (all cores, its default layer); the OpenMP layer with passive waiting;
the workqueue layer; one thread (:func:`planbench.runtime.threads.limit_threads`, the benchmark
workers' policy).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import subprocess
import sys
import time
from typing import Any

POLICIES: dict[str, dict[str, Any]] = {
    "default (all cores)": {"env": {}},
    "omp passive": {
        "env": {
            "NUMBA_THREADING_LAYER": "omp",
            "OMP_WAIT_POLICY": "PASSIVE",
            "GOMP_SPINCOUNT": "0",
            "KMP_BLOCKTIME": "0",
        }
    },
    "workqueue": {"env": {"NUMBA_THREADING_LAYER": "workqueue"}},
    "limit_threads(1)": {"env": {}, "limit": 1},
}
CASES = ("lazy par", "lazy_field", "full")
CLEARED = (
    "NUMBA_NUM_THREADS",
    "NUMBA_THREADING_LAYER",
    "OMP_NUM_THREADS",
    "OMP_WAIT_POLICY",
    "GOMP_SPINCOUNT",
    "KMP_BLOCKTIME",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
)


def _times(fn: Any, repeat: int, budget: float) -> list[float]:
    fn()
    times: list[float] = []
    end = time.perf_counter() + budget
    while len(times) < repeat and (len(times) < 5 or time.perf_counter() < end):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def child(spec: dict[str, Any]) -> dict[str, Any]:
    """Time the cases in this process (started with the policy's environment)."""
    import numpy as np  # before limit_threads, as in a benchmark worker

    if spec.get("limit"):
        from planbench.runtime.threads import limit_threads

        limit_threads(int(spec["limit"]))
    from planbench.field import _compiled as compiled
    from planbench.field import full_field, lazy_field
    from planbench.field.bench import RESOLUTION, bench_grid
    from planbench.field.kernels import Kernels
    from planbench.runtime.threads import thread_report

    n, length, points = spec["size"], spec["length"], spec["points"]
    grid = bench_grid(n, "float32", 0)
    kernels = Kernels.from_cells(length, resolution=RESOLUTION)
    rng = np.random.default_rng(1)
    pts = grid.origin + rng.uniform(0.1, 0.9, (points, 3)) * n * RESOLUTION
    along, across = kernels.factors(grid.data.dtype)
    out = np.empty((points, 3))

    def lazy_par() -> None:
        compiled.lazy_points(grid.data, grid.outside, grid.origin, grid.resolution, along, across, pts, out)

    fns = {
        "lazy par": (lazy_par, 300, 1.5),
        "lazy_field": (lambda: lazy_field(grid, kernels, pts), 300, 1.5),
        "full": (lambda: full_field(grid, kernels, np.float32), 30, 3.0),
    }
    times = {name: _times(fn, repeat, budget) for name, (fn, repeat, budget) in fns.items()}
    return {
        "median": {k: float(np.median(v)) for k, v in times.items()},
        "mean": {k: float(np.mean(v)) for k, v in times.items()},
        "threads": thread_report(),
    }


def _hog() -> None:
    while True:
        pass


def run_policies(args: argparse.Namespace, contended: bool) -> dict[str, dict[str, Any]]:
    hogs = []
    if contended:
        ctx = multiprocessing.get_context("spawn")
        hogs = [ctx.Process(target=_hog, daemon=True) for _ in range(args.hogs)]
        for h in hogs:
            h.start()
        time.sleep(0.5)
    results = {}
    try:
        for name, policy in POLICIES.items():
            env = {k: v for k, v in os.environ.items() if k not in CLEARED}
            env.update(policy["env"])
            spec = {"size": args.size, "length": args.length, "points": args.points, "limit": policy.get("limit")}
            proc = subprocess.run(
                [sys.executable, __file__, "--child", json.dumps(spec)],
                env=env,
                capture_output=True,
                text=True,
                check=False,
            )
            if proc.returncode != 0:
                raise RuntimeError(f"{name}: child failed:\n{proc.stderr[-3000:]}")
            results[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    finally:
        for h in hogs:
            h.kill()
        for h in hogs:
            h.join()
    return results


def format_table(rounds: list[dict[str, dict[str, dict[str, Any]]]], stat: str) -> str:
    """One row per policy: ``stat`` ("median" or "mean" of each round's calls), median over
    rounds, quiet and contended side by side."""
    import numpy as np

    def med(cond: str, policy: str, case: str) -> float:
        return float(np.median([r[cond][policy][stat][case] for r in rounds]))

    head = f"{stat + ' per call':<22}{'numba layer, threads':<22}"
    head += "".join(f"{c + ' quiet':>18}{c + ' contended':>22}{'ratio':>7}" for c in CASES)
    lines = [head]
    for policy in POLICIES:
        th = rounds[-1]["contended"][policy]["threads"]
        row = f"{policy:<22}{str(th['numba_layer']) + ', ' + str(th['numba_threads']):<22}"
        for case in CASES:
            q, c = med("quiet", policy, case), med("contended", policy, case)
            row += f"{_fmt(q):>18}{_fmt(c):>22}{c / q:>6.1f}x"
        lines.append(row)
    return "\n".join(lines)


def _fmt(seconds: float) -> str:
    return f"{seconds * 1e3:.2f} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.0f} us"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=3, help="quiet + contended rounds (median)")
    p.add_argument(
        "--hogs",
        type=int,
        default=len(os.sched_getaffinity(0)),
        help="busy-loop processes under contention (default: one per core)",
    )
    p.add_argument("--size", type=int, default=128, help="grid cells per side")
    p.add_argument("--length", type=int, default=21, help="kernel length [cells]")
    p.add_argument("--points", type=int, default=30, help="points per lazy call")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return 0
    rounds = []
    for i in range(args.rounds):
        print(f"round {i + 1}/{args.rounds}: quiet, then {args.hogs} busy processes", file=sys.stderr)
        rounds.append({"quiet": run_policies(args, False), "contended": run_policies(args, True)})
    from planbench.runtime.threads import SERIAL_MAX_CELLS, lazy_cells

    cells = lazy_cells(args.points, max(args.length // 2, 0))
    print(
        f"{len(os.sched_getaffinity(0))} cores, {platform.processor() or platform.machine()}, "
        f"{args.size}^3 grid, L = {args.length}, {args.points} points ({cells} cells; serial "
        f"up to {SERIAL_MAX_CELLS}), medians of {args.rounds} rounds; contended = "
        f"{args.hogs} busy-loop processes"
    )
    print(format_table(rounds, "median"))
    print()
    print(format_table(rounds, "mean"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
