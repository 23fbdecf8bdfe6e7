"""The control-model check of closed-loop records: honest runs pass, each broken rule is named at its tick."""

from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import planbench
from planbench.geometry.occupancy import OccupancyGrid
from planbench.problem import Problem
from planbench.reactive import Controller, Observation, Scenario, SensingSettings
from planbench.reactive.control_model import (
    RULES,
    ControlModelViolation,
    check_control_model,
    check_record,
    recount_deadline_misses,
)
from planbench.reactive.runner import RunRecord, RunSettings, run_scenario
from planbench.scene import Scene

T = 0.01


@pytest.fixture(scope="module")
def problem() -> Problem:
    """The Panda of mbm:box/0001 in an empty scene."""
    p = planbench.load_problems("mbm:box/0001")[0]
    return Problem.create(p.robot, Scene(), p.start, goal_q=p.goal.q, tolerances=p.tolerances, id="free")


class EmptySensor:
    """Delivers an empty grid: these runs need no obstacles."""

    def capture(self, scene, q, t, frame, rng):
        return Observation(t, OccupancyGrid.empty(np.full(3, -0.2), np.full(3, 0.2), 0.1), frame)


class TowardGoal(Controller):
    """Joint-space proportional control toward the goal configuration."""

    name = "toward-goal"

    def setup(self, task):
        self.goal_q = np.asarray(task.goal.q)

    def step(self, t, q, observation, goal):
        return 2.0 * (self.goal_q - q)


class Wild(TowardGoal):
    """Far past the velocity limits, alternating sign per joint: every tick is clipped, joints reach their limits."""

    name = "wild"

    def step(self, t, q, observation, goal):
        return 100.0 * (-1.0) ** np.arange(len(q))


def _scenario(problem: Problem, horizon: float) -> Scenario:
    return Scenario(problem, (), SensingSettings(rate=10.0), control_rate=1 / T, horizon=horizon, name="cm")


def _check(problem: Problem, rec: RunRecord, horizon: float, **changes) -> ControlModelViolation | None:
    fields = {
        "times": rec.times,
        "path": rec.path,
        "compute": rec.compute,
        "deadline_misses": rec.deadline_misses,
        "period": T,
        "horizon": horizon,
        "start": problem.start,
        **changes,
    }
    return check_control_model(problem.robot, **fields)


@pytest.fixture(scope="module")
def late_run(problem) -> tuple[Scenario, RunRecord]:
    """3 s of clipped and clamped motion, charged compute replayed: 0.025 s (2 misses) on tick 0 and
    every 7th, exactly one period (no miss) every 5th, 1.0000001 periods (1 miss) every 11th."""
    s = _scenario(problem, 3.0)
    replay = np.full(300, 0.002)
    replay[::5] = T
    replay[::11] = T * 1.0000001
    replay[::7] = 0.025
    unchecked = RunSettings(timing="replay", check_collisions=False)
    rec = run_scenario(s, Wild(), sensor=EmptySensor(), settings=unchecked, replay=replay)
    assert rec.status == "timeout" and rec.velocity_clipped > 0 and rec.position_clamped > 0
    assert rec.deadline_misses > 0
    return s, rec


def _turns(rec: RunRecord) -> np.ndarray:
    return np.flatnonzero(np.isfinite(rec.compute))


def _late_turn(rec: RunRecord, missed: int = 2) -> int:
    """The first turn (after tick 0) that misses ``missed`` deadlines."""
    return int(next(k for k in _turns(rec) if k > 0 and math.ceil(rec.compute[k] / T - 1e-9) - 1 == missed))


# --- honest runs pass ----------------------------------------------------------------------------


def test_a_run_to_the_goal_obeys_the_control_model(problem):
    s = _scenario(problem, 8.0)
    rec = run_scenario(s, TowardGoal(), sensor=EmptySensor(), settings=RunSettings(timing="ideal"))
    assert rec.status == "success"
    assert check_record(s, rec) is None


def test_a_clipped_clamped_run_with_late_commands_obeys_the_control_model(problem, late_run):
    s, rec = late_run
    assert check_record(s, rec) is None
    assert recount_deadline_misses(rec.compute, T) == rec.deadline_misses
    # the arm sat exactly on a joint limit, and moved exactly vmax T on clipped ticks
    assert np.any(rec.path == problem.robot.upper) or np.any(rec.path == problem.robot.lower)
    assert np.any(np.abs(np.diff(rec.path, axis=0)) == problem.robot.velocity_limit * T)


def test_a_measured_run_with_a_slow_controller_obeys_the_control_model(problem):
    slow = type("Slow", (TowardGoal,), {"step": lambda self, t, q, o, g: _busy(0.012) + 2.0 * (self.goal_q - q)})()
    s = _scenario(problem, 0.3)
    rec = run_scenario(s, slow, sensor=EmptySensor())
    assert rec.deadline_misses > 0 and check_record(s, rec) is None


def _busy(seconds: float) -> float:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass
    return 0.0


def test_a_run_that_ends_while_a_command_is_late_obeys_the_control_model(problem):
    s = _scenario(problem, 0.5)
    replay = np.zeros(50)
    replay[45] = 0.2  # 19 deadlines, 15 of them after the run's last tick
    rec = run_scenario(s, TowardGoal(), sensor=EmptySensor(), settings=RunSettings(timing="replay"), replay=replay)
    assert rec.deadline_misses == 19 and np.isnan(rec.compute[46:]).all()
    assert check_record(s, rec) is None


def test_a_run_ended_by_a_controller_error_obeys_the_control_model(problem):
    class Breaks(TowardGoal):
        def step(self, t, q, observation, goal):
            if t > 0.025:
                raise RuntimeError("broken")
            return super().step(t, q, observation, goal)

    s = _scenario(problem, 0.5)
    rec = run_scenario(s, Breaks(), sensor=EmptySensor())
    assert rec.status == "error" and len(rec.path) == 4 and len(rec.compute) == 3
    assert check_record(s, rec) is None


def test_a_record_sent_as_json_still_obeys_the_control_model(problem, late_run):
    """The benchmark sends the record as JSON, non-finite compute as null: the float64s survive."""
    s, rec = late_run
    wire = json.loads(
        json.dumps(
            {
                "times": rec.times.tolist(),
                "path": rec.path.tolist(),
                "compute": [v if math.isfinite(v) else None for v in rec.compute.tolist()],
            }
        )
    )
    back = dataclasses.replace(
        rec,
        times=np.asarray(wire["times"], dtype=float),
        path=np.asarray(wire["path"], dtype=float),
        compute=np.asarray(wire["compute"], dtype=float),
    )
    assert check_record(s, back) is None


@pytest.mark.parametrize(
    "clock, exact",
    [
        (lambda n: np.linspace(0.0, n * T, n + 1), True),
        (lambda n: np.concatenate([[0.0], np.cumsum(np.full(n, T))]), False),
        (lambda n: np.array([k / (1 / T) for k in range(n + 1)]), False),
    ],
    ids=["linspace", "running-sum", "divided-by-rate"],
)
def test_honest_ways_of_computing_the_clock_pass(problem, late_run, clock, exact):
    _, rec = late_run
    times = clock(len(rec.times) - 1)
    assert np.array_equal(times, rec.times) == exact
    assert _check(problem, rec, 3.0, times=times) is None


# --- each broken rule is named at its first tick ------------------------------------------------


def test_a_time_off_by_a_microsecond_breaks_times(problem, late_run):
    _, rec = late_run
    times = rec.times.copy()
    times[40] += 1e-6
    v = _check(problem, rec, 3.0, times=times)
    assert (v.rule, v.tick) == ("times", 40) and "times[40] = 0.400001 s" in v.detail


def test_a_skipped_tick_breaks_times(problem, late_run):
    _, rec = late_run
    keep = np.arange(len(rec.times)) != 12
    v = _check(problem, rec, 3.0, times=rec.times[keep], path=rec.path[keep], compute=rec.compute[1:])
    assert (v.rule, v.tick) == ("times", 12)


@pytest.mark.parametrize("bad, tick", [(np.nan, 7), (np.inf, 7)])
def test_a_time_that_is_not_a_number_breaks_times(problem, late_run, bad, tick):
    _, rec = late_run
    times = rec.times.copy()
    times[7] = bad
    v = _check(problem, rec, 3.0, times=times)
    assert (v.rule, v.tick) == ("times", tick) and "finite" in v.detail


def test_one_time_too_few_breaks_times(problem, late_run):
    _, rec = late_run
    v = _check(problem, rec, 3.0, times=rec.times[:-1])
    assert (v.rule, v.tick) == ("times", len(rec.times) - 1)


def test_a_start_moved_by_a_picoradian_breaks_start(problem, late_run):
    _, rec = late_run
    path = rec.path.copy()
    path[0, 3] += 1e-12
    v = _check(problem, rec, 3.0, path=path)
    assert (v.rule, v.tick) == ("start", 0) and "panda_joint4" in v.detail


def test_a_start_one_float_away_breaks_start(problem, late_run):
    _, rec = late_run
    path = rec.path.copy()
    path[0, 0] = np.nextafter(path[0, 0], np.inf)
    v = _check(problem, rec, 3.0, path=path)
    assert (v.rule, v.tick) == ("start", 0)


def test_a_path_for_another_robot_breaks_start(problem, late_run):
    _, rec = late_run
    v = _check(problem, rec, 3.0, path=rec.path[:, :6])
    assert (v.rule, v.tick) == ("start", 0) and "7" in v.detail


def _simulated(problem: Problem, commands: np.ndarray) -> np.ndarray:
    """The states the runner's motion step gives for ``commands`` (n, nq): clip, integrate, clamp."""
    robot = problem.robot
    vmax = np.asarray(robot.velocity_limit)
    q = np.array(problem.start, dtype=float)
    path = [q]
    for qd in commands:
        q = np.clip(q + T * np.clip(qd, -vmax, vmax), robot.lower, robot.upper)
        path.append(q)
    return np.array(path)


def _hand_made(problem: Problem, path: np.ndarray, **changes) -> ControlModelViolation | None:
    n = len(path) - 1
    fields = {"times": np.arange(n + 1) * T, "compute": np.zeros(n), "deadline_misses": 0, "path": path, **changes}
    return check_control_model(problem.robot, problem.start, T, 10.0, **fields)


def test_a_tick_at_1_0000001_times_the_velocity_limit_breaks_velocity(problem):
    vmax = np.asarray(problem.robot.velocity_limit)
    direction = np.where(np.asarray(problem.start) > 0.5 * (problem.robot.lower + problem.robot.upper), -1.0, 1.0)
    path = _simulated(problem, np.tile(direction * vmax * 0.5, (20, 1)))
    assert _hand_made(problem, path) is None
    excess = vmax[2] * T * 1.0000001 - abs(path[13, 2] - path[12, 2])
    path[13:, 2] += direction[2] * excess
    v = _hand_made(problem, path)
    assert (v.rule, v.tick) == ("velocity", 12)
    assert "joint panda_joint3 moved" in v.detail and "1.0000001 x the limit" in v.detail
    assert str(v).startswith("control model broken (velocity) at tick 12: joint panda_joint3")


def test_a_non_finite_state_breaks_velocity(problem, late_run):
    _, rec = late_run
    path = rec.path.copy()
    path[9, 1] = np.nan
    v = _check(problem, rec, 3.0, path=path)
    assert (v.rule, v.tick) == ("velocity", 8) and "finite" in v.detail


def test_a_joint_one_float_past_its_limit_breaks_joint_limits(problem, late_run):
    _, rec = late_run
    at_upper = np.argwhere(rec.path == problem.robot.upper)
    k, j = (int(i) for i in at_upper[len(at_upper) // 2])
    path = rec.path.copy()
    path[k, j] = np.nextafter(path[k, j], np.inf)
    v = _check(problem, rec, 3.0, path=path)
    assert (v.rule, v.tick) == ("joint_limits", k) and problem.robot.joint_names[j] in v.detail


def test_a_start_just_outside_its_limits_is_the_problems_tolerance(problem):
    robot = problem.robot
    start = np.array(problem.start, dtype=float)
    start[0] = robot.upper[0] + 5e-10
    path = np.tile(start, (3, 1))
    path[1:, 0] = robot.upper[0]
    assert check_control_model(robot, start, T, 10.0, np.arange(3) * T, path, np.zeros(2), 0) is None
    path[2, 0] = start[0]
    v = check_control_model(robot, start, T, 10.0, np.arange(3) * T, path, np.zeros(2), 0)
    assert (v.rule, v.tick) == ("joint_limits", 2)


def test_a_run_past_the_horizon_breaks_horizon(problem, late_run):
    _, rec = late_run
    v = _check(problem, rec, 2.5)
    assert (v.rule, v.tick) == ("horizon", 251)


def test_deadline_misses_under_reported_by_one_break_deadline_misses(problem, late_run):
    _, rec = late_run
    last_late = int(max(k for k in _turns(rec) if math.ceil(rec.compute[k] / T - 1e-9) > 1))
    v = _check(problem, rec, 3.0, deadline_misses=rec.deadline_misses - 1)
    assert (v.rule, v.tick) == ("deadline_misses", last_late)
    assert f"{rec.deadline_misses - 1} deadline misses reported" in v.detail


def test_deadline_misses_over_reported_break_deadline_misses_at_the_end(problem, late_run):
    _, rec = late_run
    v = _check(problem, rec, 3.0, deadline_misses=rec.deadline_misses + 1)
    assert (v.rule, v.tick) == ("deadline_misses", len(rec.compute))


def test_a_turn_started_while_the_controller_is_busy_breaks_schedule(problem, late_run):
    _, rec = late_run
    k = _late_turn(rec)
    compute = rec.compute.copy()
    compute[k + 2] = 0.001
    v = _check(problem, rec, 3.0, compute=compute)
    assert (v.rule, v.tick) == ("schedule", k + 2) and f"busy until tick {k + 3}" in v.detail


def test_a_turn_missing_where_the_controller_was_free_breaks_schedule(problem, late_run):
    _, rec = late_run
    k = _late_turn(rec)
    compute = rec.compute.copy()
    compute[k + 3] = np.nan
    v = _check(problem, rec, 3.0, compute=compute)
    assert (v.rule, v.tick) == ("schedule", k + 3)


def test_a_charge_of_exactly_one_period_misses_nothing_and_a_hair_more_misses_one(problem, late_run):
    _, rec = late_run
    k = int(next(k for k in _turns(rec) if rec.compute[k] == T))
    assert np.isfinite(rec.compute[k + 1])
    k = int(next(k for k in _turns(rec) if rec.compute[k] == T * 1.0000001))
    assert np.isnan(rec.compute[k + 1]) and np.isfinite(rec.compute[k + 2])


@pytest.mark.parametrize("charge", [-1e-6, np.inf, -np.inf])
def test_a_negative_or_infinite_charge_breaks_schedule(problem, late_run, charge):
    _, rec = late_run
    k = int(_turns(rec)[4])
    compute = rec.compute.copy()
    compute[k] = charge
    v = _check(problem, rec, 3.0, compute=compute)
    assert (v.rule, v.tick) == ("schedule", k) and "finite and >= 0" in v.detail
    with pytest.raises(ValueError):
        recount_deadline_misses(compute, T)


def test_one_compute_entry_too_few_breaks_schedule(problem, late_run):
    _, rec = late_run
    v = _check(problem, rec, 3.0, compute=rec.compute[:-1])
    assert (v.rule, v.tick) == ("schedule", len(rec.compute) - 1)


def test_the_first_rule_in_order_is_reported(problem, late_run):
    _, rec = late_run
    times, path = rec.times.copy(), rec.path.copy()
    times[50] += 1e-6
    path[0, 0] += 1e-6
    assert _check(problem, rec, 3.0, path=path, deadline_misses=0).rule == "start"
    assert _check(problem, rec, 3.0, times=times, path=path, deadline_misses=0).rule == "times"
    assert _check(problem, rec, 2.0, deadline_misses=0).rule == "horizon"
    assert RULES.index("schedule") < RULES.index("deadline_misses")


def test_a_violation_names_a_known_rule():
    with pytest.raises(ValueError, match="rule must be one of"):
        ControlModelViolation("speed", 0, "")


# --- properties: the tolerances never refuse an honest run ---------------------------------------


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rate=st.sampled_from([10.0, 30.0, 100.0, 250.0, 333.0, 1000.0, 3000.0]) | st.floats(1.0, 10000.0),
    where=st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7),
    speed=st.lists(st.sampled_from([-1.0, 1.0, -3.0, 3.0, 0.0]) | st.floats(-3.0, 3.0), min_size=7, max_size=7),
)
def test_the_velocity_rule_accepts_motion_at_the_limit_as_the_simulation_computes_it(problem, rate, where, speed):
    robot = problem.robot
    period = 1.0 / rate
    lower, upper, vmax = (np.asarray(a, dtype=float) for a in (robot.lower, robot.upper, robot.velocity_limit))
    q = lower + np.asarray(where) * (upper - lower)
    qd = np.asarray(speed) * vmax
    q1 = np.clip(q + period * np.clip(qd, -vmax, vmax), lower, upper)
    v = check_control_model(robot, q, period, 1.0, [0.0, period], np.array([q, q1]), [0.0], 0)
    assert v is None, str(v)
    over = np.clip(q + period * vmax * 1.0000001, lower, upper)
    moved = over - q >= period * vmax * (1 + 1e-8)
    if moved.any():
        v = check_control_model(robot, q, period, 1.0, [0.0, period], np.array([q, over]), [0.0], 0)
        assert v is not None and v.rule == "velocity"


@settings(max_examples=200, deadline=None)
@given(
    rate=st.sampled_from([30.0, 100.0, 1000.0]) | st.floats(1.0, 5000.0),
    charges=st.lists(
        st.tuples(st.integers(0, 5), st.sampled_from([1.0, 1.0 - 1e-12, 1.0 + 1e-12, 0.5, 1.0000001])),
        min_size=1,
        max_size=40,
    ),
    n=st.integers(1, 120),
)
def test_any_schedule_the_runner_makes_passes_and_recounts_its_misses(problem, rate, charges, n):
    """The runner's own rule, charges at and around whole periods included (m T misses m - 1)."""
    period = 1.0 / rate
    compute = np.full(n, np.nan)
    k, misses, i = 0, 0, 0
    while k < n:
        m, f = charges[i % len(charges)]
        c = m * period * f
        compute[k] = c
        missed = max(0, math.ceil(c / period - 1e-9) - 1)
        misses += missed
        k += missed + 1
        i += 1
    path = np.tile(np.asarray(problem.start, dtype=float), (n + 1, 1))
    v = check_control_model(
        problem.robot, problem.start, period, n * period, np.arange(n + 1) * period, path, compute, misses
    )
    assert v is None, str(v)
    assert recount_deadline_misses(compute, period) == misses
