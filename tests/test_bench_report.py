"""Summary statistics and table rendering of benchmark results (no processes)."""

import math

import pytest

from planbench.bench.report import summarize, to_csv, to_markdown
from planbench.metrics import wilson_interval


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


def _run(planner, success, status="success", pair="", **more):
    base = {"planner": planner, "success": success, "status": status, "collision_pair": pair}
    return {**base, **more}


def test_failure_reasons_name_the_link_the_stall_and_the_limits():
    from planbench.bench.report import failure_reason, failure_text

    rows = [
        _run("p", False, "success", "panda_hand / obstacle:table"),  # a claimed success the harness refused
        _run("p", False, "collision", "panda_hand / obstacle:shelf"),
        _run("p", False, "collision", "panda_link5 / obstacle:shelf"),
        _run("p", False, "collision", "panda_link7 / panda_link2"),
        _run("p", False, "local_minimum"),
        _run("p", False, "timeout"),
        _run("p", False, "timeout", deadline_misses=3),
        _run("p", False, "crash"),
        _run("p", True),
    ]
    assert [failure_reason(r) for r in rows] == [
        "collision panda_hand",
        "collision panda_hand",
        "collision panda_link5",
        "self-collision panda_link7/panda_link2",
        "stall",
        "time limit",
        "horizon",
        "crash",
        "",
    ]
    assert failure_text(rows) == (
        "collision 3 (panda_hand 2, panda_link5 1), self-collision 1 (panda_link7/panda_link2 1), "
        "stall 1, time limit 1, horizon 1, crash 1"
    )


def test_the_terminal_table_is_whole_in_80_columns():
    from rich.console import Console

    from planbench.bench.report import TERMINAL_METRICS, summarize, to_rich

    rows = []
    for planner in ("matrix-field-guided", "ompl-rrtconnect", "straight-line"):
        for k in range(6):
            ok = k % 2 == 0
            rows.append(
                _run(
                    planner,
                    ok,
                    "success" if ok else "collision",
                    "" if ok else "panda_hand / obstacle:box",
                    planning_time=0.1234 * (k + 1),
                    setup_time=0.01,
                    joint_path_length=3.21,
                    ee_path_length=1.234,
                    min_clearance=0.0123,
                    duration=2.5,
                )
            )
    console = Console(width=80, record=True, color_system=None)
    console.print(to_rich(summarize(rows), ("planner",), title="t", metrics=TERMINAL_METRICS, width=80))
    text = console.export_text()
    assert max(len(line) for line in text.splitlines()) <= 80
    assert "…" not in text  # no cell cut
    for cell in ("matrix-field-guided", "50% [19, 81]", "collision 3 (panda_hand 3)", "370", "12.3", "2.5"):
        assert cell in text
    wide = Console(width=80, record=True, color_system=None)
    wide.print(to_rich(summarize(rows), ("planner",), metrics=TERMINAL_METRICS, width=80, wide=True))
    assert "…" in wide.export_text()  # one table, cut to the terminal: what --wide asks for


def test_plots_show_a_single_success_and_zero_rates_and_write_every_format(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from planbench.bench.plots import _ecdf_axes, write_plots
    from planbench.bench.report import METRICS

    rows = [
        _run("one", True, planning_time=0.2, family="box", problem="a", seed=0, time_limit=1.0),
        _run(
            "one",
            False,
            "collision",
            "panda_hand / obstacle:x",
            planning_time=0.3,
            family="cage",
            problem="b",
            seed=0,
            time_limit=1.0,
        ),
        _run("none", False, "local_minimum", planning_time=0.1, family="box", problem="a", seed=0, time_limit=1.0),
    ]
    for r in rows:
        r.update({m.name: 1.0 for m in METRICS if m.name not in r})
    fig, ax = plt.subplots()
    _ecdf_axes(ax, rows, METRICS[0], ["none", "one"])
    (line,) = ax.get_lines()  # the planner with one success is drawn, from 0 to 1; the other has none
    assert min(line.get_ydata()) == 0.0 and max(line.get_ydata()) == 1.0
    plt.close(fig)
    for fmt in ("png", "pdf", "svg"):
        files = write_plots(rows, tmp_path / fmt, fmt, by="family")
        assert files and all(f.suffix == f".{fmt}" and f.stat().st_size > 1000 for f in files)
    svg = (tmp_path / "svg" / "success_by_family.svg").read_text()
    assert "0/1" in svg and "1/1" in svg  # a 0 % bar reads as 0 of 1 run, not as missing data


def test_valid_paths_that_failed_are_named_apart():
    """A late answer and a valid path with a failure status are failures the tables name, with the
    status claimed; rows written before these checks existed keep their old reasons."""
    from planbench.bench.report import failure_reason, failure_text, valid_path_failure

    path_ok = {"starts_at_start": True, "collision_free": True, "goal_pose": True}
    late = _run("p", False, "timeout", checks={**path_ok, "claimed_success": True, "in_time": False})
    claimed = _run("p", False, "step_limit", checks={**path_ok, "claimed_success": False})
    claimed_json = _run("p", False, "timeout", checks='{"claimed_success": false, "collision_free": true}')
    unclaimed = {**path_ok, "collision_free": False, "claimed_success": False}
    bad_and_unclaimed = _run("p", False, "timeout", checks=unclaimed)
    old = _run("p", False, "timeout", checks='{"collision_free": true}')
    rows = [late, claimed, claimed_json, bad_and_unclaimed, old, _run("p", True, checks=path_ok)]
    assert [valid_path_failure(r) for r in rows] == ["late", "claimed_failure", "claimed_failure", "", "", ""]
    assert [failure_reason(r) for r in rows] == [
        "late",
        "claimed-failure step limit",
        "claimed-failure timeout",
        "time limit",
        "time limit",
        "",
    ]
    assert failure_text(rows) == "claimed-failure 2 (step limit 1, timeout 1), time limit 2, late 1"
    (s,) = summarize([{**r, "planning_time": 1.0} for r in rows], metrics=())
    assert (s["solved"], s["timeout"], s["late"], s["claimed_failure"]) == (1, 4, 1, 2)
