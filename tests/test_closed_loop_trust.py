"""Closed-loop verdicts no controller can fake (issue 27): controllers written to fool the benchmark,
run through ``planbench bench``, and the simulation's own record checked against the control model.

None of these asserts depends on how fast the machine is: charged compute is CPU time, and each
bound below is a fraction of work the controller is known to have done."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.suite import parse_suite
from planbench.reactive.bench import evaluate_record
from planbench.reactive.runner import RunSettings, run_scenario
from planbench.reactive.sets import load_scenario

SCENARIO = "dynamic:panda_crossing_slow_truth/0001"


def _scenario_file(tmp_path, horizon: float) -> str:
    d = load_scenario(SCENARIO).to_dict()
    d.update(name="hostile", horizon=horizon, metadata={})
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(d))
    return str(path)


def _bench(tmp_path, controllers: list[str], horizon: float = 1.0) -> dict[str, dict]:
    entries = "".join(f'[[controllers]]\ncontroller = "bench_hostile_controllers:{c}"\n' for c in controllers)
    suite = (
        f'[suite]\nname = "hostile"\nscenarios = ["{_scenario_file(tmp_path, horizon)}"]\n'
        f'timing = "measured"\ntime_limit = 120.0\n{entries}'
    )
    db_path = tmp_path / "h.db"
    run_benchmark(parse_suite(suite, "hostile.toml"), db_path, jobs=2)
    with ResultsDB(db_path) as db:
        return {r["planner"].split(":")[-1]: r for r in db.rows(with_arrays=True)}


def _within_velocity_limits(row, scenario) -> bool:
    vmax = np.asarray(scenario.problem.robot.velocity_limit)
    step = np.abs(np.diff(row["path"], axis=0))
    return bool(np.all(step <= vmax * scenario.period * (1 + 1e-9)))


@pytest.mark.slow
def test_patching_clocks_modules_and_the_robot_in_the_controller_process_changes_no_verdict(tmp_path):
    rows = _bench(tmp_path, ["PatchEverything", "SlowClocks", "BackgroundThread", "CollectorState"])
    scenario = load_scenario(SCENARIO)
    T = scenario.period

    patched = rows["PatchEverything"]
    assert json.loads(patched["info"])["controller"]["patched"] is True  # the attempt ran
    assert _within_velocity_limits(patched, scenario)  # clipped by the simulation all the same
    assert len(patched["path"]) > 2  # in-process, this reached the goal in one 10 ms tick
    if patched["success"]:
        assert patched["time_to_goal"] > T

    slow = rows["SlowClocks"]
    assert json.loads(slow["info"])["controller"]["patched"] is True
    assert slow["tick_time_median"] >= 0.03 * 0.9  # 30 ms of CPU per step, whatever its clocks say
    n_turns = np.isfinite(np.array(json.loads(slow["info"])["compute"], dtype=float)).sum()
    assert slow["deadline_misses"] >= 2 * n_turns - 1  # ceil(30 ms / 10 ms) - 1 per turn

    background = rows["BackgroundThread"]
    info = json.loads(background["info"])
    work = info["controller"].get("background_cpu")
    charged = np.nansum(np.array(info["compute"], dtype=float))
    if work is not None:  # the thread finished within the run: all of its work was charged
        assert charged >= 0.95 * work
    else:  # it did not: the run's calls were charged at least the horizon's worth of CPU
        assert charged >= 0.5 * scenario.horizon or background["deadline_misses"] > 0
    assert charged >= 0.1 and background["deadline_misses"] > 0

    # what set-up made was collected and frozen before the first tick: no full collection of it later
    assert json.loads(rows["CollectorState"]["info"])["controller"]["frozen"] > 10000


@pytest.mark.parametrize(("controller", "warmed"), [("FirstUseCost", True), ("FirstUseCostNoWarmUp", False)])
def test_a_controller_that_never_heard_of_the_warm_up_is_not_charged_its_one_time_costs(controller, warmed):
    """Every controller is warmed up before its run unless it declines (``warm_up = False``): a
    third-party controller's 0.3 s of one-time CPU work per process (compiling, a first plan) is
    then no tick's charge, as it is for the built-in ones. Declined, the first call pays it."""
    from dataclasses import replace

    from planbench.reactive.isolated import run_isolated

    scenario = replace(load_scenario(SCENARIO), horizon=1.0)  # longer than the cost: no call abandoned
    run = run_isolated(
        scenario, f"bench_hostile_controllers:{controller}", settings=RunSettings(check_collisions=False)
    )
    charged = run.record.measured[np.isfinite(run.record.measured)]
    cost = 0.3  # FirstUseCost.COST: CPU time, whatever the machine's load
    if warmed:
        assert charged.max() < 0.5 * cost, charged[:5]
    else:
        assert charged[0] >= 0.9 * cost, charged[:5]


def test_the_info_of_a_run_whose_last_call_was_abandoned_is_still_read():
    """A call that computes past the horizon's end is abandoned (its command can no longer act),
    and its late answer would be read as the next call's: the simulation waits for it, throws it
    away, then asks ``info`` (it was lost before, as in five ``ompl-replan`` runs of `dynamic-test`)."""
    from dataclasses import replace

    from planbench.reactive.isolated import run_isolated

    scenario = replace(load_scenario(SCENARIO), horizon=0.5)  # the step at 0.4 s burns 0.3 s of CPU
    run = run_isolated(
        scenario, "bench_hostile_controllers:PlansPastTheHorizon", settings=RunSettings(check_collisions=False)
    )
    assert run.record.status != "success"
    assert "info_error" not in run.record.info, run.record.info
    assert run.record.info["steps"] == 41, run.record.info  # ticks 0.00-0.40 s, the last one abandoned


@pytest.mark.slow
def test_a_warm_up_that_hangs_is_a_timeout_row_bounded_by_the_setup_timeout(tmp_path):
    """The warm-up runs before the run's clock, so it is bounded as ``setup`` is: a controller whose
    steps never return ends as a ``timeout`` row within ``setup_timeout`` that says where, and the
    benchmark goes on."""
    suite = (
        f'[suite]\nname = "hangs"\nscenarios = ["{_scenario_file(tmp_path, 1.0)}"]\n'
        'timing = "measured"\ntime_limit = 60.0\nsetup_timeout = 5.0\n'
        '[[controllers]]\ncontroller = "bench_hostile_controllers:HangsInItsSteps"\n'
        '[[controllers]]\ncontroller = "bench_hostile_controllers:FirstUseCost"\n'
    )
    db_path = tmp_path / "hangs.db"
    run_benchmark(parse_suite(suite, "hangs.toml"), db_path, jobs=2)
    with ResultsDB(db_path) as db:
        rows = {r["planner"].split(":")[-1]: r for r in db.rows()}
    hung = rows["HangsInItsSteps"]
    assert hung["status"] == "timeout" and not hung["success"], (hung["status"], hung["message"])
    assert "the controller's setup and warm-up" in hung["message"], hung["message"]
    assert rows["FirstUseCost"]["status"] != "error", rows["FirstUseCost"]["message"]


@pytest.mark.slow
def test_the_uncharged_warm_up_shows_nothing_of_the_scenario(tmp_path):
    """The warm-up (two frames, before the run, uncharged) is of a scene of its own: a controller
    that keeps what it saw there learns nothing of the scenario's obstacles."""
    seen = json.loads(_bench(tmp_path, ["PeeksAtWarmUp"])["PeeksAtWarmUp"]["info"])["controller"]["warm_up_frames"]
    scenario_obstacles = {o.name for o in load_scenario(SCENARIO).scene_at(0.0).obstacles}
    assert seen == [["warm-up box"], ["warm-up box"]]
    assert scenario_obstacles and not scenario_obstacles & {"warm-up box"}


@pytest.mark.slow
def test_a_controller_can_start_no_process_nor_reach_into_the_simulation(tmp_path):
    rows = _bench(tmp_path, ["ChildProcess", "ReachesIntoSimulation"])
    tried = json.loads(rows["ChildProcess"]["info"])["controller"]
    assert tried["seccomp"] == "2"
    for how in ("fork", "subprocess", "multiprocessing", "posix_spawn"):
        assert tried[how].startswith("refused"), (how, tried[how])
    reached = json.loads(rows["ReachesIntoSimulation"]["info"])["controller"]
    assert reached, "found none of the benchmark's processes"
    assert all(v.startswith("refused") for v in reached.values()), [v for v in reached.values() if "refused" not in v]


WRONG = ["short", "matrix", "nan", "inf", "text", "none", "object", "complex", "raises_on_read"]


@pytest.mark.slow
def test_every_wrong_kind_of_command_is_an_error_row_that_keeps_the_ticks_run(tmp_path):
    rows = _bench(tmp_path, [f"Wrong_{k}" for k in WRONG])
    for kind in WRONG:
        row = rows[f"Wrong_{kind}"]
        assert row["status"] == "error" and not row["success"], (kind, row["status"], row["message"])
        assert row["failure"].startswith("error:") and "tick 2" in row["message"], (kind, row["message"])
        assert len(row["path"]) == 3, kind  # the two ticks before it: kept


def test_a_record_that_breaks_the_control_model_is_an_invalid_row_naming_rule_and_tick():
    from bench_controllers import ToGoalController

    scenario = load_scenario(SCENARIO)
    honest = evaluate_record(scenario, run_scenario(scenario, ToGoalController(), settings=RunSettings(timing="ideal")))
    assert not honest["failure"].startswith("invalid")
    vmax = np.asarray(scenario.problem.robot.velocity_limit)
    broken = run_scenario(scenario, ToGoalController(), settings=RunSettings(timing="ideal"))
    broken.path = broken.path.copy()
    broken.path[5:] += 0.5 * vmax * scenario.period  # tick 4 moves 1.5 x the limit
    ev = evaluate_record(scenario, broken)
    assert not ev["success"] and ev["failure"].startswith("invalid: control model broken (velocity) at tick 4")
    late = run_scenario(scenario, ToGoalController(), settings=RunSettings(timing="ideal"))
    late.deadline_misses = 0
    late.compute = late.compute.copy()
    late.compute[3] = 0.025  # a 25 ms turn at 100 Hz misses 2 deadlines; the record says none
    ev = evaluate_record(scenario, late)
    assert not ev["success"] and ev["failure"].startswith("invalid: control model broken (schedule)")
    assert math.isnan(ev["min_clearance"])


def test_frames_reach_the_controller_exactly_and_arrays_kept_past_their_slot_are_refused():
    from planbench.reactive.remote import GRID_SLOTS, GridRing, GridView, RemoteFault
    from planbench.reactive.sensing import Sensor

    for name in ("dynamic:panda_swinging_fast_depth/0001", "dynamic:panda_swinging_fast_truth/0001"):
        scenario = load_scenario(name)
        p = scenario.problem
        sensor, rng = Sensor(scenario.sensing, p.robot), np.random.default_rng(0)
        frames = [
            sensor.capture(scenario.scene_at(t), np.array(p.start), t, j, rng) for j, t in enumerate(np.arange(9) / 30)
        ]
        frames[5].grid.data[3, 4, 5] = 0.25  # a value other than 1 reaches the controller too
        ring, view = GridRing(), GridView()
        kept = []
        for j, frame in enumerate(frames):
            obs = view.read(ring.write(frame))
            assert np.array_equal(obs.grid.data, frame.grid.data), (name, j)
            assert (obs.points is None) == (frame.points is None)
            if frame.points is not None:
                assert np.array_equal(obs.points, frame.points)
            assert obs.frame == frame.frame and obs.time == frame.time and not obs.grid.data.flags.writeable
            if frame.scene is not None:
                assert obs.scene.to_dict() == frame.scene.to_dict()
            if j == len(frames) - 1:
                kept.append(obs.grid.data)  # the last frame's grid, kept on
            del obs
        for frame in frames[: GRID_SLOTS - 1]:  # the other slots: the kept grid stays as delivered
            view.read(ring.write(frame))
        assert np.array_equal(kept[0], frames[-1].grid.data) and kept[0].any()
        message = ring.write(frames[0])  # the kept grid's slot, rewritten
        with pytest.raises(RemoteFault, match="copy what you keep longer"):
            view.read(message)
        kept.clear()
        assert np.array_equal(view.read(message).grid.data, frames[0].grid.data)


class _SleepsOnce:
    """Sleeps (computes nothing) through its first step, then answers at once."""

    def __init__(self) -> None:
        self.calls = 0

    def update(self, observation):  # pragma: no cover - not called
        pass

    def step(self, t, q, observation, goal):
        import time

        self.calls += 1
        if self.calls == 1:
            time.sleep(1.0)
        return np.zeros(len(q))

    def info(self):
        return {"calls": self.calls}


def _serve_sleeper(sock) -> None:
    from planbench.reactive.remote import serve_controller

    serve_controller(sock, _SleepsOnce(), 7, None)


def test_after_an_abandoned_call_the_controller_is_asked_nothing_more(monkeypatch):
    """A late answer is never matched with a later call: once a call is abandoned (here: the
    controller computed nothing for IDLE_WAIT), further calls are a fault and ``info`` is not asked."""
    import multiprocessing as mp

    from planbench.reactive import remote

    monkeypatch.setattr(remote, "IDLE_WAIT", 0.2)
    monkeypatch.setattr(remote, "POLL", 0.02)
    ours, theirs = remote.socket_pair()
    proc = mp.get_context("fork").Process(target=_serve_sleeper, args=(theirs,), daemon=True)
    proc.start()
    theirs.close()
    try:
        port = remote.RemoteController(ours, proc.pid, 7)
        with pytest.raises(remote.Overrun, match="computed nothing"):
            port.step(0.0, np.zeros(7), None, None)
        with pytest.raises(remote.RemoteFault, match="asked nothing more"):
            port.step(0.01, np.zeros(7), None, None)  # the first step's answer arrives meanwhile: never read
        assert "not asked: a call was abandoned" in port.info()["info_error"]
    finally:
        proc.kill()
        proc.join(5)
