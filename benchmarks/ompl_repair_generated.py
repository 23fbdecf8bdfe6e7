"""OMPL's repair of failing segments on scenes the repository does not ship: generated clutter
(benchmarks/recheck.py's generator) for the Panda and the UR5, with and without repair.

Prints per robot and variant the certified successes (``planbench.evaluate``), the median planning
time and where the returned paths came from. Runs through ``planbench.bench`` (benchmarks/_bench.py):
one suite per robot with the planner twice, ``repair_attempts`` 0 and 5.

    python benchmarks/ompl_repair_generated.py --problems 12 --seed 3
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from collections import Counter

from _bench import run_suite, write_problems
from recheck import generated_problems  # the scene generator beside this script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", type=int, default=12, help="generated problems per robot")
    ap.add_argument("--seed", type=int, default=3, help="seed of the generated scenes")
    ap.add_argument("--time-limit", type=float, default=5.0)
    args = ap.parse_args()
    variants = {
        "no repair": ("ompl-rrtconnect", {"repair_attempts": 0}),
        "repair": ("ompl-rrtconnect", {"repair_attempts": 5}),
    }
    for robot in ("panda", "ur5"):
        problems = generated_problems(robot, args.problems, seed=args.seed)
        with tempfile.TemporaryDirectory() as tmp:
            rows = run_suite(f"repair-{robot}", [write_problems(problems, tmp)], variants, time_limit=args.time_limit)
        for label in variants:
            mine = [r for r in rows if r["planner"] == label]
            sources = Counter(json.loads(r["info"] or "{}").get("path_source", "-") for r in mine)
            times = [r["planning_time"] for r in mine if r["planning_time"] is not None]
            print(
                f"{robot:<6} {label:<10} {sum(bool(r['success']) for r in mine)}/{len(mine)} certified, "
                f"median planning {statistics.median(times) * 1e3:.0f} ms, paths {dict(sources)}",
                flush=True,
            )


if __name__ == "__main__":
    main()
