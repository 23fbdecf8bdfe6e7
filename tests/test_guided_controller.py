"""The ``matrix-field-guided`` controller: RRT-Connect planned a slice of collision checks per tick,
tracked with the matrix field; and the sliced query it plans with.

Nothing here depends on timing: slices end by check counts, runs use ``timing="ideal"`` or drive
the controller tick by tick as the runner does, without charging compute.
"""

from __future__ import annotations

import dataclasses
import gc
import math
import threading
import time

import numpy as np
import pytest

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.metrics import densify
from planbench.problem import Problem
from planbench.reactive import Scenario, SensingSettings
from planbench.reactive.body import ArmBody
from planbench.reactive.conformance import check_controller
from planbench.reactive.controller import ControlTask, Observation
from planbench.reactive.runner import RunSettings, evaluate_run, run_scenario
from planbench.scene import Obstacle, Scene
from planbench_plugins.controllers.matrix_field_guided import (
    MatrixFieldGuidedController,
    MatrixFieldGuidedControllerConfig,
)
from planbench_plugins.ompl_planners import SlicedRRTConnect
from planbench_plugins.ompl_planners.motion import SegmentChecker

BOUNDS = (np.full(3, -1.2), np.full(3, 1.2))


@pytest.fixture(scope="module")
def task() -> ControlTask:
    p = planbench.load_problems("mbm:table_pick/0001")[0]
    return ControlTask(p.robot, p.start, p.goal, p.tolerances, 0.01, "free")


@pytest.fixture(scope="module")
def bookshelf() -> Problem:
    return planbench.load_problems("mbm:bookshelf_tall/0001")[0]


def truth(scene: Scene, t: float = 0.0, frame: int = 0) -> Observation:
    """A truth observation of ``scene`` (its grid at 4 cm; the controller plans on the scene)."""
    grid = OccupancyGrid.from_scene(scene, 0.04, bounds=BOUNDS) if len(scene) else OccupancyGrid.empty(*BOUNDS, 0.04)
    return Observation(t, grid, frame, None, scene)


def depth(scene: Scene, t: float = 0.0, frame: int = 0, known: np.ndarray | None = None) -> Observation:
    """A depth-like observation: ``scene``'s cells at 2 cm, no scene (the controller plans on cells)."""
    grid = OccupancyGrid.from_scene(scene, 0.02, bounds=BOUNDS) if len(scene) else OccupancyGrid.empty(*BOUNDS, 0.02)
    if known is not None:
        grid = OccupancyGrid(grid.data, grid.origin, grid.resolution, known=known)
    return Observation(t, grid, frame, np.zeros((0, 3)), None)


class Driver:
    """A controller driven as the runner drives it, no compute charged: a frame every third tick,
    the command clipped to the velocity limits and integrated."""

    def __init__(self, task: ControlTask, **settings) -> None:
        self.task = task
        self.c = MatrixFieldGuidedController(**settings)
        self.c.setup(task)
        self.q = np.array(task.start, dtype=float)
        self.c.reset(self.q.copy(), np.random.default_rng(0))
        self.k = 0
        self.commands: list[np.ndarray] = []

    def run(self, observation: Observation, ticks: int, until=None) -> None:
        robot, T = self.task.robot, self.task.period
        vmax = np.asarray(robot.velocity_limit)
        for _ in range(ticks):
            if self.k % 3 == 0:
                self.c.update(dataclasses.replace(observation, time=self.k * T, frame=self.k // 3))
            qd = self.c.step(self.k * T, self.q.copy(), None, self.task.goal)
            self.commands.append(qd)
            self.q = np.clip(self.q + T * np.clip(qd, -vmax, vmax), robot.lower, robot.upper)
            self.k += 1
            if until is not None and until(self):
                return


def free_along(checker: CollisionChecker, path: np.ndarray, resolution: float = 0.01) -> bool:
    """Whether ``path`` is free at the planner's check points (every ``resolution`` rad)."""
    return not any(checker.in_collision(x) for x in densify(np.asarray(path), resolution)[0])


# --- the sliced query ----------------------------------------------------------------------------------


def test_a_sliced_query_keeps_its_trees_across_slices(bookshelf):
    """RRT-Connect keeps its trees across solve() calls: unbounded slices of 50 checks make the
    checks and path one unlimited solve makes."""
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    whole = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, shorten=False)
    assert whole.advance(10**9) and whole.slices == 1
    sliced = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, shorten=False, overrun_motions=None)
    while not sliced.advance(50):
        pass
    assert sliced.slices > 20 and sliced.checks == whole.checks
    assert sliced.path is not None and whole.path is not None
    assert np.array_equal(sliced.path, whole.path)


def test_a_bounded_slice_ends_within_one_motion_of_its_checks_and_repeats_exactly(bookshelf):
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    runs = []
    for _ in range(2):
        query = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, shorten=False)
        per_slice = []
        while True:
            before = query.checks
            done = query.advance(50)
            per_slice.append(query.checks - before)
            if done:
                break
        assert max(per_slice) <= 50 + query.max_overshoot and query.slices > 20
        assert query.path is not None and free_along(checker, query.path)
        runs.append((per_slice, query.path))
    assert runs[0][0] == runs[1][0] and np.array_equal(runs[0][1], runs[1][1])


def test_a_sliced_query_shortens_its_path_in_slices_and_keeps_it_free(bookshelf):
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    raw = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, shorten=False)
    raw.advance(10**9)
    short = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3)
    while not short.advance(50):
        pass
    assert raw.path is not None and short.path is not None
    assert len(short.path) < len(raw.path)
    assert np.array_equal(short.path[0], bookshelf.start) and np.array_equal(short.path[-1], bookshelf.goal.q)
    segments = SegmentChecker(checker, 0.01)
    assert all(segments.motion_free(a, b) for a, b in zip(short.path[:-1], short.path[1:], strict=True))


def test_a_query_from_or_to_a_configuration_in_collision_is_refused_at_once(bookshelf):
    """OMPL would wait for another goal sample until the slice ends, and no check would end it."""
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    rng = np.random.default_rng(0)
    samples = rng.uniform(bookshelf.robot.lower, bookshelf.robot.upper, (500, 7))
    inside = next(q for q in samples if checker.in_collision(q))
    with pytest.raises(ValueError, match="goal"):
        SlicedRRTConnect(checker, bookshelf.start, inside, seed=0)
    with pytest.raises(ValueError, match="start"):
        SlicedRRTConnect(checker, inside, bookshelf.goal.q, seed=0)


# --- settings ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "setting",
    [
        {"plan_checks_per_tick": 0},
        {"plan_check_budget": 2.5},
        {"octree_cells": True},
        {"plan_range": -0.5},
        {"check_resolution": 0.0},
        {"replan_lag": math.inf},
        {"velocity_scale": 1.5},
        {"goal_fade": -1.0},
        {"shorten": "yes"},
        {"unknown": "maybe"},
        {"field_mode": "sometimes"},
        {"standoff": 0.5},
        {"slice_cpu_share": 1.0},
    ],
)
def test_bad_settings_are_errors_that_name_the_setting(setting):
    key = next(iter(setting))
    with pytest.raises(InvalidConfigError, match=key if key != "standoff" else "standoff"):
        MatrixFieldGuidedControllerConfig(**setting)


def test_a_gain_too_high_for_the_control_period_is_refused_at_setup(task):
    c = MatrixFieldGuidedController(tracking_gain=200.0)
    with pytest.raises(InvalidConfigError, match="tracking_gain"):
        c.setup(task)


def test_it_conforms():
    # slices ended by count: by default they also end by CPU time, so a second run may part from the first
    assert check_controller(MatrixFieldGuidedController, {"slice_cpu_share": 0.0}) == []


# --- planning a slice per tick ------------------------------------------------------------------------


def test_planning_is_spread_over_ticks_with_at_most_one_slice_each(task, monkeypatch):
    """A board between start and goal: the plan takes several ticks; every tick runs at most one
    slice, of at most ``plan_checks_per_tick`` checks plus two motions (and the few checks of a
    slice that prepares the query); the arm holds still meanwhile."""
    hand = task.robot.frame_pose(0.5 * (np.asarray(task.start) + np.asarray(task.goal.q)), task.goal.pose.frame)
    board = Scene((Obstacle("board", "box", tuple(hand.translation), size=(0.3, 0.3, 0.02)),))
    counted = {"n": 0}
    in_collision = CollisionChecker.in_collision

    def count_state(self, q):  # states and, configuration by configuration, motions (no batch pool)
        counted["n"] += 1
        return in_collision(self, q)

    monkeypatch.setattr(CollisionChecker, "in_collision", count_state)
    d = Driver(task)
    per_tick, slices = [], []
    while d.c.reference is None and d.k < 2000:
        before, s0 = counted["n"], d.c.info()["slices"]
        d.run(truth(board), 1)
        per_tick.append(counted["n"] - before)
        slices.append(d.c.info()["slices"] - s0)
        if d.c.reference is None:
            assert np.max(np.abs(d.commands[-1])) < 1e-9  # holding the start, nothing to push
    info = d.c.info()
    assert d.c.reference is not None and info["paths"] == 1 and info["plan_ticks"][0] > 5
    assert max(slices) == 1
    c = d.c.config
    query_bound = c.plan_checks_per_tick + 2 * math.ceil(c.plan_range / c.motion_resolution)  # two motions past
    assert max(per_tick) <= query_bound + 3  # a slice that prepares a query checks its start and goal
    assert info["max_checks_per_slice"] <= query_bound
    # the path found is free of the board, at the planner's check points and between them
    assert free_along(CollisionChecker(task.robot, board), d.c.reference.waypoints)


def test_with_slice_cpu_share_a_slice_ends_when_the_ticks_cpu_time_has_run_out(task, monkeypatch):
    """A CPU clock that has always run out (a counter, read by the controller and the query):
    every search and shortening slice makes one check, and the path is the one found without it,
    many more ticks later."""
    hand = task.robot.frame_pose(0.5 * (np.asarray(task.start) + np.asarray(task.goal.q)), task.goal.pose.frame)
    board = truth(Scene((Obstacle("board", "box", tuple(hand.translation), size=(0.3, 0.3, 0.02)),)))

    def planned(**settings):
        d = Driver(task, **settings)
        d.run(board, 20000, until=lambda d: d.c.reference is not None and d.c.job is None)
        assert d.c.reference is not None
        return d.c

    plain = planned(slice_cpu_share=0.0)  # slices by their count alone
    reads = iter(range(10**9))
    monkeypatch.setattr(time, "process_time", lambda: float(next(reads)))
    timed = planned(slice_cpu_share=0.5)
    assert timed.info()["max_checks_per_slice"] == 1 < plain.info()["max_checks_per_slice"]
    assert timed.info()["plan_ticks"][0] > 5 * plain.info()["plan_ticks"][0]
    assert np.array_equal(timed.reference.waypoints, plain.reference.waypoints)


def test_a_turns_cpu_share_counts_from_its_update_and_a_spent_turn_runs_no_slice(task, monkeypatch):
    """With ``slice_cpu_share``, a turn that took in a frame counts its share from the update: once
    the update (with the goal's cells, classified by the turn's step) has used it, that turn runs
    no slice of work; a turn without a frame runs one however late its clock, so the work goes on.
    The update itself only takes in the field's grid at 100 Hz."""
    clock = {"t": 0.0}
    monkeypatch.setattr(time, "process_time", lambda: clock["t"])
    period = task.period
    d = Driver(task, slice_cpu_share=0.5)
    frame = depth(Scene())
    d.c.update(frame)
    assert d.c.goal_out is None  # the goal's cells wait for the step: not the field's update
    clock["t"] += 0.6 * period  # the update took more than the turn's share
    d.c.step(0.0, d.q.copy(), None, task.goal)
    info = d.c.info()
    assert info["slices"] == 0 and d.c.goal_out is not None  # classified, and no slice after it
    clock["t"] += 5 * period  # a turn without a frame: a slice however its clock reads
    d.c.step(period, d.q.copy(), None, task.goal)
    assert d.c.info()["slices"] == 1
    d.c.update(dataclasses.replace(frame, time=2 * period, frame=1))
    clock["t"] += 0.1 * period  # within the share: the frame's turn runs its slice too
    d.c.step(2 * period, d.q.copy(), None, task.goal)
    assert d.c.info()["slices"] == 2


def test_the_arms_cells_at_the_goal_are_fitted_in_setup_to_the_sensors_default_grid(task):
    """The cells near the arm's body at the goal are built in ``setup`` for the sensor's default
    grid (untimed), so that a first frame on it classifies the goal's cells without building them;
    a frame on another grid builds them for that grid, the same as a fit made there."""
    from planbench.reactive.sensing import default_bounds
    from planbench_plugins.controllers.observed import ArmCells

    d = Driver(task)
    body = d.c.arm_cells.body
    assert body is not None and d.c.cells.body is None  # before any frame: the run's cells not yet fitted
    grid = OccupancyGrid.empty(*default_bounds(task.robot, 0.02), 0.02)
    d.c.update(Observation(0.0, grid, 0, np.zeros((0, 3)), None))
    d.c.step(0.0, d.q.copy(), None, task.goal)
    assert d.c.cells.body is body and d.c.goal_out is not None  # classified on the cells built in setup
    fresh = ArmCells(task.robot, task.goal.q)
    fresh.fit(grid)
    assert np.array_equal(np.sort(d.c.cells.near_goal), np.sort(fresh.near_goal)) and len(fresh.near_goal)
    other = depth(Scene(), t=0.01, frame=1)  # BOUNDS: another grid
    d.c.update(other)
    d.c.step(0.01, d.q.copy(), None, task.goal)
    fresh.fit(other.grid)
    assert d.c.cells.body is not body
    assert np.array_equal(np.sort(d.c.cells.near_goal), np.sort(fresh.near_goal))


def test_a_frames_new_cells_are_checked_in_octrees_of_at_most_a_slices_cells(task, monkeypatch):
    """The check of a frame builds the octrees of the cells it added a slice's worth at a time
    (``octree_cells``), as a plan does, and still finds the path blocked."""
    import planbench_plugins.controllers.matrix_field_guided as guided

    sizes: list[int] = []
    real = guided.cells_octree
    monkeypatch.setattr(
        guided, "cells_octree", lambda grid, cells, *a: sizes.append(len(cells)) or real(grid, cells, *a)
    )
    d = Driver(task, octree_cells=50, scale_slices=False)
    d.run(depth(Scene()), 400, until=lambda d: d.c.reference is not None and d.k >= 40)
    assert d.c.reference is not None
    ahead = d.c.reference.at(0.5 * (d.c.t_ref + d.c.reference.duration))[0]
    hand = task.robot.frame_pose(ahead, task.goal.pose.frame).translation
    box = Scene((Obstacle("box", "box", tuple(hand), size=(0.12, 0.12, 0.12)),))
    sizes.clear()
    d.run(depth(box), 40, until=lambda d: d.c.reference is None)
    assert d.c.reference is None and d.c.info()["replans"]["invalidated"] == 1
    assert len(sizes) >= 3 and max(sizes) <= 50  # the box's 216 cells in pieces of 50 at most


@pytest.mark.parametrize("observe", [truth, depth])
def test_a_frames_check_of_the_path_also_ends_its_slices_when_the_ticks_cpu_time_has_run_out(
    task, observe, monkeypatch
):
    """With a CPU clock that has always run out (a counter), a frame's check of the rest of the
    path checks one configuration a tick, and still finds the box on the path; without that
    share of the period a slice checks many."""

    def hand_at(d):  # where the hand will be half way along the rest of the path
        ahead = d.c.reference.at(0.5 * (d.c.t_ref + d.c.reference.duration))[0]
        return task.robot.frame_pose(ahead, task.goal.pose.frame).translation

    def checks_per_tick(**settings):
        d = Driver(task, **settings)
        d.run(observe(Scene()), 400, until=lambda d: d.c.reference is not None and d.c.job is None and d.k >= 40)
        assert d.c.reference is not None
        box = Scene((Obstacle("box", "box", tuple(hand_at(d)), size=(0.12, 0.12, 0.12)),))
        counted = {"n": 0}
        real = CollisionChecker.in_collision

        def count(self, q):
            counted["n"] += 1
            return real(self, q)

        with monkeypatch.context() as m:
            if settings.get("slice_cpu_share"):
                reads = iter(range(10**9))
                m.setattr(time, "process_time", lambda: float(next(reads)))
            m.setattr(CollisionChecker, "in_collision", count)
            per_tick = []
            while d.c.reference is not None and d.k < 2000:
                before = counted["n"]
                d.run(observe(box), 1)
                per_tick.append(counted["n"] - before)
        assert d.c.reference is None and d.c.info()["replans"]["invalidated"] == 1
        return per_tick

    timed = checks_per_tick(slice_cpu_share=0.5)
    plain = checks_per_tick(slice_cpu_share=0.0)
    assert max(timed) <= 2  # a configuration, and the arm's touch of the cells near it (depth)
    assert max(plain) > 2
    assert len(timed) > len(plain)


@pytest.mark.parametrize("observe", [truth, depth])
def test_it_replans_when_an_obstacle_appears_on_its_path(task, observe):
    d = Driver(task)
    d.run(observe(Scene()), 400, until=lambda d: d.c.reference is not None and d.k >= 40)
    assert d.c.reference is not None
    first = d.c.reference.waypoints
    assert d.c.info()["paths"] == 1
    # a box on the rest of the path, where the hand will be half way along it, off the arm now and at the goal
    ahead = d.c.reference.at(0.5 * (d.c.t_ref + d.c.reference.duration))[0]
    hand = task.robot.frame_pose(ahead, task.goal.pose.frame).translation
    box = Scene((Obstacle("box", "box", tuple(hand), size=(0.12, 0.12, 0.12)),))
    checker = CollisionChecker(task.robot, box)
    assert not checker.in_collision(d.q) and not checker.in_collision(np.asarray(task.goal.q))
    assert not free_along(checker, first)
    d.run(observe(box), 20, until=lambda d: d.c.reference is None)
    info = d.c.info()
    assert d.c.reference is None and info["replans"]["invalidated"] == 1  # dropped: holding, planning
    d.run(observe(box), 600, until=lambda d: d.c.reference is not None)
    assert d.c.reference is not None and d.c.info()["paths"] == 2
    assert free_along(checker, d.c.reference.waypoints)


def test_it_holds_while_the_goal_is_blocked_and_goes_when_it_clears(task):
    goal_hand = task.robot.frame_pose(np.asarray(task.goal.q), task.goal.pose.frame).translation
    blocked = Scene((Obstacle("ball", "sphere", tuple(goal_hand), radius=0.06),))
    assert CollisionChecker(task.robot, blocked).in_collision(np.asarray(task.goal.q))
    d = Driver(task)
    d.run(truth(blocked), 150)
    info = d.c.info()
    assert info["blocked"] >= 10 and info["paths"] == 0 and d.c.reference is None
    assert np.max(np.abs(d.q - task.start)) < 0.05  # held near the start, the field on
    assert max(np.max(np.abs(qd)) for qd in d.commands) < 0.5
    d.run(truth(Scene()), 600, until=lambda d: np.max(np.abs(d.q - task.goal.q)) < 1e-3)
    assert np.max(np.abs(d.q - task.goal.q)) < 1e-3 and d.c.info()["paths"] == 1


def test_a_depth_goal_next_to_cells_seen_at_the_start_is_reached(task):
    """A plate just under the hand at the goal, clear of it but in its cells: cells near the arm's
    body at the goal that were occupied the first time a frame knew them are the static scene a
    grasp touches, left out of the plan as ``ompl-replan`` leaves them out."""
    goal_q = np.asarray(task.goal.q)
    hand = task.robot.frame_pose(goal_q, task.goal.pose.frame).translation
    for drop in np.arange(0.0, 0.3, 0.005):  # the highest plate the arm at the goal does not touch
        plate = Scene((Obstacle("plate", "box", tuple(hand - [0, 0, drop + 0.05]), size=(0.3, 0.3, 0.1)),))
        if not CollisionChecker(task.robot, plate).in_collision(goal_q):
            break
    cells = depth(plate).grid
    occupied = np.flatnonzero(cells.data.reshape(-1) >= 0.5)
    from planbench_plugins.ompl_planners import cells_checker

    assert cells_checker(task.robot, cells, occupied).in_collision(goal_q)  # "in" the plate's cells
    d = Driver(task)
    d.run(depth(plate), 800, until=lambda d: np.max(np.abs(d.q - goal_q)) < 1e-3)
    assert d.c.info()["blocked"] == 0 and np.max(np.abs(d.q - goal_q)) < 1e-3


def test_a_depth_goal_blocked_by_cells_that_appeared_is_left_out_after_goal_block_time(task):
    """Cells near the goal that a frame saw free and that are occupied now block the goal, for
    ``goal_block_time`` at most: then they are taken for what a map keeps where no ray passes."""
    goal_q = np.asarray(task.goal.q)
    hand = task.robot.frame_pose(goal_q, task.goal.pose.frame).translation
    ball = Scene((Obstacle("ball", "sphere", tuple(hand), radius=0.06),))
    d = Driver(task, goal_block_time=0.5)
    d.c.update(depth(Scene()))  # every cell near the goal seen free
    d.k = 3  # the next tick takes in the ball's frame first
    d.run(depth(ball), 300, until=lambda d: d.c.reference is not None)
    info = d.c.info()
    assert info["blocked"] >= 5 and info["paths"] == 1
    assert 0.5 <= d.k * task.period <= 1.5  # planned once the cells had blocked the goal for 0.5 s


def test_a_goal_that_stays_blocked_is_checked_against_the_cells_near_it_then_reached(task):
    """Once a plan was refused for its goal, the next frames test the goal against the occupied
    cells near it only (no plan geometry built), until they clear; then it plans and goes."""
    goal_q = np.asarray(task.goal.q)
    hand = task.robot.frame_pose(goal_q, task.goal.pose.frame).translation
    ball = Scene((Obstacle("ball", "sphere", tuple(hand), radius=0.06),))
    d = Driver(task, goal_block_time=100.0)
    d.c.update(depth(Scene()))  # every cell near the goal seen free: the ball's cells block the goal
    d.k = 3
    d.run(depth(ball), 150)
    info = d.c.info()
    assert info["paths"] == 0 and info["blocked"] >= 10 and info["blocked_near_goal"] == info["blocked"] - 1
    d.run(depth(Scene()), 800, until=lambda d: np.max(np.abs(d.q - goal_q)) < 1e-3)
    info = d.c.info()
    assert np.max(np.abs(d.q - goal_q)) < 1e-3 and info["paths"] == 1 and info["blocked_near_goal"] >= 9


def test_at_1_khz_a_frames_turn_and_the_next_run_no_slice_and_the_goal_cells_are_classified_second(task):
    """With slices finer than a 10 ms tick's, the frame's turn carries its update only (its step
    runs no slice), the step after it classifies the cells near the goal (no slice either), and
    the plan's slices start on the third; at 100 Hz the frame's step runs a slice at once."""
    goal_q = np.asarray(task.goal.q)
    hand = task.robot.frame_pose(goal_q, task.goal.pose.frame).translation
    ball = Scene((Obstacle("ball", "sphere", tuple(hand), radius=0.06),))
    c = MatrixFieldGuidedController()
    c.setup(dataclasses.replace(task, period=0.001))
    q = np.array(task.start, dtype=float)
    c.reset(q.copy(), np.random.default_rng(0))
    c.update(depth(ball))
    assert not c.goal_cells.first_seen.any()
    c.step(0.0, q, None, task.goal)
    assert not c.goal_cells.first_seen.any() and c.job is None and c.info()["slices"] == 0  # the frame's turn
    c.step(0.001, q, None, task.goal)
    assert c.goal_cells.first_seen.any() and c.info()["slices"] == 0
    c.step(0.002, q, None, task.goal)
    assert c.job is not None and c.info()["slices"] == 1
    coarse = MatrixFieldGuidedController()
    coarse.setup(task)
    coarse.reset(q.copy(), np.random.default_rng(0))
    coarse.update(depth(ball))
    coarse.step(0.0, q, None, task.goal)
    assert len(coarse.goal_cells.first_seen) > 0 and coarse.info()["slices"] == 1


def test_unknown_cells_near_the_arm_are_obstacles_for_the_plan_with_unknown_occupied(task):
    """An unknown block where the free-space path's hand passes: ``"free"`` plans through it,
    ``"occupied"`` around it (every unknown cell in reach counts: ``unknown_reach`` 2 m)."""
    d = Driver(task)
    d.run(depth(Scene()), 400, until=lambda d: d.c.reference is not None)
    straight = d.c.reference.waypoints
    grid = OccupancyGrid.empty(*BOUNDS, 0.02)
    body = ArmBody(task.robot, grid.origin, grid.shape, grid.resolution)
    ends = np.zeros(grid.shape, dtype=bool)
    body.mark(ends, straight[0])
    body.mark(ends, straight[-1])
    dense = densify(straight, 0.02)[0]
    known = None
    for q in dense[len(dense) // 3 :]:  # the first place on the hand's way, off the arm at both ends
        i, j, k = grid.index_of(task.robot.frame_pose(q, task.goal.pose.frame).translation[None])[0]
        mask = np.ones(grid.shape, dtype=bool)
        mask[i - 3 : i + 4, j - 3 : j + 4, k - 3 : k + 4] = False
        if not (np.pad(ends, 4)[i : i + 15, j : j + 15, k : k + 15]).any():
            known = mask
            break
    assert known is not None
    assert any(body.in_unknown(q, known) for q in dense)
    free = Driver(task)
    free.run(depth(Scene(), known=known), 400, until=lambda d: d.c.reference is not None)
    assert any(body.in_unknown(q, known) for q in densify(free.c.reference.waypoints, 0.02)[0])
    safe = Driver(task, unknown="occupied", unknown_reach=2.0)
    safe.run(depth(Scene(), known=known), 1500, until=lambda d: d.c.reference is not None)
    assert safe.c.reference is not None and safe.c.info()["unknown_cells"] > 0
    assert not any(body.in_unknown(q, known) for q in densify(safe.c.reference.waypoints, 0.01)[0])


# --- closed loop ----------------------------------------------------------------------------------------


def test_it_reaches_the_goal_of_a_static_scene_with_truth_sensing():
    problem = planbench.load_problems("mbm:bookshelf_small/0001")[0]
    scenario = Scenario(problem, (), SensingSettings("truth", rate=30.0), control_rate=100.0, horizon=20.0)
    controller = MatrixFieldGuidedController()
    record = run_scenario(scenario, controller, settings=RunSettings(timing="ideal"))
    metrics = evaluate_run(scenario, record)
    assert record.status == "success" and metrics.success, (metrics.failure, controller.info())
    assert controller.info()["paths"] >= 1


@pytest.mark.parametrize(
    ("period", "scale", "expected"),
    [
        (0.01, True, (200, 4000, 2)),
        (0.001, True, (11, 1000, 20)),  # checks: the period left beyond TICK_COST; cells: at least MIN_SLICE_CELLS
        (0.001, False, (200, 4000, 2)),
        (0.02, True, (411, 8000, 2)),
    ],
)
def test_slices_are_sized_for_the_control_period(task, period, scale, expected):
    """A 10 ms tick's slice sizes, scaled with the period (``scale_slices``): the checks with the
    period left beyond a tick's fixed cost (11 at 1 kHz), the cells with the period (no fewer than
    1,000 an octree), the grid's scan in ten times the parts at 1 kHz; at 100 Hz as given."""
    c = MatrixFieldGuidedController(scale_slices=scale)
    c.setup(dataclasses.replace(task, period=period))
    assert (c.slice_checks, c.slice_cells, c.scan_parts) == expected


def test_exact_slices_make_the_unsliced_search_and_end_at_their_bound(bookshelf):
    """An exact query (its search on a thread paused at each slice's bound) makes, for any slice
    size, the checks and path of one unlimited solve, and each slice but the last makes exactly
    its checks."""
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    whole = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, shorten=False)
    assert whole.advance(10**9)
    for size in (1, 7, 50):
        query = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, shorten=False, exact=True)
        per_slice = []
        while True:
            before = query.checks
            done = query.advance(size)
            per_slice.append(query.checks - before)
            if done:
                break
        assert set(per_slice[:-1]) == {size} and per_slice[-1] <= size
        assert query.checks == whole.checks and np.array_equal(query.path, whole.path)


def test_a_slice_past_its_cpu_time_ends_after_one_check_and_the_path_is_the_same(bookshelf):
    """A slice ends at the first check past ``cpu_until`` (here always past: one check a slice),
    in the search and in the shortening; the checks and the shortened path are those of slices
    without it."""
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    free = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, exact=True)
    while not free.advance(50):
        pass
    timed = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, exact=True)
    per_slice = []
    while True:
        before = timed.checks
        done = timed.advance(50, cpu_until=-math.inf)
        per_slice.append(timed.checks - before)
        if done:
            break
    assert set(per_slice[:-1]) == {1} and timed.slices > 20 * free.slices
    assert timed.checks == free.checks and np.array_equal(timed.path, free.path)
    later = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, exact=True)
    assert not later.advance(50, cpu_until=math.inf) and later.checks == 50  # not yet: the count ends it


def test_an_exact_query_dropped_or_closed_unfinished_ends_its_thread(bookshelf):
    checker = CollisionChecker(bookshelf.robot, bookshelf.scene)
    before = threading.active_count()
    closed = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=3, exact=True)
    dropped = SlicedRRTConnect(checker, bookshelf.start, bookshelf.goal.q, seed=4, exact=True)
    assert not closed.advance(5) and not dropped.advance(5)
    assert threading.active_count() == before + 2
    closed.close()
    assert not closed.advance(5) and closed.path is None
    del dropped
    gc.collect()
    assert threading.active_count() == before


@pytest.mark.parametrize("way", [(0, 1, 0), (0, -1, 0), (0, 0, 1)])  # sideways, from above
def test_while_it_waits_it_backs_away_from_an_obstacle_that_comes_at_it(task, way):
    """Holding while the goal is blocked, the field on: a ball driven at the hand (0.58 m/s) pushes
    the arm back, and the arm never touches it; with the hold pulling the arm back
    (``hold_gives_way=False``) the ball reaches it."""
    goal_q = np.asarray(task.goal.q)
    goal_hand = task.robot.frame_pose(goal_q, task.goal.pose.frame).translation
    hand = task.robot.frame_pose(np.asarray(task.start), task.goal.pose.frame).translation
    blocker = Obstacle("blocker", "sphere", tuple(goal_hand), radius=0.06)
    touched = {}
    for gives in (True, False):
        d = Driver(task, hold_gives_way=gives)
        d.run(truth(Scene((blocker,))), 30)
        assert d.c.info()["blocked"] >= 1 and d.c.reference is None
        touched[gives] = []
        for k in range(60):  # from 0.40 m to 0.05 m off where the hand was, over 0.6 s
            ball = Obstacle("ball", "sphere", tuple(hand + np.array(way) * (0.40 - 0.35 * k / 59)), radius=0.05)
            d.run(truth(Scene((blocker, ball))), 3)
            touched[gives].append(CollisionChecker(task.robot, Scene((ball,))).in_collision(d.q))
    assert not any(touched[True]) and any(touched[False])
