"""Scenario sets, the scenario generator, and closed-loop suites through the benchmark (workers,
validator, results file)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import planbench
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.suite import SuiteFileError, load_suite, parse_suite
from planbench.errors import UnknownNameError
from planbench.problem import Problem
from planbench.reactive import Scenario
from planbench.reactive.checker import TickChecker
from planbench.reactive.generator import BEHAVIOURS, SPEEDS, base_problem, scenario
from planbench.reactive.sets import load_scenarios, scenario_names
from planbench.scene import Scene


def test_the_dynamic_set_loads_by_name_like_problem_sets():
    everything = planbench.load_scenarios("dynamic")
    assert len(everything) == 432 and len(set(scenario_names())) == 432
    assert {s.problem.robot.name for s in everything} == {"panda", "ur5", "xarm7"}
    for key, values in (("behaviour", BEHAVIOURS), ("speed", tuple(SPEEDS)), ("sensing", ("truth", "depth"))):
        assert {s.metadata[key] for s in everything} == set(values)
    smoke = load_scenarios("dynamic-smoke")
    assert len(smoke) == 4 and {s.sensing.model for s in smoke} == {"truth", "depth"}
    fast_ur5 = load_scenarios("dynamic:ur5_*_fast_*")
    assert len(fast_ur5) == 48 and all(s.metadata["speed"] == "fast" for s in fast_ur5)
    assert [s.name for s in load_scenarios("dynamic:panda_crossing_slow_truth/0002")] == [
        "dynamic:panda_crossing_slow_truth/0002"
    ]
    with pytest.raises(UnknownNameError, match="scenario set"):
        load_scenarios("dynamic:tiger_*")


def test_a_saved_scenario_names_its_problem_and_loads_back(tmp_path):
    s = load_scenarios("dynamic:panda_swinging_fast_depth/0001")[0]
    s.save(tmp_path / "s.json")
    assert json.loads((tmp_path / "s.json").read_text())["problem"] == "mbm:box/0001"
    assert load_scenarios(tmp_path / "s.json")[0].to_dict() == s.to_dict()
    bare = load_scenarios("dynamic:ur5_sliding_fast_depth/0005")[0]  # gen:ur5_table_clutter/0003, objects removed
    bare.save(tmp_path / "bare.json")
    assert json.loads((tmp_path / "bare.json").read_text())["problem"] == "gen:ur5_table_clutter/0003:bare"
    names = [o.name for o in bare.problem.scene.obstacles]
    assert "table_top" in names and not [n for n in names if n.startswith("object")]
    assert load_scenarios(tmp_path / "bare.json")[0].to_dict() == bare.to_dict()


def _same(a, b, tol: float = 1e-9) -> bool:
    """JSON data equal, numbers to ``tol`` (a pose read back from JSON differs in the last bit)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k], tol) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_same(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, (int, float)):
        return abs(a - b) <= tol
    return a == b


def test_the_generator_gives_the_shipped_scenarios_and_keeps_its_promises():
    shipped = {s.name: s for s in load_scenarios("dynamic:ur5_*/0004")}
    ref = "gen:ur5_table_clutter/0002:bare"
    problem = base_problem(ref)
    for behaviour in BEHAVIOURS[:3]:  # the others' promises: tests/test_dynamic_set.py
        made = {speed: scenario(problem, ref, behaviour, speed, "truth", index=4) for speed in SPEEDS}
        for speed, s in made.items():
            written = shipped[s.name].to_dict()
            assert written.pop("certificate")  # certified after generation (planbench.reactive.certify_set)
            assert _same(s.to_dict(), written)  # lengths rounded: round-off cannot move them
            alone = TickChecker(
                Scenario(Problem.create(problem.robot, Scene(), problem.start, problem.goal.q), s.moving)
            )
            # the start is clear of the moving obstacle at first, the goal over the second half
            assert min(alone.clearance(np.asarray(problem.start), t) for t in np.arange(0, 0.5, 0.05)) >= 0.05
            second_half = np.arange(0.5 * s.horizon, s.horizon, 0.05)
            assert min(alone.clearance(np.asarray(problem.goal.q), t) for t in second_half) >= 0.02
            assert s.moving[0].speed_bound() == pytest.approx(SPEEDS[speed], rel=0.15)
        # the speeds are paired: one draw, the same shape
        assert len({s.metadata["draw"] for s in made.values()}) == 1
        assert len({s.moving[0].obstacle.type for s in made.values()}) == 1


def test_dynamic_suites_parse_and_refuse_mixed_or_wrong_keys():
    s = load_suite("dynamic-smoke")
    assert (
        s.kind == "dynamic"
        and s.problems == ("dynamic-smoke",)
        and [p.planner for p in s.planners]
        == [
            "matrix-field",
            "edt-field",
        ]
    )
    assert json.loads(s.settings_json())["timing"] == "measured"
    mixed = '[suite]\nname = "x"\nscenarios = ["dynamic-smoke"]\nproblems = ["mbm:box/0001"]\n'
    mixed += '[[controllers]]\ncontroller = "a"\n'
    with pytest.raises(SuiteFileError, match="not both"):
        parse_suite(mixed, "mixed.toml")
    wrong_key = '[suite]\nname = "x"\nscenarios = ["dynamic-smoke"]\n[[controllers]]\nplanner = "a"\n'
    with pytest.raises(SuiteFileError, match="unknown key"):
        parse_suite(wrong_key, "wrong.toml")
    static_timing = (
        '[suite]\nname = "x"\nproblems = ["mbm:box/0001"]\ntiming = "ideal"\n[[planners]]\nplanner = "straight-line"\n'
    )
    with pytest.raises(SuiteFileError, match="timing is for closed-loop suites"):
        parse_suite(static_timing, "t.toml")


DYNAMIC = """
[suite]
name = "dyn"
scenarios = ["dynamic:ur5_sliding_slow_truth/0004", "dynamic:panda_crossing_fast_truth/0001"]
timing = "ideal"
time_limit = 120.0

[[controllers]]
label = "to-goal"
controller = "bench_controllers:ToGoalController"

[[controllers]]
label = "raises"
controller = "bench_controllers:RaisingController"
"""


@pytest.mark.slow
def test_a_closed_loop_suite_runs_in_workers_and_is_validated_from_its_trajectory(tmp_path):
    db_path = tmp_path / "d.db"
    outcome = run_benchmark(parse_suite(DYNAMIC, "dyn.toml"), db_path, jobs=2)
    assert (outcome.total, outcome.ran) == (4, 4)
    with ResultsDB(db_path) as db:
        rows = {(r["planner"], r["problem"]): r for r in db.rows(with_arrays=True)}
    ok = rows["to-goal", "dynamic:ur5_sliding_slow_truth/0004"]
    s = load_scenarios("dynamic:ur5_sliding_slow_truth/0004")[0]
    # the worker's trajectory, the validator's verdict: what the runner measured agrees with them
    assert ok["status"] in ("success", "collision", "timeout")
    assert ok["success"] == (ok["failure"] == "")
    assert ok["path"].shape[1] == 6 and ok["times"][0] == 0.0 and np.all(np.diff(ok["times"]) > 0)
    assert ok["deadline_misses"] == 0 and math.isfinite(ok["tick_time_median"]) and ok["tick_time_p99"] >= 0
    assert math.isfinite(ok["min_clearance"]) and ok["path_length"] > 0
    if ok["success"]:
        assert ok["time_to_goal"] == pytest.approx(ok["times"][-1])
    assert s.problem.robot.nq == 6
    err = rows["raises", "dynamic:panda_crossing_fast_truth/0001"]
    assert err["status"] == "error" and not err["success"] and "fails on purpose" in err["message"]
    assert err["path"] is not None and len(err["path"]) == 3  # the 2 ticks run before it raised: kept
    assert err["failure"].startswith("error:")


def test_the_command_line_refuses_bad_scenarios_and_controllers_with_exit_code_2(tmp_path, capsys):
    from planbench.cli.main import main

    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "planbench-scenario/1", "problem": "mbm:box/0001", "horizon": -1}')
    suite = tmp_path / "s.toml"
    suite.write_text(f'[suite]\nname = "bad"\nscenarios = ["{bad}"]\n[[controllers]]\ncontroller = "matrix-field"\n')
    assert main(["bench", "--suite", str(suite), "--out", str(tmp_path / "r.db")]) == 2
    assert "horizon must be > 0" in capsys.readouterr().err
    suite.write_text('[suite]\nname = "bad"\nscenarios = ["dynamic-smoke"]\n[[controllers]]\ncontroller = "x-field"')
    assert main(["bench", "--suite", str(suite), "--out", str(tmp_path / "r.db")]) == 2
    assert "unknown controller 'x-field'" in capsys.readouterr().err
    assert not (tmp_path / "r.db").exists()  # refused before any run: no results file left behind
