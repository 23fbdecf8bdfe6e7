"""Solvability certificates: a timed trajectory stored in a scenario, judged as a controller's run
(planbench.reactive.certificate, solvability, spacetime; ``planbench check-scenario``)."""

import dataclasses
import json

import numpy as np
import pytest

from conftest import box
from planbench.cli.main import main
from planbench.errors import ScenarioFileError
from planbench.problem import Problem
from planbench.reactive.motion import Motion
from planbench.reactive.runner import evaluate_run
from planbench.reactive.scenario import MovingObstacle, Scenario
from planbench.reactive.sets import load_scenarios
from planbench.reactive.solvability import certificate_record, verify_certificate
from planbench.reactive.spacetime import SpaceTimeSettings, find_certificate
from planbench.scene import Obstacle, Scene

BUDGET = 30.0  # [s] far more than the solvable scenario needs (a fraction of a second): never the limit


def _waiting(problem: Problem) -> Scenario:
    """A 5 cm ball on the arm's straight path (where the hand is 60 % of the way) until 0.8 s: it
    touches the goal configuration, so every solution waits for it to go (3 s horizon)."""
    centre = problem.robot.frame_pose(_blocked(problem)).translation
    ball = MovingObstacle(Obstacle("ball", "sphere", tuple(centre), radius=0.05), Motion(), disappear=0.8)
    return Scenario(problem, (ball,), control_rate=100.0, horizon=3.0, name="test:waiting")


def _blocked(problem: Problem) -> np.ndarray:
    return np.asarray(problem.start) + 0.6 * (np.asarray(problem.goal.q) - np.asarray(problem.start))


@pytest.fixture(scope="module")
def solved(panda):
    goal = panda.home + 0.3
    problem = Problem.create(panda, Scene(name="empty"), panda.home, goal, id="test:free")
    scenario = _waiting(problem)
    search = find_certificate(scenario, SpaceTimeSettings(budget=BUDGET))
    assert search.certificate is not None, search.reason
    return dataclasses.replace(scenario, certificate=search.certificate)


def test_a_found_certificate_replays_as_a_success(solved):
    cert = solved.certificate
    record = certificate_record(solved, cert)
    metrics = evaluate_run(solved, record)
    assert metrics.success, metrics.failure
    assert metrics.time_to_goal == pytest.approx(cert.time_to_goal)
    assert cert.time_to_goal > 0.8  # the ball is there until 0.8 s: it waited
    assert record.times[1] - record.times[0] == pytest.approx(solved.period)  # sampled at the control ticks
    assert verify_certificate(solved).success
    # the file's form (rounded) is what was verified: it survives the JSON unchanged and verifies again
    again = Scenario.from_dict(json.loads(json.dumps(solved.to_dict())))
    assert np.array_equal(again.certificate.path, cert.path) and np.array_equal(again.certificate.times, cert.times)
    assert verify_certificate(again).success


def test_a_knot_moved_into_the_obstacle_is_refused(solved):
    cert = solved.certificate
    times = np.append(cert.times, 0.4)
    path = np.vstack([cert.path, _blocked(solved.problem)])
    order = np.argsort(times)
    tampered = dataclasses.replace(cert, times=times[order], path=path[order])
    metrics = verify_certificate(solved, tampered)
    assert not metrics.success and "collision with obstacle:ball" in metrics.failure


def test_a_certificate_faster_than_the_velocity_limits_is_refused(solved):
    cert = solved.certificate
    fast = dataclasses.replace(cert, times=cert.times / 10, time_to_goal=cert.time_to_goal / 10)
    metrics = verify_certificate(solved, fast)
    assert not metrics.success and "above its velocity limit" in metrics.failure


def test_a_certificate_that_misstates_its_time_or_its_start_is_refused(solved):
    cert = solved.certificate
    late = verify_certificate(solved, dataclasses.replace(cert, time_to_goal=cert.time_to_goal + 0.5))
    assert not late.success and "reaches the goal at" in late.failure
    path = cert.path.copy()
    path[0] += 1e-3
    moved = verify_certificate(solved, dataclasses.replace(cert, path=path))
    assert not moved.success and "start" in moved.failure


def _walled(panda) -> Scenario:
    """The waiting scenario with a static box around the hand at the goal: impossible."""
    goal = panda.home + 0.3
    hand = panda.frame_pose(goal).translation
    scene = Scene((box("cage", hand, (0.3, 0.3, 0.3)),), "caged")
    return _waiting(Problem.create(panda, scene, panda.home, goal, id="test:caged"))


def test_a_goal_inside_a_wall_gets_no_certificate(panda):
    search = find_certificate(_walled(panda), SpaceTimeSettings(budget=BUDGET))
    # refused because it is impossible (the goal is in the static scene's collision), not for time
    assert search.certificate is None and "goal" in search.reason and search.elapsed < BUDGET


def test_a_start_hit_at_time_zero_gets_no_certificate(free_problem):
    centre = free_problem.robot.frame_pose(np.asarray(free_problem.start)).translation
    ball = MovingObstacle(Obstacle("ball", "sphere", tuple(centre), radius=0.05), Motion(), disappear=0.5)
    search = find_certificate(Scenario(free_problem, (ball,), horizon=2.0), SpaceTimeSettings(budget=BUDGET))
    assert search.certificate is None and "start" in search.reason


def test_scenarios_without_a_certificate_load_as_before():
    d = load_scenarios("dynamic-smoke")[0].to_dict()  # the shipped ones are certified
    d.pop("certificate", None)
    assert Scenario.from_dict(d).certificate is None


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda c: c.update(times=c["times"][::-1]), "times"),
        (lambda c: c.update(path=[q[:-1] for q in c["path"]]), "path"),
        (lambda c: c.update(path=c["path"][:-1]), "path"),
        (lambda c: c.update(path="fast"), "path"),
        (lambda c: c.pop("time_to_goal"), "time_to_goal"),
        (lambda c: c.update(time_to_goal="soon"), "time_to_goal"),
        (lambda c: c.update(speed=1), "speed"),
    ],
)
def test_a_malformed_certificate_is_a_scenario_file_error_naming_the_field(solved, change, field):
    d = solved.to_dict()
    change(d["certificate"])
    with pytest.raises(ScenarioFileError, match=f"certificate: .*{field}"):
        Scenario.from_dict(d, "bad.json")
    d["certificate"] = [1, 2]
    with pytest.raises(ScenarioFileError, match="certificate: must be a JSON object"):
        Scenario.from_dict(d, "bad.json")


# --- planbench check-scenario ---------------------------------------------------------------------


def _file(tmp_path, scenario, name):
    path = tmp_path / name
    d = scenario.to_dict()
    d.pop("certificate", None)
    path.write_text(json.dumps(d))
    return path


def test_check_scenario_stores_a_certificate_and_verifies_it_later(solved, tmp_path, capsys):
    path = _file(tmp_path, solved, "waiting.json")
    assert main(["check-scenario", str(path), "--budget", str(BUDGET), "--replay", str(tmp_path / "r.html")]) == 0
    stored = Scenario.load(path)
    assert stored.certificate is not None and verify_certificate(stored).success
    assert (tmp_path / "r.html").stat().st_size > 0
    text = path.read_text()
    assert main(["check-scenario", str(path)]) == 0  # verified, not searched again
    assert "certificate verified" in capsys.readouterr().out and path.read_text() == text


def test_check_scenario_no_write_leaves_the_file(solved, tmp_path):
    path = _file(tmp_path, solved, "waiting.json")
    text = path.read_text()
    assert main(["check-scenario", str(path), "--budget", str(BUDGET), "--no-write"]) == 0
    assert path.read_text() == text


def test_check_scenario_certifies_a_set_once_per_geometry(solved, tmp_path, capsys):
    d = solved.to_dict()
    d.pop("certificate")
    depth = dict(d, name="test:waiting-depth", sensing={"model": "depth"})
    path = tmp_path / "set.json"
    path.write_text(json.dumps({"format": "planbench-scenario-set/1", "scenarios": [d, depth]}))
    assert main(["check-scenario", str(path), "--budget", str(BUDGET)]) == 0
    assert "of the same geometry verified" in capsys.readouterr().out
    stored = json.loads(path.read_text())["scenarios"]
    assert stored[0]["certificate"] == stored[1]["certificate"]


def test_check_scenario_exits_1_when_a_scenario_has_no_certificate(panda, tmp_path, capsys):
    path = _file(tmp_path, _walled(panda), "caged.json")
    assert main(["check-scenario", str(path), "--budget", str(BUDGET)]) == 1
    assert "NO certificate" in capsys.readouterr().out
    assert "certificate" not in json.loads(path.read_text())


@pytest.mark.parametrize(
    "args, says",
    [
        (["missing.json"], "cannot read"),
        (["bad.json"], "not valid JSON"),
        (["tampered.json"], "certificate: "),
        (["ok.json", "--budget", "-1"], "--budget"),
        (["ok.json", "--budget", "nan"], "--budget"),
    ],
)
def test_check_scenario_bad_input_is_a_named_error_with_exit_2(solved, tmp_path, monkeypatch, capsys, args, says):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.json").write_text("{not json")
    _file(tmp_path, solved, "ok.json")
    d = solved.to_dict()
    d["certificate"]["times"] = "later"
    (tmp_path / "tampered.json").write_text(json.dumps(d))
    assert main(["check-scenario", *args]) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err


def test_the_report_tables_put_the_certificate_beside_the_controllers(solved, tmp_path):
    from planbench.bench.report import CERTIFICATE, certificate_rows, summarize

    path = tmp_path / "waiting.json"
    path.write_text(json.dumps(solved.to_dict()))
    run = {"suite": "s", "problem": str(path), "family": "f", "planner": "ctl", "seed": 0, "success": True}
    run.update(status="success", deadline_misses=0, time_to_goal=2.5)
    rows = [run, dict(run, seed=1, time_to_goal=3.5)]
    extra = certificate_rows(rows)
    assert [r["planner"] for r in extra] == [CERTIFICATE]  # one per scenario, not per run
    lines = {s["planner"]: s for s in summarize([*rows, *extra], ("planner", "family"))}
    assert lines[CERTIFICATE]["time_to_goal_median"] == pytest.approx(solved.certificate.time_to_goal)
    assert lines["ctl"]["time_to_goal_median"] == pytest.approx(3.0)
    bare = _file(tmp_path, solved, "bare.json")  # no scenario with a certificate: no line
    assert certificate_rows([dict(run, problem=str(bare)), dict(run, problem="dynamic:none/0001")]) == []
