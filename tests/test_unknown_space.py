"""How the built-in controllers read cells no camera saw (``unknown``): the field controllers keep
out of an unknown block with ``"occupied"`` that ``"free"`` drives through; ``ompl-replan``'s
safe mode does not plan through an unknown block; the arm's own cells never count; bad values are
named errors. Observations are built by hand (an empty grid with a ``known`` mask)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.conformance import conformance_task
from planbench.reactive.controller import ControlTask, Observation
from planbench.registry import make_controller
from planbench.scene import Obstacle, Scene
from planbench_plugins.controllers.unknown import near_unknown, unknown_as_occupied
from planbench_plugins.ik_loop import place_control_points

FIELD_CONTROLLERS = ["matrix-field", "matrix-field-qp", "edt-field", "distance-field"]
ALL_CONTROLLERS = [*FIELD_CONTROLLERS, "ompl-replan"]


@pytest.fixture(scope="module")
def box():
    return conformance_task()


def unknown_block(grid: OccupancyGrid, centre: np.ndarray, half: int) -> Observation:
    """An observation of ``grid`` (all free) whose cells within ``half`` cells of ``centre`` [m] are unknown."""
    known = np.ones(grid.shape, dtype=bool)
    i, j, k = grid.index_of(centre[None])[0]
    known[i - half : i + half + 1, j - half : j + half + 1, k - half : k + half + 1] = False
    return Observation(0.0, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=known))


def hand_path(controller, task, observation, ticks: int, frame_every: int = 3) -> np.ndarray:
    """The hand's positions [m] under ``controller``, integrated as the runner does, with the same
    frame delivered every ``frame_every`` ticks (30 Hz at 10 ms)."""
    robot, vmax = task.robot, np.asarray(task.robot.velocity_limit)
    q = np.array(task.start, dtype=float)
    controller.setup(task)
    controller.reset(q.copy(), np.random.default_rng(0))
    hands = [robot.frame_pose(q, task.goal.pose.frame).translation.copy()]
    for k in range(ticks):
        if k % frame_every == 0:
            controller.update(dataclasses.replace(observation, time=k * task.period, frame=k // frame_every))
        qd = controller.step(k * task.period, q.copy(), observation, task.goal)
        q = np.clip(q + task.period * np.clip(qd, -vmax, vmax), robot.lower, robot.upper)
        hands.append(robot.frame_pose(q, task.goal.pose.frame).translation.copy())
    return np.array(hands)


def inside(grid: OccupancyGrid, known: np.ndarray, points: np.ndarray) -> np.ndarray:
    idx = grid.index_of(points)
    ok = np.all((idx >= 0) & (idx < np.array(grid.shape)), axis=1)
    out = np.zeros(len(points), dtype=bool)
    out[ok] = ~known[tuple(idx[ok].T)]
    return out


@pytest.mark.parametrize("name", FIELD_CONTROLLERS)
def test_a_field_controller_reading_unknown_as_occupied_keeps_out_of_an_unknown_block(box, name):
    task, free = box.task, box.free
    ticks = 250
    path = hand_path(make_controller(name), task, free, ticks)
    centre = path[len(path) // 3]  # on the hand's way in free space
    seen = unknown_block(free.grid, centre, half=3)  # a 14 cm cube no camera saw
    core = unknown_block(free.grid, centre, half=1).grid.known  # its middle 3 x 3 x 3 cells
    assert core is not None
    through = hand_path(make_controller(name), task, seen, ticks)
    assert inside(seen.grid, core, through).any()  # "free": the same way, through the block's middle
    kept = hand_path(make_controller(name, unknown="occupied"), task, seen, ticks)
    assert not inside(seen.grid, core, kept).any()  # "occupied": held off it, as by an obstacle


def test_the_arms_own_cells_and_far_cells_are_not_counted(box):
    robot, q = box.task.robot, np.array(box.task.start, dtype=float)
    grid = box.free.grid
    cp = place_control_points(robot)
    centres = cp.world(robot, q)
    known = np.zeros(grid.shape, dtype=bool)  # nothing seen, as around a blinded arm
    g = OccupancyGrid(grid.data, grid.origin, grid.resolution, known=known)
    cells = near_unknown(g, [(centres, cp.radius)], reach=0.2, self_margin=0.05)
    assert cells is not None and cells.any()
    where = g.cell_centers()[cells]
    d = np.linalg.norm(where[:, None, :] - centres[None, :, :], axis=2)
    assert np.all(d.min(axis=1) <= 0.2 + 1e-9)  # only near the arm
    assert np.all(d >= cp.radius[None, :] + 0.05 - 1e-9)  # never within its body and margin
    assert near_unknown(grid, [(centres, cp.radius)], 0.2, 0.05) is None  # every cell known
    marked = unknown_as_occupied(g, cells)
    assert marked.known is None and np.array_equal(marked.data > 0, cells | (g.data > 0))
    assert unknown_as_occupied(g, np.zeros_like(cells)) is g


@pytest.mark.parametrize("name", ALL_CONTROLLERS)
@pytest.mark.parametrize(
    "setting", [{"unknown": "maybe"}, {"unknown_reach": 0.0}, {"unknown_reach": "far"}, {"unknown_self_margin": -0.1}]
)
def test_bad_unknown_settings_are_named_errors(name, setting):
    key = next(iter(setting))
    with pytest.raises(InvalidConfigError, match=key):
        make_controller(name, **setting)


@pytest.mark.parametrize("name", ALL_CONTROLLERS)
def test_every_controller_defaults_to_unknown_as_free(name):
    assert make_controller(name).config.unknown == "free"


# --- ompl-replan's safe mode -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def free_task() -> ControlTask:
    p = planbench.load_problems("mbm:table_pick/0001")[0]
    return ControlTask(p.robot, p.start, p.goal, p.tolerances, 0.01, "free")


def _plan_of(task: ControlTask, observation: Observation, **settings) -> tuple[np.ndarray, dict]:
    """The first path ``ompl-replan`` plans from the start on ``observation`` (start first), and its info."""
    c = make_controller("ompl-replan", **settings)
    c.setup(task)
    q = np.array(task.start, dtype=float)
    c.reset(q.copy(), np.random.default_rng(0))
    c.update(observation)
    c.step(0.0, q.copy(), observation, task.goal)
    assert c.path is not None, c.info()
    return np.vstack([q, c.path]), c.info()


def _touches(task: ControlTask, scene, path: np.ndarray) -> bool:
    checker = CollisionChecker(task.robot, scene)
    dense = [a + u * (b - a) for a, b in zip(path[:-1], path[1:], strict=True) for u in np.linspace(0, 1, 25)]
    return any(checker.in_collision(x) for x in dense)


def test_ompl_replan_safe_mode_does_not_plan_through_an_unknown_block_near_its_path(free_task):
    robot = free_task.robot
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    seen_all = Observation(0.0, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=np.ones(grid.shape, bool)))
    path, _ = _plan_of(free_task, seen_all)
    dense = [a + u * (b - a) for a, b in zip(path[:-1], path[1:], strict=True) for u in np.linspace(0, 1, 25)]
    # a 10 cm cube no camera saw, on the hand's way, within 0.3 m of it (near the arm) and off the arm
    hands = [robot.frame_pose(x, free_task.goal.pose.frame).translation for x in dense]
    start_checker = CollisionChecker(robot, Scene())
    for hand in hands:
        centre = grid.origin + (grid.index_of(hand[None])[0] + 0.5) * grid.resolution
        block = Scene((Obstacle("unseen", "box", position=tuple(centre), size=(0.1, 0.1, 0.1)),))
        start_checker = CollisionChecker(robot, block)
        if np.linalg.norm(hand - hands[0]) < 0.28 and not start_checker.in_collision(path[0]):
            break
    assert np.linalg.norm(hand - hands[0]) < 0.28 and not start_checker.in_collision(path[0])
    blind = unknown_block(grid, centre, half=2)
    through, _ = _plan_of(free_task, blind)  # "free": the same plan, through the block
    assert _touches(free_task, block, through)
    around, info = _plan_of(free_task, blind, unknown="occupied")
    assert info["unknown_boxes"] > 0 and info["failed_plans"] == 0
    assert not _touches(free_task, block, around)
