"""The reactive benchmark's core: scenario files, moving-obstacle certification, the closed loop."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

import planbench
from planbench.errors import ScenarioFileError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.problem import Problem
from planbench.reactive import Controller, Motion, MovingObstacle, Observation, Scenario, SensingSettings
from planbench.reactive.checker import TickChecker
from planbench.reactive.runner import RunSettings, evaluate_run, run_scenario
from planbench.scene import Obstacle, Scene


@pytest.fixture(scope="module")
def free_problem() -> Problem:
    """The Panda of mbm:box/0001 with an empty scene: the goal is reachable in a straight line."""
    p = planbench.load_problems("mbm:box/0001")[0]
    return Problem.create(p.robot, Scene(), p.start, goal_q=p.goal.q, tolerances=p.tolerances, id="free")


def _link_point(problem: Problem, q: np.ndarray, frame: str = "panda_link4") -> np.ndarray:
    return problem.robot.frame_pose(q, frame).translation.copy()


# --- scenario files ----------------------------------------------------------------------------


def test_scenario_round_trips_through_json(tmp_path, free_problem):
    moving = (
        MovingObstacle(
            Obstacle("forearm", "capsule", (0.5, 0.0, 0.5), radius=0.05, length=0.3),
            Motion("swing", pivot=(0.5, 0.0, 0.3), axis=(1.0, 0.0, 0.0), amplitude=0.8, frequency=0.5),
        ),
        MovingObstacle(
            Obstacle("box", "box", (0.4, -0.6, 0.3), size=(0.1, 0.1, 0.1)),
            Motion("waypoints", times=(0.0, 2.0), offsets=((0, 0, 0), (0, 1.2, 0))),
            appear=0.5,
            disappear=4.0,
        ),
        MovingObstacle(
            Obstacle("ball", "sphere", (0.3, 0.3, 0.6), radius=0.05),
            Motion("sinusoid", amplitude=(0, 0, 0.1), frequency=1.0),
        ),
        MovingObstacle(
            Obstacle("slider", "box", (0.6, 0, 0.1), size=(0.1, 0.1, 0.1)),
            Motion("velocity", velocity=(0, 0.2, 0), stop=3.0),
        ),
    )
    s = Scenario(free_problem, moving, SensingSettings("depth", rate=15, latency=0.03), 200.0, 6.0, "mixed")
    path = tmp_path / "s.json"
    s.save(path)
    back = Scenario.load(path)
    assert back.to_dict() == s.to_dict()
    for t in (0.0, 0.7, 1.9, 3.5, 5.0):
        assert back.scene_at(t) == s.scene_at(t)
    assert back.sensing.cameras and back.sensing.latency == 0.03 and back.period == pytest.approx(1 / 200)


def test_scenario_motions_place_obstacles_where_the_formulas_say(free_problem):
    box = MovingObstacle(
        Obstacle("box", "box", (0.4, -0.6, 0.3), size=(0.1, 0.1, 0.1)),
        Motion("waypoints", times=(1.0, 3.0), offsets=((0, 0, 0), (0, 1.0, 0))),
        appear=0.5,
        disappear=4.0,
    )
    s = Scenario(free_problem, (box,))
    assert [o.name for o in s.scene_at(0.4).obstacles] == []  # not there yet
    assert s.scene_at(2.0).obstacles[0].position == pytest.approx((0.4, -0.1, 0.3))  # half way
    assert s.scene_at(3.9).obstacles[0].position == pytest.approx((0.4, 0.4, 0.3))  # held at the last offset
    assert s.scene_at(4.0).obstacles == ()  # gone
    swing = MovingObstacle(
        Obstacle("arm", "capsule", (0.0, 0.0, 1.0), radius=0.05, length=0.2),
        Motion("swing", pivot=(0, 0, 0), axis=(1, 0, 0), amplitude=math.pi / 2, frequency=0.25),
    )
    at_1s = swing.at(1.0)  # angle = pi/2 sin(pi/2): the rest position (0, 0, 1) turned a quarter about x
    assert at_1s.position == pytest.approx((0.0, -1.0, 0.0), abs=1e-12)
    # any point of it moves at most omega * amplitude * (pivot distance + its radius)
    assert swing.speed_bound() == pytest.approx(
        2 * math.pi * 0.25 * math.pi / 2 * (1.0 + np.linalg.norm([0.05, 0.05, 0.15]))
    )


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda d: d.update(format="planbench-scenario/9"), "unsupported scenario format"),
        (lambda d: d.pop("problem"), "missing required key 'problem'"),
        (lambda d: d.update(horizon=-1), "horizon must be > 0"),
        (lambda d: d.update(control_rate="fast"), "could not convert"),
        (lambda d: d.update(extra=1), "unknown keys ['extra']"),
        (lambda d: d["moving_obstacles"][0]["motion"].update(type="teleport"), "moving obstacle #0: motion 'type'"),
        (lambda d: d["moving_obstacles"][0]["motion"].update(times=[1.0, 0.5]), "strictly increasing"),
        (lambda d: d["moving_obstacles"][0].update(disappear=0.0), "disappear must come after appear"),
        (lambda d: d["sensing"].update(model="lidar"), "sensing model must be one of"),
        (lambda d: d["problem"].pop("start"), "problem: missing required key 'start'"),
    ],
)
def test_bad_scenario_files_name_the_field(tmp_path, free_problem, change, words):
    box = MovingObstacle(
        Obstacle("box", "box", (0.4, -0.6, 0.3), size=(0.1, 0.1, 0.1)),
        Motion("waypoints", times=(0.0, 2.0), offsets=((0, 0, 0), (0, 1.0, 0))),
    )
    d = Scenario(free_problem, (box,)).to_dict()
    change(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ScenarioFileError) as info:
        Scenario.load(path)
    assert str(path) in str(info.value) and words in str(info.value)


def test_unreadable_scenario_files_are_named_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ScenarioFileError, match="not valid JSON"):
        Scenario.load(bad)
    with pytest.raises(ScenarioFileError, match="cannot read"):
        Scenario.load(tmp_path / "missing.json")


# --- certified ticks against moving obstacles ----------------------------------------------------


def _crossing(problem: Problem, speed: float, miss: float) -> Scenario:
    """A 2 cm ball that crosses the arm's link 4 along y at ``speed`` [m/s], passing ``miss`` [m]
    beside it along x, centred on the link at t = 0.005 s (the middle of the first 10 ms tick)."""
    p = _link_point(problem, np.asarray(problem.start))
    t_mid = 0.005
    start = p + np.array([miss, -speed * t_mid, 0.0])
    ball = MovingObstacle(
        Obstacle("ball", "sphere", tuple(start), radius=0.02), Motion("velocity", velocity=(0, speed, 0))
    )
    return Scenario(problem, (ball,), control_rate=100.0, horizon=1.0)


def test_an_obstacle_crossing_the_arm_between_ticks_is_a_collision(free_problem):
    s = _crossing(free_problem, speed=40.0, miss=0.0)
    q = np.asarray(free_problem.start)
    checker = TickChecker(s)
    # at both ends of the tick the ball is 20 cm away: a check of the tick's ends sees nothing
    assert checker.clearance(q, 0.0) > 0.03 and checker.clearance(q, 0.01) > 0.03
    verdict = checker.check_tick(q, q, 0.0, 0.01)
    assert not verdict.free and verdict.pair[1] == "obstacle:ball"
    # the contact begins where dense sampling of the exact clearance finds it (to 1/256 of the tick)
    ts = np.linspace(0.0, 0.01, 1025)
    first = ts[np.argmax([checker.clearance(q, t) <= 0 for t in ts])]
    assert 0.0 < first < 0.005
    assert verdict.fraction * 0.01 == pytest.approx(first, abs=0.01 / 256)


def test_an_obstacle_passing_beside_the_arm_is_free_and_its_clearance_is_exact(free_problem):
    q = np.asarray(free_problem.start)
    s = _crossing(free_problem, speed=40.0, miss=0.25)
    checker = TickChecker(s)
    assert checker.check_tick(q, q, 0.0, 0.01).free
    # at the crossing the ball centre is 0.25 m from link 4's origin, so the distance is below 0.23 m
    assert 0.0 < checker.clearance(q, 0.005) < 0.23


# --- the closed loop -----------------------------------------------------------------------------


class TruthStandIn:
    """The truth sensor reduced to what these tests need: the scene voxelised at 4 cm."""

    def capture(self, scene, q, t, frame, rng):
        bounds = (np.full(3, -1.2), np.full(3, 1.2))
        grid = (
            OccupancyGrid.from_scene(scene, 0.04, bounds=bounds) if len(scene) else OccupancyGrid.empty(*bounds, 0.04)
        )
        return Observation(t, grid, frame, None, scene)


class TowardGoal(Controller):
    """Joint-space proportional control toward the goal configuration (no obstacle avoidance)."""

    name = "toward-goal"

    def setup(self, task):
        self.goal_q = np.asarray(task.goal.q)
        self.frames: list[float] = []

    def update(self, observation):
        self.frames.append(observation.time)

    def step(self, t, q, observation, goal):
        return 2.0 * (self.goal_q - q)


class Sleeper(TowardGoal):
    """Sleeps ``delay`` seconds in every step."""

    name = "sleeper"

    def __init__(self, delay: float) -> None:
        super().__init__()
        self.delay = delay

    def step(self, t, q, observation, goal):
        time.sleep(self.delay)
        return super().step(t, q, observation, goal)


def test_a_controller_reaches_the_goal_and_the_evaluation_agrees(free_problem):
    s = Scenario(free_problem, (), SensingSettings(rate=10.0), control_rate=100.0, horizon=8.0)
    c = TowardGoal()
    rec = run_scenario(s, c, sensor=TruthStandIn(), settings=RunSettings(timing="ideal"))
    assert rec.status == "success" and rec.deadline_misses == 0
    m = evaluate_run(s, rec)
    assert m.success and m.failure == "" and m.time_to_goal == pytest.approx(rec.times[-1])
    assert m.path_length > 0 and math.isinf(m.min_clearance)
    # frames at 10 Hz: the controller took in one per 0.1 s, on the tick of capture (no latency)
    assert np.allclose(np.diff(c.frames), 0.1)


def test_a_slow_controller_misses_deadlines_and_holds_its_previous_command(free_problem):
    s = Scenario(free_problem, (), SensingSettings(rate=10.0), control_rate=100.0, horizon=0.5)
    rec = run_scenario(s, Sleeper(0.025), sensor=TruthStandIn())  # 25 ms per step at a 10 ms period
    ran = np.flatnonzero(np.isfinite(rec.compute))
    assert np.all(rec.compute[ran] > 0.02)
    # each step took 3 periods: it starts every 3rd tick and misses 2 deadlines each time
    assert np.all(np.diff(ran) >= 3) and rec.deadline_misses >= 2 * (len(ran) - 1)
    # the first command is applied late: the arm holds still (the zero command) for the ticks missed
    assert np.allclose(rec.commands[: ran[1] - 1], 0.0) and not np.allclose(rec.commands[ran[1] - 1], 0.0)
    m = evaluate_run(s, rec)
    assert m.deadline_misses == rec.deadline_misses and m.tick_time_median > 0.02
    # replaying its compute times reproduces the run exactly, without the sleeps
    again = run_scenario(
        s, TowardGoal(), sensor=TruthStandIn(), settings=RunSettings(timing="replay"), replay=rec.compute
    )
    assert np.array_equal(again.path, rec.path) and again.deadline_misses == rec.deadline_misses


def test_a_moving_obstacle_that_hits_the_arm_ends_the_run_as_a_collision(free_problem):
    s = _crossing(free_problem, speed=2.0, miss=0.0)
    still = type("Still", (TowardGoal,), {"step": lambda self, t, q, o, g: np.zeros_like(q)})()
    rec = run_scenario(s, still, sensor=TruthStandIn(), settings=RunSettings(timing="ideal"))
    assert rec.status == "collision" and rec.collision[1] == "obstacle:ball"
    m = evaluate_run(s, rec)
    assert not m.success and "collision with obstacle:ball" in m.failure


@pytest.mark.parametrize("bad", [lambda q: np.full(len(q), np.nan), lambda q: np.zeros(3), lambda q: 1 / 0])
def test_a_controller_that_raises_or_returns_garbage_ends_its_run_as_an_error(free_problem, bad):
    s = Scenario(free_problem, (), control_rate=100.0, horizon=0.5)
    broken = type("Broken", (TowardGoal,), {"step": lambda self, t, q, o, g: bad(q)})()
    rec = run_scenario(s, broken, sensor=TruthStandIn())
    assert rec.status == "error" and "tick 0" in rec.message
    m = evaluate_run(s, rec)
    assert not m.success and m.failure.startswith("error:")


def test_the_runner_enforces_and_records_velocity_and_joint_limits(free_problem):
    s = Scenario(free_problem, (), control_rate=100.0, horizon=3.0)
    wild = type("Wild", (TowardGoal,), {"step": lambda self, t, q, o, g: np.full_like(q, 100.0)})()
    unchecked = RunSettings(timing="ideal", check_collisions=False)  # the arm folds into itself on the way
    rec = run_scenario(s, wild, sensor=TruthStandIn(), settings=unchecked)
    vmax = np.asarray(free_problem.robot.velocity_limit)
    assert rec.velocity_clipped == len(rec.commands) and np.all(np.abs(rec.commands) <= vmax + 1e-9)
    assert rec.position_clamped > 0 and not free_problem.robot.limit_violations(rec.path[-1])
