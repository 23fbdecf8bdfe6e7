"""``benchmarks/dynamic_summary.py --truth-gap``: depth against truth paired by scenario and seed,
with a gap interval that resamples scenarios (the figure issue 30's goal is stated in)."""

from __future__ import annotations

import importlib.util
import pathlib

import pytest

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / "dynamic_summary.py"


@pytest.fixture(scope="module")
def summary():
    spec = importlib.util.spec_from_file_location("dynamic_summary", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _row(sensing: str, n: int, seed: int, success: bool, robot: str = "panda") -> dict:
    return {
        "planner": "ompl-replan",
        "problem": f"dynamic:{robot}_crossing_fast_{sensing}/{n:04d}",  # as the results file names them
        "seed": seed,
        "success": success,
    }


def _gap_line(table: str) -> list[str]:
    return [cell.strip() for cell in table.splitlines()[-1].strip("|").split("|")]


def test_the_gap_pairs_depth_with_truth_by_scenario_and_seed(summary):
    rows = [_row("truth", n, seed, True) for n in (1, 2, 3) for seed in (0, 1)]
    rows += [_row("depth", n, seed, not (n == 1 or (n == 2 and seed == 1))) for n in (1, 2, 3) for seed in (0, 1)]
    rows.append(_row("depth", 4, 0, False))  # no truth twin: not counted
    cells = _gap_line(summary.truth_gap(rows))
    assert cells[2] == "0,1"
    assert cells[3].endswith("(6/6)") and cells[4].endswith("(3/6)")
    gap, interval = cells[5].split(" ", 1)
    assert gap == "50.0"
    lo, hi = (float(x) for x in interval.strip("[]").split(","))
    assert 0.0 <= lo < 50.0 < hi <= 100.0  # three scenarios: a wide interval


def test_no_difference_is_a_gap_of_zero_with_a_zero_interval(summary):
    rows = [_row(s, n, 0, n % 2 == 0) for s in ("truth", "depth") for n in range(1, 9)]
    assert _gap_line(summary.truth_gap(rows))[5] == "0.0 [0.0, 0.0]"
