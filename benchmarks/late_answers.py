"""The hand-off of a static run's answer, as the benchmark's time limit sees it (issue 27, part 4):
the plan phase timed by the parent (the worker's "plan" message to its result, each stamped when the
parent's loop woke to read it) minus the planning time the worker measured. Planners answer
``--before`` seconds before their time limit (tests/bench_adversarial_planners.py:LatePlanner, a
straight line after a sleep), so every run should count; a ``timeout`` among them is an honest
answer the hand-off tolerance failed. ``--load`` starts one busy process per core beside it.

    python benchmarks/late_answers.py [--runs 40] [--jobs 2] [--limit 0.3] [--before 0.005] [--load]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the workers inherit it

from planbench.bench.runner import Runner  # noqa: E402
from planbench.bench.task import RunTask  # noqa: E402
from planbench.harness import HANDOFF_TOLERANCE  # noqa: E402


class _TimedRunner(Runner):
    """A runner that keeps each run's plan phase as the parent timed it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.phases: dict[int, float] = {}

    def _finish(self, slot: Any, record: Any, on_record: Any) -> None:
        self.phases[slot.task.seed] = slot.timings.get("plan", float("nan"))
        super()._finish(slot, record, on_record)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--limit", type=float, default=0.3, help="[s] time limit of each run")
    parser.add_argument("--before", type=float, default=0.005, help="[s] how long before its limit a planner answers")
    parser.add_argument("--load", action="store_true", help="one busy process per core beside the benchmark")
    args = parser.parse_args()
    busy = (
        [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 1)]
        if args.load
        else []
    )
    try:
        tasks = [
            RunTask(
                "handoff",
                "mbm:table_pick/0001",
                "mbm:table_pick/0001",
                "late",
                "bench_adversarial_planners:LatePlanner",
                seed,
                {"past": -args.before},
                time_limit=args.limit,
                grace=5.0,
            )
            for seed in range(args.runs)
        ]
        records: dict[int, Any] = {}
        runner = _TimedRunner(args.jobs)
        runner.run(tasks, lambda task, record: records.__setitem__(task.seed, record))
    finally:
        for p in busy:
            p.kill()
            p.wait()
    reported = [records[s]["evaluation"]["planning_time"] for s in range(args.runs)]
    handoff = [runner.phases[s] - r for s, r in enumerate(reported)]
    statuses = [records[s]["evaluation"]["status"] for s in range(args.runs)]
    ms = sorted(1e3 * h for h in handoff)
    print(
        f"{args.runs} runs, --jobs {args.jobs}, limit {args.limit} s, answers {args.before * 1e3:g} ms before it, "
        f"load: {'one busy process per core' if args.load else 'none'} ({os.cpu_count()} cores)"
    )
    print(
        f"hand-off [ms] (parent's plan phase - worker's planning time): median {statistics.median(ms):.2f}, "
        f"p90 {ms[int(0.9 * (len(ms) - 1))]:.2f}, max {ms[-1]:.2f}; tolerance {HANDOFF_TOLERANCE * 1e3:g} ms"
    )
    print(
        f"worker's planning time [s]: max {max(reported):.4f}; "
        f"parent's plan phase [s]: max {max(runner.phases.values()):.4f}"
    )
    print(f"statuses: { {s: statuses.count(s) for s in sorted(set(statuses))} } (timeout: an honest answer failed)")


if __name__ == "__main__":
    main()
