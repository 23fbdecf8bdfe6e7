"""Hard time limits of static runs: an answer after the time limit is a ``timeout`` that did not
succeed, whatever its path, in a benchmark, in ``planbench plan`` and from ``planbench.plan``; a
row's success never contradicts its status. Planners in tests/bench_adversarial_planners.py."""

from __future__ import annotations

import json
import time

import planbench
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.suite import parse_suite
from planbench.cli.main import main

FREE = "mbm:table_pick/0001"  # the straight line solves it
A = "bench_adversarial_planners"
LIMIT = 2.0


def _planner(label: str, settings: str = "", planner: str = f"{A}:LatePlanner") -> str:
    return f'[[planners]]\nlabel = "{label}"\nplanner = "{planner}"\nsettings = {{ {settings} }}\n'


def test_an_answer_after_the_limit_is_a_timeout_whatever_its_path(tmp_path):
    suite = f"""
[suite]
name = "limits"
problems = ["{FREE}"]
seeds = [0]
time_limit = {LIMIT}
grace = 5.0
"""
    suite += _planner("late", "past = 1.0")
    suite += _planner("late-clock-frozen", "past = 1.0, freeze_clock = true")  # only the parent's clock sees it
    suite += _planner("claims-failure", f'past = {-LIMIT}, status = "step_limit"')
    suite += _planner("late-claims-timeout", 'past = 1.0, status = "timeout"')
    suite += _planner("straight-line", planner="straight-line")
    db_path = tmp_path / "r.db"
    run_benchmark(parse_suite(suite, "limits.toml"), db_path, jobs=2)
    with ResultsDB(db_path) as db:
        rows = {r["planner"]: r for r in db.rows(with_arrays=True)}
    assert len(rows) == 5
    for row in rows.values():  # status and success never contradict
        assert not row["success"] or row["status"] == "success", row
    for label in ("late", "late-clock-frozen", "late-claims-timeout"):
        row = rows[label]
        assert row["status"] == "timeout" and not row["success"], (label, row["failure"])
        assert f"past the time limit of {LIMIT:g} s" in row["failure"], (label, row["failure"])
        assert "its path (valid) and metrics are kept" in row["failure"], (label, row["failure"])
        assert json.loads(row["checks"])["in_time"] is False
        assert row["path"] is not None and row["joint_path_length"] > 0  # kept for inspection
        assert row["planning_time"] > LIMIT
    claimed = rows["claims-failure"]
    assert claimed["status"] == "step_limit" and not claimed["success"]
    assert "not counted" in claimed["failure"] and json.loads(claimed["checks"])["claimed_success"] is False


def test_plan_in_process_makes_a_late_answer_a_timeout():
    problem = planbench.load_problems(FREE)[0]
    result = planbench.plan(problem, f"{A}:LatePlanner", time_limit=0.2, past=0.5)
    assert result.status is planbench.PlanStatus.TIMEOUT and result.path is not None
    assert "past the time limit of 0.2 s" in result.message and "the planner said success" in result.message
    ev = planbench.evaluate(problem, result)
    assert not ev.success and ev.status == "timeout"


def test_planbench_plan_kills_a_planner_at_its_limit(tmp_path, capsys):
    out = tmp_path / "m.json"
    t0 = time.monotonic()
    argv = ["plan", "--problem", FREE, "--planner", f"{A}:LatePlanner", "--set", "past=30", "--time-limit", "1"]
    assert main([*argv, "--json", str(out)]) == 1
    assert time.monotonic() - t0 < 25  # killed, not waited for (it would answer after 31 s)
    (row,) = json.loads(out.read_text())
    assert row["status"] == "timeout" and row["success"] is False
    assert "worker process killed" in row["failure"]
    assert "0/1 solved" in capsys.readouterr().out


def test_planbench_plan_shows_a_late_answer_as_a_timeout(tmp_path):
    """Answered 0.6 s late (or killed at 1 s + 1 s grace on a very slow machine): a timeout either way."""
    out = tmp_path / "m.json"
    argv = ["plan", "--problem", FREE, "--planner", f"{A}:LatePlanner", "--set", "past=0.6", "--time-limit", "1"]
    assert main([*argv, "--json", str(out)]) == 1
    (row,) = json.loads(out.read_text())
    assert row["status"] == "timeout" and row["success"] is False
    assert "past the time limit of 1" in row["failure"]
