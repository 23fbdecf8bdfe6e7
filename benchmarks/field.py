"""Benchmark of the matrix field: prints one table of medians and ratios measured in one run.

    python benchmarks/field.py             # 64^3, 128^3, 256^3; L = 21, 61; float32, float64
    python benchmarks/field.py --quick     # 64^3 and 128^3, L = 21
    planbench bench-field ...              # the same from the CLI

See ``planbench/field/bench.py`` for what each column measures.
"""

from __future__ import annotations

import argparse
import sys

from planbench.field.bench import add_arguments, run_from_args


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run_from_args(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
