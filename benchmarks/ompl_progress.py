"""What recording the progress of an anytime OMPL planner costs: RRT* iterations per second of
search with ``progress_interval`` 0.05 s (OMPL Benchmark's default) and with 0 (no recording).

Usage::

    python benchmarks/ompl_progress.py [--problems 'mbm:*/0001'] [--planner ompl-rrtstar]
        [--time-limit 1] [--repeats 3]

Both variants plan with ``optimize=True`` (the search runs until the time limit), in this process,
one after the other in an order alternating from run to run, so a busy machine slows both alike.
Printed: per variant the median of iterations per second of ``solve`` over all runs, and the
samples recorded per run; then the median of the per-pair ratio (with / without).
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np

from planbench.problems.datasets import load_problems
from planbench.registry import REGISTRY

VARIANTS = {"progress": 0.05, "none": 0.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--problems", default="mbm:*/0001")
    parser.add_argument("--planner", default="ompl-rrtstar")
    parser.add_argument("--time-limit", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    planners = {
        name: REGISTRY.make(args.planner, optimize=True, progress_interval=interval)
        for name, interval in VARIANTS.items()
    }
    rate: dict[str, list[float]] = {name: [] for name in VARIANTS}
    samples: list[int] = []
    ratios = []
    k = 0
    for problem in load_problems(args.problems):
        for planner in planners.values():
            planner.setup(problem)
        for repeat in range(args.repeats):
            order = list(VARIANTS) if k % 2 == 0 else list(reversed(VARIANTS))
            k += 1
            pair = {}
            for name in order:
                result = planners[name].plan(problem, time_limit=args.time_limit, rng=np.random.default_rng(repeat))
                info = result.info
                if "iterations" not in info:
                    continue
                pair[name] = info["iterations"] / info["solve_time"]
                rate[name].append(pair[name])
                if name == "progress":
                    samples.append(len(info["progress"]["time"]))
            if len(pair) == 2:
                ratios.append(pair["progress"] / pair["none"])
            print(problem.id, repeat, {n: round(v) for n, v in pair.items()}, flush=True)
    for name, values in rate.items():
        print(f"{name:9s} median iterations/s {statistics.median(values):9.1f} over {len(values)} runs")
    print(f"samples per run: median {statistics.median(samples)}, min {min(samples)}, max {max(samples)}")
    print(f"ratio with/without: median {statistics.median(ratios):.3f} over {len(ratios)} pairs")


if __name__ == "__main__":
    main()
