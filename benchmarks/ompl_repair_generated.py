"""OMPL's repair of failing segments on scenes the repository does not ship: generated clutter
(benchmarks/recheck.py's generator) for the Panda and the UR5, with and without repair.

Prints per robot and variant the certified successes (``planbench.evaluate``), the median planning
time and where the returned paths came from. In-process runs (OMPL reseeded per query).

    python benchmarks/ompl_repair_generated.py --problems 12 --seed 3
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections import Counter
from pathlib import Path

import planbench

sys.path.insert(0, str(Path(__file__).parent))
from recheck import generated_problems  # noqa: E402  (the scene generator beside this script)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", type=int, default=12, help="generated problems per robot")
    ap.add_argument("--seed", type=int, default=3, help="seed of the generated scenes")
    ap.add_argument("--time-limit", type=float, default=5.0)
    args = ap.parse_args()
    for robot in ("panda", "ur5"):
        problems = generated_problems(robot, args.problems, seed=args.seed)
        for label, attempts in (("no repair", 0), ("repair", 5)):
            solved, times, sources = 0, [], Counter()
            for p in problems:
                r = planbench.plan(p, "ompl-rrtconnect", seed=0, time_limit=args.time_limit, repair_attempts=attempts)
                solved += planbench.evaluate(p, r).success
                times.append(r.planning_time)
                sources[r.info.get("path_source", "-")] += 1
            print(
                f"{robot:<6} {label:<10} {solved}/{len(problems)} certified, "
                f"median planning {statistics.median(times) * 1e3:.0f} ms, paths {dict(sources)}",
                flush=True,
            )


if __name__ == "__main__":
    main()
