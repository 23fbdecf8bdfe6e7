"""The benchmark's own cost: the smoke suite's wall time with --jobs 1 and --jobs 2 (ratio in one
run), and the harness overhead per run (process isolation + validation) against planning time.

    python benchmarks/harness_overhead.py                  # the smoke suite, jobs 1 then 2
    python benchmarks/harness_overhead.py --suite my.toml --jobs 1 4

Per run, from the results database (all seconds):
- planning: ``planning_time`` (the timed query, measured by the harness);
- validation: ``validation_time`` (``planbench.evaluate`` certifying the path in the slot's
  validator process, where no planner code runs);
- isolation: ``elapsed - wall_time``: from the parent sending the run to receiving its verdict,
  minus the worker's and the validator's own time for it (encoding, pipes, scheduling, the
  database write);
- worker start: the one-off cost of spawning the worker processes, amortised over their runs.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from planbench.bench.benchmark import run_benchmark, select
from planbench.bench.db import ResultsDB


def _fmt(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else "-"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="smoke")
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args(argv)
    suite = select(args.suite)
    walls: dict[int, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for jobs in args.jobs:
            db_path = Path(tmp) / f"jobs{jobs}.db"
            t0 = time.perf_counter()
            outcome = run_benchmark(suite, db_path, jobs=jobs)
            walls[jobs] = time.perf_counter() - t0
            print(f"suite {suite.name}: {outcome.ran} runs with --jobs {jobs}: {walls[jobs]:.1f} s wall")
        base = args.jobs[0]
        for jobs in args.jobs[1:]:
            print(f"speed-up --jobs {jobs} vs --jobs {base}: {walls[base] / walls[jobs]:.2f}x")
        with ResultsDB(Path(tmp) / f"jobs{base}.db") as db:
            rows = db.rows()
    plan = np.array([r["planning_time"] for r in rows], dtype=float)
    setup = np.array([r["setup_time"] for r in rows], dtype=float)
    valid = np.array([r["validation_time"] for r in rows], dtype=float)
    iso = np.array([r["elapsed"] - r["wall_time"] for r in rows], dtype=float)
    ok = np.isfinite(plan) & np.isfinite(valid) & np.isfinite(iso)
    plan, setup, valid, iso = plan[ok], setup[ok], valid[ok], iso[ok]
    start = walls[base] - float(np.sum([r["elapsed"] for r in rows if math.isfinite(r["elapsed"])])) / base
    print(f"\nper run, --jobs {base}, {ok.sum()} runs (medians; totals over all runs) [ms]:")
    print(f"  planning    median {_fmt(1e3 * np.median(plan))}  total {_fmt(1e3 * plan.sum())}")
    print(f"  setup       median {_fmt(1e3 * np.median(setup))}  total {_fmt(1e3 * setup.sum())}")
    print(f"  validation  median {_fmt(1e3 * np.median(valid))}  total {_fmt(1e3 * valid.sum())}")
    print(f"  isolation   median {_fmt(1e3 * np.median(iso))}  total {_fmt(1e3 * iso.sum())}")
    print(f"  worker start (one-off, whole benchmark): about {_fmt(1e3 * max(start, 0.0))}")
    print("overhead as a fraction of planning time (total over total):")
    print(f"  isolation            {iso.sum() / plan.sum():.3g}")
    print(f"  validation           {valid.sum() / plan.sum():.3g}")
    print(f"  isolation+validation {(iso.sum() + valid.sum()) / plan.sum():.3g}")
    print(f"  median per run of (isolation+validation)/planning {np.median((iso + valid) / plan):.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
