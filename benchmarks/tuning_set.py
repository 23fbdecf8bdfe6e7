"""Write a tuning set of generated problems (another seed than the shipped ``gen:`` test set) as
problem files, for a suite's ``problems``.

    python benchmarks/tuning_set.py --out tuning/ur5 --robot ur5 -n 10 --seed 1

MotionBenchMaker has only the Panda, so settings that matter on other arms are chosen on a set the
generator draws with a seed other than the shipped one (``gen:`` is seed 0 and stays a test set).
The escapes' defaults were chosen on ``--robot ur5 -n 10 --seed 1`` (40 problems) beside
MotionBenchMaker 0001-0020.
"""

from __future__ import annotations

import argparse

from _bench import write_problems

from planbench.problems import generators
from planbench.robot import load_robot


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="folder for the problem files")
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("-n", type=int, default=10, help="problems per family")
    parser.add_argument("--seed", type=int, default=1, help="not 0: that is the shipped test set")
    args = parser.parse_args(argv)
    if args.seed == generators.SHIPPED_SEED:
        parser.error(f"seed {args.seed} draws the shipped gen: set, which is a test set")
    load_robot(args.robot)  # a bad name fails here, with the known robots
    problems = [
        generators.generate_problem(args.robot, family, index, seed=args.seed)
        for family in generators.FAMILIES
        for index in range(1, args.n + 1)
    ]
    print(f"{len(problems)} problems in {write_problems(problems, args.out)}")


if __name__ == "__main__":
    main()
