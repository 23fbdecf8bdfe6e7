"""The post-processing stage (planbench.bench.postprocess): certified shortcutting applied by the
harness, its suite and command-line setting, its columns in results files, reports and exports."""

import math

import numpy as np
import pytest

import planbench.cli.main as cli
from conftest import midpoint_wall
from planbench import PlanResult, PlanStatus, Problem, Scene, evaluate
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.export import experiments, ompl_log, write_runs_csv
from planbench.bench.postprocess import PostprocessSettingError, PostprocessSettings, apply, segment_checker, shortcut
from planbench.bench.report import PROCESSED_METRICS, metrics_for, summarize, to_markdown
from planbench.bench.suite import SuiteFileError, parse_suite
from planbench.checking.certified import CertifiedChecker
from planbench.validate import ValidationSettings

SHORTCUT = PostprocessSettings(method="shortcut")
BOX = (np.array([0.4, 0.4]), np.array([0.6, 0.6]))  # an obstacle in a 2-D configuration space


def _crosses_box(a, b, lo=BOX[0], hi=BOX[1]):
    """Whether the segment a -> b meets the open box (lo, hi): the slab method, exact."""
    t0, t1 = 0.0, 1.0
    d = b - a
    for i in range(len(a)):
        if abs(d[i]) < 1e-15:
            if not lo[i] < a[i] < hi[i]:
                return False
            continue
        u, v = sorted(((lo[i] - a[i]) / d[i], (hi[i] - a[i]) / d[i]))
        t0, t1 = max(t0, u), min(t1, v)
        if t0 >= t1:
            return False
    return True


def _free(a, b):
    return not _crosses_box(a, b)


def _length(path):
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())


def _around_the_box(n=15):
    """A dense path from (0, 0) to (1, 1) around the box by the corner (0, 1)."""
    corners = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    legs = [np.linspace(corners[i], corners[i + 1], n, endpoint=False) for i in range(2)]
    return np.vstack([*legs, corners[-1:]])


def test_a_shortcut_is_shorter_keeps_the_ends_and_never_crosses_the_obstacle():
    path = _around_the_box()
    assert not _free(path[0], path[-1])  # the straight line is blocked
    for seed in range(5):
        out = shortcut(path, _free, SHORTCUT, seed)
        assert out.shortcuts > 0 and out.checks >= out.shortcuts
        assert _length(out.path) < _length(path)
        assert np.array_equal(out.path[0], path[0]) and np.array_equal(out.path[-1], path[-1])
        assert all(_free(a, b) for a, b in zip(out.path[:-1], out.path[1:], strict=True))
        assert _length(out.path) > math.dist((0, 0), (0.4, 0.6)) + math.dist((0.4, 0.6), (1, 1)) - 1e-9


def test_a_refused_shortcut_changes_nothing_and_a_straight_path_stays():
    path = _around_the_box()
    out = shortcut(path, lambda a, b: False, SHORTCUT, 0)
    assert out.shortcuts == 0 and out.checks > 0 and np.array_equal(out.path, path)
    line = np.linspace([0.0, 0.0], [0.3, 0.1], 20)  # collinear waypoints: nothing to gain, nothing checked
    out = shortcut(line, _free, SHORTCUT, 0)
    assert out.checks == 0 and np.array_equal(out.path, line)


def test_the_same_seed_gives_the_same_path():
    path = _around_the_box()
    one, two = shortcut(path, _free, SHORTCUT, 3), shortcut(path, _free, SHORTCUT, 3)
    assert np.array_equal(one.path, two.path) and one.shortcuts == two.shortcuts
    other = shortcut(path, _free, PostprocessSettings(method="shortcut", attempts=3), 4)
    assert not np.array_equal(other.path, one.path)
    # fewer attempts make the first tries of more: the trace says what each count gives
    few = shortcut(path, _free, PostprocessSettings(method="shortcut", attempts=10), 3)
    assert len(one.trace) == one.attempts == SHORTCUT.attempts and len(few.trace) == 10
    assert [x for _, x in few.trace] == [x for _, x in one.trace[:10]] == sorted([x for _, x in few.trace])[::-1]
    assert _length(few.path) == pytest.approx(few.trace[-1][1])


@pytest.fixture
def walled(panda, free_problem):
    """A thin wall across the straight line, and a dense certified path around it."""
    start, goal = free_problem.start, free_problem.goal.q
    problem = Problem.create(panda, Scene((midpoint_wall(panda, start, goal),)), start, goal, id="test:walled")
    for offset in (-1.0, -1.2, -0.8):  # the shoulder back: the hand passes above the wall
        via = 0.5 * (start + goal)
        via[1] += offset
        path = np.vstack([np.linspace(start, via, 12, endpoint=False), np.linspace(via, goal, 12)])
        result = PlanResult(PlanStatus.SUCCESS, path, target="configuration")
        if evaluate(problem, result).success:
            return problem, result
    pytest.fail("no certified detour around the wall")


def test_the_stage_shortens_a_certified_path_and_the_result_is_certified_again(walled):
    problem, result = walled
    validation = ValidationSettings()
    checker = CertifiedChecker.for_problem(problem, validation.certification(measure_clearance=False))
    assert not checker.check_segment(problem.start, problem.goal.q).free  # the straight line is refused
    for resolution in (0.05, 0.0):  # by the stage too, with its sampled pre-check and without
        free = segment_checker(problem, validation, PostprocessSettings("shortcut", precheck_resolution=resolution))
        assert not free(problem.start, problem.goal.q) and free(result.path[0], result.path[1])
    raw = evaluate(problem, result, validation)
    done = apply(problem, result, raw, validation, SHORTCUT, seed=0)
    assert done.postprocess_note == "" and done.postprocess_shortcuts > 0 and done.postprocess_time >= 0
    assert done.processed_joint_path_length < raw.joint_path_length
    assert 2 < done.processed_n_waypoints < raw.n_waypoints  # not the straight line, fewer waypoints
    assert done.processed_min_clearance > 0 and math.isfinite(done.processed_duration_limited)
    assert (done.joint_path_length, done.n_waypoints) == (raw.joint_path_length, raw.n_waypoints)  # raw kept
    again = apply(problem, result, raw, validation, SHORTCUT, seed=0)
    assert again.processed_joint_path_length == done.processed_joint_path_length
    assert apply(problem, result, raw, validation, PostprocessSettings(), seed=0) == raw  # "none"


def test_a_failed_run_is_not_post_processed(walled):
    problem, result = walled
    claimed = result.replace(status=PlanStatus.TIMEOUT)
    raw = evaluate(problem, claimed)
    assert not raw.success
    assert apply(problem, claimed, raw, ValidationSettings(), SHORTCUT, seed=0) == raw


SUITE = """
[suite]
name = "pp"
problems = ["mbm:table_pick/0001"]
time_limit = 1.0
grace = 0.5
{head}
{table}
[[planners]]
planner = "straight-line"
"""


def test_the_suite_setting_is_parsed_and_named_in_the_settings():
    s = parse_suite(SUITE.format(head='postprocess = "shortcut"', table="[postprocess]\nattempts = 50\n"))
    assert s.postprocess_settings == PostprocessSettings(method="shortcut", attempts=50)
    assert '"postprocess"' in s.settings_json()
    plain = parse_suite(SUITE.format(head="", table=""))
    assert not plain.postprocess_settings.active and '"postprocess"' not in plain.settings_json()


@pytest.mark.parametrize(
    ("head", "table", "expected"),
    [
        ('postprocess = "smooth"', "", "postprocess must be one of 'none', 'shortcut', got 'smooth'"),
        ("postprocess = 1", "", 'postprocess must be "none" or "shortcut"'),
        ('postprocess = "shortcut"', "[postprocess]\nattempts = -1\n", "attempts must be an integer >= 0"),
        ('postprocess = "shortcut"', "[postprocess]\ntries = 5\n", "fields: method, attempts"),
        ("", '[postprocess]\nmethod = "shortcut"\n', "give it as [suite] postprocess"),
    ],
)
def test_bad_post_processing_settings_name_the_file_and_the_problem(head, table, expected):
    with pytest.raises(SuiteFileError, match="pp.toml") as info:
        parse_suite(SUITE.format(head=head, table=table), source="pp.toml")
    assert expected in str(info.value)


def test_the_command_line_option_sets_the_stage_and_refuses_a_bad_value(tmp_path, capsys):
    import argparse

    from planbench.cli.bench import _bench_suite, add_commands

    parser = argparse.ArgumentParser()
    add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["bench", "--problems", "mbm:box/0001", "--postprocess", "shortcut"])
    assert _bench_suite(args).postprocess_settings.method == "shortcut"
    args = parser.parse_args(["bench", "--problems", "mbm:box/0001", "--postprocess", "smooth"])
    with pytest.raises(PostprocessSettingError, match="--postprocess: postprocess must be one of"):
        _bench_suite(args)
    out = tmp_path / "r.db"
    assert cli.main(["bench", "--problems", "mbm:box/0001", "--postprocess", "x", "--out", str(out)]) == 2
    assert "--postprocess" in capsys.readouterr().err and not out.exists()


def test_processed_columns_are_stored_shown_and_read_from_older_files(tmp_path):
    s = parse_suite(SUITE.format(head='postprocess = "shortcut"', table=""), "pp.toml")
    run_benchmark(s, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db", read_only=True) as db:
        (row,) = db.rows()
    assert row["success"] and row["n_waypoints"] == 2  # the straight line: nothing to shortcut
    assert row["processed_joint_path_length"] == pytest.approx(row["joint_path_length"])
    assert row["processed_n_waypoints"] == 2 and row["postprocess_shortcuts"] == 0
    assert row["processed_duration_limited"] == pytest.approx(row["duration_limited"])
    assert metrics_for([row])[-len(PROCESSED_METRICS) :] == PROCESSED_METRICS
    table = to_markdown(summarize([row]), metrics=metrics_for([row]))
    assert "| joint path length [rad] |" in table and "| processed joint path length [rad] |" in table
    (log,) = [ompl_log(exp) for exp in experiments([row])]
    assert "processed solution length REAL" in log and f"{row['processed_joint_path_length']!r}; " in log
    write_runs_csv([row], tmp_path / "runs.csv")
    assert "processed_joint_path_length,processed_ee_path_length" in (tmp_path / "runs.csv").read_text()
    # a results file from before the stage: its rows read without the columns, no processed table
    with ResultsDB(tmp_path / "r.db") as db, db.conn:
        for m in ("processed_n_waypoints", "processed_joint_path_length", "postprocess_time", "postprocess_note"):
            db.conn.execute(f"ALTER TABLE runs DROP COLUMN {m}")
    with ResultsDB(tmp_path / "r.db", read_only=True) as db:
        (old,) = db.rows()
        assert "processed_joint_path_length" not in db.columns
    assert math.isnan(old["processed_joint_path_length"]) and old["processed_n_waypoints"] is None
    assert PROCESSED_METRICS[0] not in metrics_for([old])
    with ResultsDB(tmp_path / "r.db") as db:  # opened for writing: the columns are added back
        assert "processed_joint_path_length" in db.columns


def test_the_stage_never_costs_a_run_its_verdict(walled, monkeypatch):
    from planbench.bench import validator

    problem, result = walled
    fields = {
        "status": "success",
        "path": result.path,
        "times": None,
        "target": "configuration",
        "message": "",
        "info": {},
        "planning_time": 0.1,
        "setup_time": 0.0,
    }
    done = validator.validate_fields(problem, fields, {}, {"method": "shortcut", "attempts": 20}, seed=1)
    assert done["success"] and done["processed_joint_path_length"] < done["joint_path_length"]

    def broken(*args, **kwargs):
        raise MemoryError("no room")

    monkeypatch.setattr(validator, "apply_postprocess", broken)
    kept = validator.validate_fields(problem, fields, {}, {"method": "shortcut"}, seed=1)
    assert kept["success"] and kept["joint_path_length"] == done["joint_path_length"]
    assert math.isnan(kept["processed_joint_path_length"]) and "MemoryError: no room" in kept["postprocess_note"]
