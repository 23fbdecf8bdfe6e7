"""Write generated closed-loop scenarios on base problems of your choice as scenario files, for a
suite's ``scenarios`` (a tuning set beside ``dynamic-tune``).

    python benchmarks/scenario_tune_set.py --out benchmarks/scenarios/shelf-tune \
        --base mbm:bookshelf_tall/0002 --base mbm:bookshelf_small/0002

``dynamic-tune`` has one base problem per robot (the Panda's is ``mbm:box/0001``), so a controller's
behaviour in a deep shelf, which ``dynamic-test`` has (``mbm:bookshelf_tall/0001``), cannot be
chosen on it. This draws the same behaviours, speeds and sensing as the shipped set
(:func:`planbench.reactive.generator.scenario`) on other problems, from MotionBenchMaker's tuning
range (0001-0020) or a generated set drawn with a seed other than the shipped one. The files are
not certified solvable (``planbench check-scenario`` certifies one); compare controllers on them
paired, scenario by scenario.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from planbench.errors import PlanbenchError
from planbench.reactive import generator


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="folder for the scenario files")
    parser.add_argument("--base", action="append", required=True, help="a base problem (repeat)")
    parser.add_argument("--sensing", choices=generator.SENSING, default="depth")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    shipped = set(generator.BASE_PROBLEMS)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n = 0
    for index, ref in enumerate(args.base, start=1):
        if ref in shipped:
            parser.error(f"{ref} is a base problem of the shipped dynamic set; choose another")
        problem = generator.base_problem(ref)
        for behaviour in generator.BEHAVIOURS:
            for speed in generator.SPEEDS:
                try:
                    s = generator.scenario(problem, ref, behaviour, speed, args.sensing, args.seed, index=index)
                except PlanbenchError as e:  # no valid draw of this behaviour on this problem
                    print(f"left out: {e}")
                    break
                s = dataclasses.replace(s, name=s.name.replace("dynamic:", "tune:"))
                s.save(out / f"{s.name.split(':', 1)[1].replace('/', '_')}.json")
                n += 1
    print(f"{n} scenarios in {out}")


if __name__ == "__main__":
    main()
