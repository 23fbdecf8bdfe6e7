"""The ``mppi`` controller: a sampling model-predictive controller on the observed grid's distance
field (planbench_plugins.controllers.mppi) and its compiled kinematics and distance transform.

Nothing here depends on timing: the closed-loop runs go through the real runner with
``timing="ideal"`` (no compute charged), and their verdicts are :func:`evaluate_run`'s.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin
import pytest
from scipy.ndimage import distance_transform_edt

import planbench
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive import Scenario, SensingSettings
from planbench.reactive.conformance import check_controller
from planbench.reactive.controller import ControlTask, Observation
from planbench.reactive.runner import RunSettings, evaluate_run, run_scenario
from planbench.registry import make_controller
from planbench.robot import load_robot
from planbench.scene import Obstacle, Scene
from planbench_plugins.controllers import _mppi_compiled as compiled
from planbench_plugins.controllers.mppi import ChainModel, MPPIConfig, MPPIController


@pytest.fixture(scope="module")
def table_pick():
    return planbench.load_problems("mbm:table_pick/0001")[0]


def task_of(problem) -> ControlTask:
    return ControlTask(problem.robot, problem.start, problem.goal, problem.tolerances, 0.01, "test")


def closed_loop(problem, controller, horizon: float = 10.0, seed: int = 0):
    """``controller`` on ``problem``'s static scene through the runner (truth sensing at 30 Hz, 100
    Hz control, no compute charged): the run and its independent verdict."""
    scenario = Scenario(problem, (), SensingSettings("truth", rate=30.0), control_rate=100.0, horizon=horizon)
    record = run_scenario(scenario, controller, seed=seed, settings=RunSettings(timing="ideal"))
    return record, evaluate_run(scenario, record)


def with_box(problem, along: float = 0.6, size: float = 0.08):
    """``problem`` with its scene replaced by one box of edge ``size`` [m] on the end effector's
    straight line from the start to the goal, ``along`` of the way."""
    a = problem.robot.frame_pose(problem.start, problem.goal.pose.frame).translation
    centre = a + along * (problem.goal.pose.position - a)
    box = Obstacle("box", "box", position=tuple(centre), size=(size, size, size))
    return dataclasses.replace(problem, scene=Scene((box,), "one-box"))


# --- the parts -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("robot", ["panda", "ur5", "xarm7"])
def test_the_compiled_forward_kinematics_are_pinocchios(robot):
    r = load_robot(robot)
    chain = ChainModel(r.model)
    data = r.model.createData()
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(r.lower, r.upper)
        pin.forwardKinematics(r.model, data, q)
        R, t = chain.forward(q)
        for j in range(1, r.model.njoints):
            assert np.allclose(R[j], data.oMi[j].rotation, atol=1e-12)
            assert np.allclose(t[j], data.oMi[j].translation, atol=1e-12)


def test_the_distance_transform_is_scipys_cut_at_the_cap():
    rng = np.random.default_rng(1)
    occupied = rng.random((30, 41, 52)) < 0.002
    out = np.empty(occupied.shape, dtype=np.float32)
    compiled.distance_block(occupied, 0.02, 0.15, out)
    cells = distance_transform_edt(~occupied)
    expected = np.minimum(np.where(cells > 0, (cells - 0.5) * 0.02, 0.0), 0.15)
    assert np.abs(out - expected).max() < 1e-6
    empty = np.empty((4, 5, 6), dtype=np.float32)
    compiled.distance_block(np.zeros((4, 5, 6), dtype=bool), 0.02, 0.15, empty)
    assert np.all(empty == np.float32(0.15))


def test_it_conforms():
    assert check_controller(MPPIController) == []


@pytest.mark.parametrize(
    "setting",
    [
        {"samples": 2},
        {"samples": 16.0},
        {"horizon_steps": 0},
        {"horizon_dt": 0.0},
        {"noise": -0.1},
        {"noise_smoothing": 1.0},
        {"temperature": 0.0},
        {"speed_scale": 1.5},
        {"obstacle_margin": math.nan},
        {"collision_cost": math.inf},
        {"fade_floor": 2.0},
        {"moving_inflation": True},
        {"unknown": "maybe"},
    ],
)
def test_bad_settings_are_errors_that_name_the_setting(setting):
    key = next(iter(setting))
    with pytest.raises(InvalidConfigError, match=key):
        MPPIConfig(**setting)


def test_the_registry_refuses_a_bad_setting_by_name():
    with pytest.raises(InvalidConfigError, match="temperature"):
        make_controller("mppi", temperature=-1.0)


# --- closed loop -----------------------------------------------------------------------------------------


def test_it_reaches_a_goal_in_free_space_within_its_velocity_and_joint_limits(table_pick):
    free = dataclasses.replace(table_pick, scene=Scene(name="free"))
    controller = make_controller("mppi")
    record, metrics = closed_loop(free, controller)
    assert record.status == "success" and metrics.success, (metrics.failure, controller.info())
    vmax = controller.config.speed_scale * np.asarray(table_pick.robot.velocity_limit)
    assert np.all(np.abs(record.commands) <= vmax + 1e-9)
    assert record.velocity_clipped == 0 and record.position_clamped == 0
    assert not table_pick.robot.limit_violations(record.path[-1])


def test_it_goes_around_a_box_that_a_blind_controller_hits(table_pick):
    problem = with_box(table_pick)
    blind = make_controller("mppi", obstacle_weight=0.0, collision_cost=0.0, moving_inflation=0.0)
    record, metrics = closed_loop(problem, blind)
    assert record.status == "collision" and "obstacle:box" in metrics.failure  # the box is in the way
    controller = make_controller("mppi")
    record, metrics = closed_loop(problem, controller)
    assert record.status == "success" and metrics.success, (metrics.failure, controller.info())
    assert metrics.min_clearance > 0.0


def test_a_joint_at_its_limit_is_never_commanded_past_it(table_pick):
    task = task_of(table_pick)
    controller = MPPIController()
    controller.setup(task)
    robot = table_pick.robot
    for j in range(robot.nq):
        for side, limit in ((1, robot.upper), (-1, robot.lower)):
            q = np.clip(np.array(table_pick.start, dtype=float), robot.lower, robot.upper)
            q[j] = limit[j]
            controller.reset(q, np.random.default_rng(j))
            qd = controller.step(0.0, q, None, task.goal)
            assert side * qd[j] <= 1e-12


def test_the_same_seed_gives_the_same_run_and_another_seed_another(table_pick):
    problem = with_box(table_pick)
    runs = [closed_loop(problem, make_controller("mppi"), horizon=1.0, seed=s)[0] for s in (3, 3, 4)]
    assert np.array_equal(runs[0].path, runs[1].path)
    assert not np.array_equal(runs[0].commands, runs[2].commands)


# --- what the field is made of ---------------------------------------------------------------------------


def observe(grid: OccupancyGrid, t: float, frame: int) -> Observation:
    return Observation(t, grid, frame, np.zeros((0, 3)), None)


def field_at(controller: MPPIController, point) -> float:
    return compiled.field_at(controller.dist, controller.forigin, controller.fres, *point)


def test_unknown_cells_near_the_arm_are_obstacles_only_when_read_as_occupied(table_pick):
    task = task_of(table_pick)
    q = np.array(table_pick.start, dtype=float)
    hand = table_pick.robot.frame_pose(q, task.goal.pose.frame).translation
    grid = OccupancyGrid.empty(np.full(3, -1.2), np.full(3, 1.2), 0.02)
    known = np.ones(grid.shape, dtype=bool)
    idx = grid.index_of(hand[None] + [0.0, 0.0, -0.2])[0]  # a block of unseen cells below the hand
    known[idx[0] - 2 : idx[0] + 3, idx[1] - 2 : idx[1] + 3, idx[2] - 2 : idx[2] + 3] = False
    grid = OccupancyGrid(grid.data, grid.origin, grid.resolution, known=known)
    reads = {}
    for mode in ("free", "occupied"):
        controller = MPPIController(unknown=mode)
        controller.setup(task)
        controller.reset(q, np.random.default_rng(0))
        controller.update(observe(grid, 0.0, 0))
        reads[mode] = controller.dist.size and field_at(controller, hand + [0.0, 0.0, -0.2])
    assert reads["free"] == 0  # no field: nothing occupied
    assert reads["occupied"] == 0.0  # the unseen cells are an obstacle there


def test_cells_seen_free_a_while_then_occupied_are_a_moving_obstacle_grown_by_the_inflation(table_pick):
    task = task_of(table_pick)
    q = np.array(table_pick.start, dtype=float)
    hand = table_pick.robot.frame_pose(q, task.goal.pose.frame).translation
    bounds = (np.full(3, -1.2), np.full(3, 1.2))
    empty = OccupancyGrid.empty(*bounds, 0.02)
    ball = Scene((Obstacle("ball", "sphere", position=tuple(hand + [0.25, 0.0, 0.0]), radius=0.05),), "ball")
    with_ball = OccupancyGrid.from_scene(ball, 0.02, bounds=bounds)
    probe = hand + [0.14, 0.0, 0.0]  # 6 cm from the ball's surface
    histories = {
        "moved in": [empty] * 8 + [with_ball],  # free for 0.23 s, then the ball
        "there all along": [with_ball] * 9,
        "flickered": [with_ball] * 7 + [empty, with_ball],  # seen free one frame only (a noisy surface)
    }
    seen = {}
    for what, frames in histories.items():
        controller = MPPIController(moving_inflation=0.1, moving_free_time=0.2)
        controller.setup(task)
        controller.reset(q, np.random.default_rng(0))
        for k, grid in enumerate(frames):
            controller.update(observe(grid, k / 30.0, k))
        seen[what] = (field_at(controller, probe), controller.info()["moving_cells"])
    assert seen["moved in"][1] > 0 and seen["moved in"][0] == 0.0  # grown over the probe
    for what in ("there all along", "flickered"):
        assert seen[what][1] == 0 and 0.03 < seen[what][0] < 0.09, what  # its own distance
