"""What the controller had observed: ``unobserved_motion`` and collisions with obstacles no
observation had shown, decided by the simulation from the observations it delivered."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from bench_controllers import ToGoalController

from conftest import box
from planbench.bench.report import failure_reason, failure_text
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.body import ArmBody
from planbench.reactive.controller import Observation
from planbench.reactive.runner import RunSettings, evaluate_run, run_scenario
from planbench.reactive.scenario import MovingObstacle, Scenario, SensingSettings
from planbench.scene import Scene

RES = 0.04
BOUNDS = (np.full(3, -1.2), np.full(3, 1.2))
IDEAL = RunSettings(timing="ideal")


class MaskedSensor:
    """Empty grids whose ``known`` mask is given (None: every cell known), one per frame."""

    def __init__(self, known):
        self.known = known

    def capture(self, scene, q, t, frame, rng):
        grid = OccupancyGrid.empty(*BOUNDS, RES)
        known = None if self.known is None else self.known.copy()
        return Observation(t, OccupancyGrid(grid.data, grid.origin, RES, known=known), frame, None, None)


class Still(ToGoalController):
    def step(self, t, q, observation, goal):
        return np.zeros_like(q)


def scenario(problem, *moving, rate=30.0, horizon=3.0):
    return Scenario(problem, tuple(moving), SensingSettings(rate=rate), horizon=horizon)


def test_moving_through_known_space_is_not_counted(free_problem):
    rec = run_scenario(scenario(free_problem), ToGoalController(), sensor=MaskedSensor(None), settings=IDEAL)
    m = evaluate_run(scenario(free_problem), rec)
    assert m.success and m.unobserved_motion == 0.0


def test_standing_still_in_unknown_space_is_not_counted(free_problem):
    nothing = np.zeros(OccupancyGrid.empty(*BOUNDS, RES).shape, dtype=bool)
    rec = run_scenario(scenario(free_problem), Still(), sensor=MaskedSensor(nothing), settings=IDEAL)
    assert evaluate_run(scenario(free_problem), rec).unobserved_motion == 0.0


def test_unobserved_motion_is_the_time_the_moving_arm_fills_unknown_cells(free_problem):
    s = scenario(free_problem)
    shape = OccupancyGrid.empty(*BOUNDS, RES).shape
    known = np.ones(shape, dtype=bool)
    hand = free_problem.robot.frame_pose(free_problem.goal.q).translation
    i = np.floor((hand - BOUNDS[0]) / RES).astype(int)
    known[i[0] - 1 : i[0] + 2, i[1] - 1 : i[1] + 2, i[2] - 1 : i[2] + 2] = False  # a blind spot at the goal
    rec = run_scenario(s, ToGoalController(), sensor=MaskedSensor(known), settings=IDEAL)
    m = evaluate_run(s, rec)
    # recount from the trajectory: the ticks whose end fills a blind cell (the arm moves on every tick)
    body = ArmBody(free_problem.robot, BOUNDS[0], shape, RES)
    expected = sum(s.period for q in rec.path[1:] if body.in_unknown(q, known))
    assert m.success and 0 < m.unobserved_motion == pytest.approx(expected)
    assert m.unobserved_motion < rec.times[-1]


def test_before_the_first_delivery_every_cell_is_unknown(free_problem):
    s = Scenario(free_problem, (), SensingSettings(rate=30.0, latency=0.2), horizon=3.0)
    rec = run_scenario(s, ToGoalController(), sensor=MaskedSensor(None), settings=IDEAL)
    assert evaluate_run(s, rec).unobserved_motion == pytest.approx(0.2)  # 20 ticks, the arm moving


def on_the_way(problem, appear=0.0):
    """A ball where the arm's hand passes halfway to the goal, present from ``appear`` [s]."""
    mid = problem.robot.frame_pose(0.5 * (np.asarray(problem.start) + problem.goal.q)).translation
    return MovingObstacle(box("ball", mid, (0.08, 0.08, 0.08)), appear=appear)


def test_a_collision_with_an_obstacle_no_observation_showed_is_told_apart(free_problem):
    # truth sensing at 1 Hz: the frame at t = 0 holds no ball, the next comes after the collision
    s = scenario(free_problem, on_the_way(free_problem, appear=0.05), rate=1.0)
    rec = run_scenario(s, ToGoalController(), settings=IDEAL)
    m = evaluate_run(s, rec)
    assert rec.status == "collision" and m.collision_observed is False
    assert m.failure.endswith("never observed") and "ball" not in rec.first_seen

    seen = scenario(free_problem, on_the_way(free_problem), rate=1.0)  # there from the first frame
    rec = run_scenario(seen, ToGoalController(), settings=IDEAL)
    m = evaluate_run(seen, rec)
    assert rec.status == "collision" and m.collision_observed is True and rec.first_seen["ball"] == 0.0
    assert "never observed" not in m.failure


class PartSensor:
    """Frames that show the scene's cells inside the box ``lo``-``hi`` only: those occupied and
    known, the rest unknown; with ``all_known``, every cell known (the rest free)."""

    def __init__(self, lo, hi, all_known=False):
        self.lo, self.hi, self.all_known = np.asarray(lo), np.asarray(hi), all_known

    def capture(self, scene, q, t, frame, rng):
        full = OccupancyGrid.from_scene(scene, RES, bounds=BOUNDS)
        centres = full.origin + (np.indices(full.shape).reshape(3, -1).T + 0.5) * RES
        inside = np.all((centres >= self.lo) & (centres <= self.hi), axis=1).reshape(full.shape)
        known = np.ones(full.shape, dtype=bool) if self.all_known else inside
        return Observation(t, OccupancyGrid(np.where(inside, full.data, 0.0), full.origin, RES, known=known), frame)


def test_a_collision_where_no_frame_showed_the_obstacle_is_told_apart(free_problem):
    """A long board across the hand's way, shown by its far end only: the obstacle counts as
    observed, but the arm hits it where the frames knew nothing, so the collision is "in
    unobserved space". With every cell known (the hit part seen free or occupied), it is not."""
    robot = free_problem.robot
    a = robot.frame_pose(free_problem.start).translation
    b = robot.frame_pose(free_problem.goal.q).translation
    mid = 0.5 * (a + b)
    axis = int(np.argmin(np.abs(b - a)))  # the board's length runs across the hand's way
    size = np.full(3, 0.08)
    size[axis] = 0.8
    problem = dataclasses.replace(free_problem, scene=Scene((box("board", mid, size),)))
    s = scenario(problem)
    far = mid.copy()
    far[axis] += 0.35
    end = (far - 0.06, far + 0.06)  # the board's far end: shown
    rec = run_scenario(s, ToGoalController(), sensor=PartSensor(*end), settings=IDEAL)
    m = evaluate_run(s, rec)
    assert rec.status == "collision" and m.collision_observed is True and "board" in rec.first_seen
    assert rec.contact_unobserved is True and m.failure.endswith(", in unobserved space"), m.failure
    row = {"success": False, "status": "collision", "collision_pair": f"{rec.collision[0]} / obstacle:board"}
    assert failure_reason({**row, "collision_observed": True, "failure": m.failure}).startswith("unobserved-collision")
    rec = run_scenario(s, ToGoalController(), sensor=PartSensor(*end, all_known=True), settings=IDEAL)
    m = evaluate_run(s, rec)
    assert rec.status == "collision" and rec.contact_unobserved is False
    assert not m.failure.endswith("space") and "never observed" not in m.failure


def test_depth_shows_an_obstacle_by_its_occupied_cells(panda):
    from planbench.problem import Problem
    from planbench.reactive.exposure import Exposure
    from planbench.reactive.scenario import CameraSettings
    from planbench.reactive.sensing import Sensor

    wall = box("wall", (1.1, 0.0, 0.4), (0.2, 0.3, 0.3))
    hidden = box("hidden", (1.6, 0.0, 0.4), (0.1, 0.1, 0.1))  # in the wall's shadow
    problem = Problem.create(panda, Scene((wall, hidden)), panda.home, panda.home + 0.1)
    camera = CameraSettings(position=(0.8, 0.0, 0.4), look_at=(2.0, 0.0, 0.4))
    s = Scenario(problem, (), SensingSettings(model="depth", cameras=(camera,)))
    exposure = Exposure(s)
    exposure.delivered(Sensor(s.sensing, panda).capture(problem.scene, panda.home, 0.0, 0, None), 0.03)
    assert exposure.first_seen == {"wall": 0.03}


def test_reports_count_unseen_collisions_apart():
    rows = [
        {
            "success": False,
            "status": "collision",
            "collision_pair": "panda_hand / obstacle:ball",
            "collision_observed": 0,
        },
        {
            "success": False,
            "status": "collision",
            "collision_pair": "panda_hand / obstacle:ball",
            "collision_observed": 1,
        },
        {"success": False, "status": "collision", "collision_pair": "panda_hand / obstacle:ball"},
    ]
    assert [failure_reason(r) for r in rows] == ["unseen-collision panda_hand"] + ["collision panda_hand"] * 2
    assert failure_text(rows) == "collision 2 (panda_hand 2), unseen-collision 1 (panda_hand 1)"


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_the_cells_of_the_arm_are_those_it_marks(free_problem, backend):
    """``ArmBody.cells`` lists the cells ``mark`` sets, without a grid-sized array, in either backend."""
    from planbench.runtime.backend import prefer

    shape = tuple(int(n) for n in np.round((BOUNDS[1] - BOUNDS[0]) / RES))
    prefer(backend)
    try:
        body = ArmBody(free_problem.robot, BOUNDS[0], shape, RES)
    finally:
        prefer(None)
    rng = np.random.default_rng(0)
    for q in rng.uniform(free_problem.robot.lower, free_problem.robot.upper, size=(10, free_problem.robot.nq)):
        marked = np.zeros(shape, dtype=bool)
        body.mark(marked, q)
        assert np.array_equal(body.cells(q), np.flatnonzero(marked))


def test_the_cells_of_points_are_each_found_once_and_sorted():
    """PartPoints.cells' unique-by-sort gives np.unique's answer (duplicates, unsorted input,
    one point, none)."""
    from planbench.geometry.part_cells import _sorted_unique

    rng = np.random.default_rng(0)
    for values in (rng.integers(0, 50, size=400), rng.integers(0, 10**6, size=30), np.array([7]), np.zeros(0, int)):
        assert np.array_equal(_sorted_unique(values), np.unique(values))
