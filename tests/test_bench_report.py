"""Summary statistics and table rendering of benchmark results (no processes)."""

import math

import pytest

from planbench.bench.report import summarize, to_csv, to_markdown, wilson_interval


def test_wilson_interval_known_values():
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    lo, hi = wilson_interval(10, 10)
    assert hi == pytest.approx(1.0) and lo == pytest.approx(0.7225, abs=1e-4)
    lo, hi = wilson_interval(5, 10)
    assert (lo, hi) == (pytest.approx(0.2366, abs=1e-4), pytest.approx(0.7634, abs=1e-4))
    assert all(math.isnan(x) for x in wilson_interval(0, 0))


def _row(planner, family, success, t, status=None):
    return {
        "planner": planner,
        "family": family,
        "success": success,
        "status": status or ("success" if success else "collision"),
        "planning_time": t,
        "setup_time": 0.0,
        "joint_path_length": 2 * t,
        "ee_path_length": math.nan,
        "min_clearance": 0.01,
        "duration": 1.0,
    }


def test_summarize_uses_validated_successes_only():
    rows = [_row("a", "box", True, t) for t in (1.0, 2.0, 3.0, 4.0)]
    rows += [_row("a", "cage", False, 100.0), _row("a", "cage", False, math.nan, "crash")]
    rows += [_row("b", "box", False, 5.0, "error")]
    (a, b) = summarize(rows)
    assert (a["planner"], a["runs"], a["solved"], a["crash"], a["error"]) == ("a", 6, 4, 1, 0)
    assert a["success_rate"] == pytest.approx(4 / 6)
    assert (a["success_ci_low"], a["success_ci_high"]) == pytest.approx(wilson_interval(4, 6))
    assert a["planning_time_median"] == 2.5  # the failed 100 s run is not in the median
    assert (a["planning_time_q1"], a["planning_time_q3"]) == (1.75, 3.25)
    assert math.isnan(a["ee_path_length_median"])
    assert b["solved"] == 0 and b["error"] == 1 and math.isnan(b["planning_time_median"])
    by_family = summarize(rows, ("planner", "family"))
    assert [(s["planner"], s["family"], s["runs"]) for s in by_family] == [
        ("a", "box", 4),
        ("a", "cage", 2),
        ("b", "box", 1),
    ]


def test_markdown_and_csv():
    summary = summarize([_row("a", "box", True, 0.002), _row("a", "box", False, 1.0)])
    md = to_markdown(summary)
    lines = md.strip().splitlines()
    assert lines[0].startswith("| planner | solved | success [95% CI]")
    assert lines[2].startswith("| a | 1/2 | 50% [9, 91] |")
    assert "2 [2, 2]" in lines[2]  # planning time in ms
    csv_text = to_csv(summary).splitlines()
    assert csv_text[0].startswith("planner,runs,solved,success_rate,success_ci_low,success_ci_high,error,timeout,crash")
    assert csv_text[1].startswith("a,2,1,0.5,")
