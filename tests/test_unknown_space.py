"""How the built-in controllers read cells no camera saw (``unknown``): the field controllers keep
out of an unknown block with ``"occupied"`` that ``"free"`` drives through; ``ompl-replan``'s
safe mode does not plan through an unknown block; the arm's own cells never count; bad values are
named errors. Observations are built by hand (an empty grid with a ``known`` mask)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree

import planbench
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.body import ArmBody
from planbench.reactive.conformance import conformance_task
from planbench.reactive.controller import ControlTask, Observation
from planbench.reactive.scenario import CameraSettings
from planbench.reactive.shadows import ARM, SURFACE, occluders
from planbench.registry import make_controller
from planbench_plugins.controllers.evade import ArmSamples
from planbench_plugins.controllers.unknown import near_unknown, unknown_as_occupied
from planbench_plugins.ik_loop import place_control_points
from planbench_plugins.ompl_planners import cells_checker

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


@pytest.mark.parametrize(
    "setting",
    [
        {"known_plan_time": 0.0},
        {"known_plan_time": float("nan")},
        {"surface_margin": -1.0},
        {"look_frames": 1.5},
        {"known_checks_per_tick": -1},
        {"known_checks_per_tick": True},
        {"known_plan_checks": 0},
        {"known_cpu_share": 1.0},
        {"known_cpu_share": -0.1},
        {"relax_steps": -1},
        {"relax_after": 0},
        {"dead_end": "jump"},
        {"known_plan_at": "later"},
        {"surface_shadow": "never"},
        {"known_sliced_when": "sometimes"},
        {"known_hold_distance": 0.0},
        {"plan_sliced_when": "always"},
        {"plan_sliced_when": "threat", "known_checks_per_tick": 0},
        {"plan_sliced_when": "contact", "known_checks_per_tick": 0},
        {"hold_time": float("inf")},
    ],
)
def test_bad_safe_mode_settings_of_ompl_replan_are_named_errors(setting):
    key = next(iter(setting))
    with pytest.raises(InvalidConfigError, match=key):
        make_controller("ompl-replan", **setting)


@pytest.mark.parametrize("name", ALL_CONTROLLERS)
def test_defaults_chosen_on_dynamic_tune_field_controllers_free_ompl_replan_safe(name):
    expected = "occupied" if name == "ompl-replan" else "free"
    assert make_controller(name).config.unknown == expected


# --- ompl-replan's safe mode -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def free_task() -> ControlTask:
    p = planbench.load_problems("mbm:table_pick/0001")[0]
    return ControlTask(p.robot, p.start, p.goal, p.tolerances, 0.01, "free")


def _run(
    task: ControlTask,
    observation: Observation | list[tuple[int, Observation]],
    ticks: int,
    before: Observation | None = None,
    **settings,
):
    """``ompl-replan`` driven as the runner drives it (no compute time charged), the same frame
    delivered every 3 ticks (a list of (tick, frame): the last whose tick has come), after
    ``before`` 0.2 s earlier if given (a change between them reads as motion): the configurations
    after each tick, and the controller."""
    frames = observation if isinstance(observation, list) else [(0, observation)]
    c = make_controller("ompl-replan", **settings)
    robot, vmax = task.robot, np.asarray(task.robot.velocity_limit)
    q = np.array(task.start, dtype=float)
    c.setup(task)
    c.reset(q.copy(), np.random.default_rng(0))
    if before is not None:
        c.update(dataclasses.replace(before, time=-0.2, frame=-1))
    qs = [q.copy()]
    for k in range(ticks):
        seen = [f for when, f in frames if when <= k][-1]
        if k % 3 == 0:
            c.update(dataclasses.replace(seen, time=k * task.period, frame=k // 3))
        qd = c.step(k * task.period, q.copy(), seen, task.goal)
        q = np.clip(q + task.period * np.clip(qd, -vmax, vmax), robot.lower, robot.upper)
        qs.append(q.copy())
    return np.array(qs), c


@pytest.fixture(scope="module")
def open_space(free_task):
    """An empty grid, every cell seen, and the path ``ompl-replan`` follows there (start first)."""
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    seen = Observation(0.0, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=np.ones(grid.shape, bool)))
    qs, c = _run(free_task, seen, 400)
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6), c.info()
    return grid, qs


def _seeing(grid: OccupancyGrid, known: np.ndarray) -> Observation:
    return Observation(0.0, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=known))


def test_ompl_replan_safe_mode_leaves_a_start_walled_in_by_unknown_space_off_its_path(free_task, open_space):
    """Only the cells the arm sweeps on its way are known (one cell around them): the start stands
    in unknown space on every side, as a camera's view of a still arm leaves it. The old safe mode
    (unknown cells within 0.3 m are obstacles) never left such a start; this one follows its path,
    and never moves the arm into an unknown cell."""
    grid, path = open_space
    robot = free_task.robot
    body = ArmBody(robot, grid.origin, grid.shape, grid.resolution)
    swept = np.zeros(grid.shape, dtype=bool)
    for a, b in zip(path[:-1], path[1:], strict=True):
        for u in np.linspace(0.0, 1.0, 5):
            body.mark(swept, a + u * (b - a))
    known = ndimage.binary_dilation(swept)
    assert (~known).sum() > 0.9 * known.size  # unknown nearly everywhere, around the start too
    start_shell = ndimage.binary_dilation(swept, iterations=3) & ~known
    assert start_shell.any()
    qs, c = _run(free_task, _seeing(grid, known), 400, unknown="occupied")
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6), c.info()  # it got there
    assert not any(body.in_unknown(q, known) for q in qs)  # through known cells only
    assert c.info()["forced"] == 0


def _block_on_path(free_task, grid: OccupancyGrid, path: np.ndarray, body: ArmBody) -> np.ndarray:
    """The ``known`` mask of ``grid`` with a 10 cm cube unknown on the hand's way along ``path``,
    off the arm at the start and at the goal."""
    robot = free_task.robot
    ends = np.zeros(grid.shape, dtype=bool)  # near the arm at the start and at the goal
    body.mark(ends, path[0])
    body.mark(ends, path[-1])
    ends = ndimage.binary_dilation(ends, iterations=4)
    for q in path[len(path) // 4 :]:  # the first place on the hand's way off both
        hand = robot.frame_pose(q, free_task.goal.pose.frame).translation
        known = unknown_block(grid, hand, half=2).grid.known
        assert known is not None
        if not (ends & ~known).any():
            return known
    raise AssertionError("no place for the block")


@pytest.mark.parametrize(
    ("per_tick", "at", "share"), [(50, "start", 0.0), (2000, "start", 0.9), (0, "start", 0.0), (0, "stop", 0.0)]
)
def test_ompl_replan_safe_mode_plans_around_an_unknown_block_in_known_space(free_task, open_space, per_tick, at, share):
    """A 10 cm cube no camera saw lies on the path, off the start and the goal; everything else is
    seen. The default follows its path through it; the safe mode plans in known space around it, in
    slices while the arm follows the first path up to the cube (``known_checks_per_tick`` > 0), or
    at once, the arm held still (the default), or once the arm, following the first path, has
    stopped short of the cube and looked (``known_plan_at = "stop"``); the arm's body is never in
    one of the cube's cells. Slices bounded by a share of the tick's CPU time too
    (``known_cpu_share``) end when the clock says, so how many there are is not asserted."""
    grid, path = open_space
    body = ArmBody(free_task.robot, grid.origin, grid.shape, grid.resolution)
    known = _block_on_path(free_task, grid, path, body)
    through, _ = _run(free_task, _seeing(grid, known), 400, unknown="free")
    assert any(body.in_unknown(q, known) for q in through)  # "free": through the block
    qs, c = _run(
        free_task,
        _seeing(grid, known),
        600,
        unknown="occupied",
        known_checks_per_tick=per_tick,
        known_plan_at=at,
        known_cpu_share=share,
        known_sliced_when="always",
        plan_sliced_when="never",  # the plan to the goal at once: the arm sets off on the first tick
    )
    info = c.info()
    assert not any(body.in_unknown(q, known) for q in qs), info  # never in the block
    assert info["known_plans"] >= 1 and info["forced"] == 0
    if at == "stop":  # planned round only after it had stopped short of the cube and looked
        assert info["looks"] > 3, info
    elif not per_tick:  # planned round at once: never held short of the cube
        assert info["looks"] == 0, info
    if per_tick and not share:  # the plan took ticks, and the arm moved meanwhile
        assert info["known_slices"] > 1
        assert np.linalg.norm(qs[info["known_slices"] // 2] - qs[0]) > 0.01, info
    elif not per_tick:
        assert info["known_slices"] == 0
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6), info  # around it to the goal


def test_ompl_replan_sliced_plan_in_known_space_spends_cpu_time_not_checks(free_task, open_space, monkeypatch):
    """With ``known_cpu_share`` the sliced plan in known space is bounded by CPU time, not by its
    check count (``known_plan_checks``, 10,000): under a CPU clock that moves a second at every
    reading, each slice ends after its first check and the first slice spends the plan's budget
    (``known_plan_time``, 0.5 s), so the plan gives up after that one slice."""
    grid, path = open_space
    body = ArmBody(free_task.robot, grid.origin, grid.shape, grid.resolution)
    known = _block_on_path(free_task, grid, path, body)
    clock = iter(range(1, 10**9))
    monkeypatch.setattr(time, "process_time", lambda: float(next(clock)))
    _, c = _run(
        free_task,
        _seeing(grid, known),
        60,
        unknown="occupied",
        plan_clock="wall",  # the first plan's limit on the true clock
        known_checks_per_tick=2000,
        known_cpu_share=0.9,
        known_sliced_when="always",
        plan_sliced_when="never",  # the first plan at once, under the true clock
    )
    info = c.info()
    assert info["known_slices"] == 1 and info["known_failed"] == 1 and info["known_plans"] == 0, info


def test_ompl_replan_goes_through_cells_only_its_own_arm_hides(free_task, open_space):
    """The 10 cm cube no camera saw lies where the one camera's lines of sight to it pass through
    the arm at the start (the camera just behind the arm): moving the arm shows it. With
    ``arm_shadow`` the safe mode follows its first path through it, without a plan in known space or
    a look; without, it plans around it as before."""
    grid, path = open_space
    body = ArmBody(free_task.robot, grid.origin, grid.shape, grid.resolution)
    known = _block_on_path(free_task, grid, path, body)
    cube = np.flatnonzero(~known)
    centre = grid.origin + (np.column_stack(np.unravel_index(cube, grid.shape)).mean(axis=0) + 0.5) * grid.resolution
    arm_cells = body.cells(path[0])
    points = grid.origin + (np.column_stack(np.unravel_index(arm_cells, grid.shape)) + 0.5) * grid.resolution
    near = points[np.argmin(np.linalg.norm(points - centre, axis=1))]
    away = (near - centre) / np.linalg.norm(near - centre)
    up = (0.0, 0.0, 1.0) if abs(away[2]) < 0.9 else (1.0, 0.0, 0.0)
    camera = CameraSettings(position=tuple(near + 0.12 * away), look_at=tuple(centre), up=up)
    task = dataclasses.replace(free_task, cameras=(camera,), robot_margin=0.03)
    arm = np.zeros(grid.shape, dtype=bool)
    arm.reshape(-1)[arm_cells] = True
    arm = ndimage.binary_dilation(arm, iterations=3)
    assert (occluders(cube, grid, arm, [camera]) == ARM).mean() > 0.9  # the arm hides the cube
    qs, c = _run(task, _seeing(grid, known), 400, unknown="occupied", arm_shadow=True)
    info = c.info()
    assert info["arm_shadow"] > 0 and info["known_plans"] == 0 and info["looks"] == 0, info
    assert any(body.in_unknown(q, known) for q in qs)  # through the cube
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6), info
    _, c = _run(task, _seeing(grid, known), 400, unknown="occupied")
    assert c.info()["arm_shadow"] == 0 and c.info()["known_plans"] >= 1


def test_ompl_replan_safe_mode_stops_before_an_unknown_block_it_cannot_avoid(free_task, open_space):
    """Only the cells the path sweeps are known, and a 10 cm cube of them is not: no path in known
    space. The safe mode follows the default's path, stops short of the cube, and goes into it only
    after ``look_frames`` new frames have shown nothing there; with a wait longer than the run it
    never does."""
    grid, path = open_space
    body = ArmBody(free_task.robot, grid.origin, grid.shape, grid.resolution)
    swept = np.zeros(grid.shape, dtype=bool)
    for a, b in zip(path[:-1], path[1:], strict=True):
        for u in np.linspace(0.0, 1.0, 5):
            body.mark(swept, a + u * (b - a))
    known = ndimage.binary_dilation(swept) & _block_on_path(free_task, grid, path, body)
    qs, c = _run(free_task, _seeing(grid, known), 400, unknown="occupied", look_frames=10**6)
    info = c.info()
    inside = [body.in_unknown(q, known) for q in qs]
    assert not any(inside[60:]), info  # (the first ticks leave the start, in its own unknown shell)
    assert info["looks"] > 0 and info["forced"] == 0 and info["known_plans"] == 0
    assert np.allclose(qs[-1], qs[-2]) and not np.allclose(qs[-1], free_task.goal.q)  # stopped short
    qs, c = _run(free_task, _seeing(grid, known), 600, unknown="occupied")  # look_frames = 3
    inside = [body.in_unknown(q, known) for q in qs]
    first = next(k for k in range(60, len(qs)) if inside[k])
    still = np.linalg.norm(np.diff(qs[first - 20 : first], axis=0), axis=1) < 1e-12
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]]))))[::2]
    assert runs.max() >= 8  # still for 3 frames (9 ticks) just before it went in (the lookahead after)
    assert c.info()["forced"] >= 1
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6)


def _swept_and_cube(free_task, grid, path):
    """The arm's body on ``grid``, the cells it sweeps along ``path``, the unknown cube on it (False
    in ``block``), and the known mask: the swept cells grown by one, less the cube."""
    body = ArmBody(free_task.robot, grid.origin, grid.shape, grid.resolution)
    swept = np.zeros(grid.shape, dtype=bool)
    for a, b in zip(path[:-1], path[1:], strict=True):
        for u in np.linspace(0.0, 1.0, 5):
            body.mark(swept, a + u * (b - a))
    block = _block_on_path(free_task, grid, path, body)
    return body, swept, block, ndimage.binary_dilation(swept) & block


def test_ompl_replan_never_goes_into_cells_a_surface_hides_with_surface_shadow_avoid(free_task, open_space):
    """The cube it cannot avoid (above) lies behind an observed plate from the one camera, 0.25 m
    in front of it: no look from a standstill shows it. With ``surface_shadow = "avoid"`` the arm
    stops short of it and never goes in (a dead end, ``stuck``); by default it goes in after its
    looks, as into any unknown cell."""
    grid, path = open_space
    body, swept, block, known = _swept_and_cube(free_task, grid, path)
    cube = np.flatnonzero(~block)
    centre = grid.origin + (np.column_stack(np.unravel_index(cube, grid.shape)).mean(axis=0) + 0.5) * grid.resolution
    near_path = ndimage.binary_dilation(swept, iterations=2)

    def clear(direction):  # the camera's line from the cube meets the arm's way nowhere beyond 0.15 m
        pts = centre + np.linspace(0.15, 0.7, 60)[:, None] * direction
        ijk = np.floor((pts - grid.origin) / grid.resolution).astype(int)
        ok = np.all((ijk >= 0) & (ijk < grid.shape), axis=1)
        return not near_path[tuple(ijk[ok].T)].any()

    grid_directions = np.array(
        [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (1, 0, -1) if (i, j, k) != (0, 0, 0)]
    )
    away = next(d / np.linalg.norm(d) for d in grid_directions.astype(float) if clear(d / np.linalg.norm(d)))
    up = (0.0, 0.0, 1.0) if abs(away[2]) < 0.9 else (1.0, 0.0, 0.0)
    camera = CameraSettings(position=tuple(centre + 0.7 * away), look_at=tuple(centre), up=up)
    data = grid.data.copy()
    plate = np.floor((centre + 0.25 * away - grid.origin) / grid.resolution).astype(int)
    lo, hi = plate - 4, plate + 5
    lo[np.argmax(np.abs(away))], hi[np.argmax(np.abs(away))] = (
        plate[np.argmax(np.abs(away))],
        plate[np.argmax(np.abs(away))] + 1,
    )
    data[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = 1.0
    seen = OccupancyGrid(data, grid.origin, grid.resolution, known=known | (data > 0.5))
    task = dataclasses.replace(free_task, cameras=(camera,), robot_margin=0.03)
    assert (occluders(cube, seen, np.zeros(grid.shape, dtype=bool), [camera]) == SURFACE).mean() > 0.9
    frame = Observation(0.0, seen)
    qs, c = _run(task, frame, 400, unknown="occupied", surface_shadow="avoid")
    info = c.info()
    assert not any(body.in_unknown(q, known) for q in qs[60:]), info  # never into the cube
    assert info["stuck"] > 0 and info["forced"] == 0, info
    qs, c = _run(task, frame, 600, unknown="occupied")
    assert c.info()["forced"] >= 1 and np.allclose(qs[-1], free_task.goal.q, atol=1e-6), c.info()


def test_ompl_replan_safe_mode_relaxes_a_surface_margin_that_leaves_no_plan(free_task, open_space):
    """Only the cells the path sweeps are known, a 10 cm cube of them is not, and one occupied cell
    lies 0.3 m off the path: with a surface margin of 0.5 m every unknown cell near the path is the
    unseen rest of that surface, so no plan exists. Without relaxing (``relax_steps = 0``) the arm
    never leaves; relaxed step by step (``relax_steps``) it plans through the cube, stops short,
    looks, goes in and reaches the goal, and its body never meets the occupied cell."""
    grid, path = open_space
    robot = free_task.robot
    body, swept, block, known = _swept_and_cube(free_task, grid, path)
    centre = grid.origin + (np.argwhere(~block).mean(axis=0) + 0.5) * grid.resolution  # the cube's [m]
    far = ~ndimage.binary_dilation(swept, iterations=4)
    cells = np.argwhere(far)
    centres = grid.origin + (cells + 0.5) * grid.resolution
    d = np.linalg.norm(centres - centre, axis=1)
    cell = tuple(cells[int(np.argmin(np.abs(d - 0.3)))])
    data = grid.data.copy()
    data[cell] = 1.0
    known[cell] = True
    seen = Observation(0.0, OccupancyGrid(data, grid.origin, grid.resolution, known=known))
    settings = dict(unknown="occupied", surface_margin=0.5, plan_time=0.2, known_plan_time=0.1)
    qs, c = _run(free_task, seen, 300, relax_steps=0, **settings)
    assert c.info()["plans"] >= 2 and c.info()["failed_plans"] == c.info()["plans"], c.info()
    assert np.allclose(qs[-1], qs[0])  # never left: no plan under the margin
    qs, c = _run(free_task, seen, 900, **settings)
    info = c.info()
    assert info["relaxed"] >= 1 and info["forced"] >= 1, info
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6), info
    checker = cells_checker(robot, grid, np.array([np.ravel_multi_index(cell, grid.shape)]))
    assert not any(checker.in_collision(q) for q in qs)  # never into the occupied cell


def _run_frames(task: ControlTask, frames: list[tuple[int, Observation]], ticks: int, **settings):
    """As :func:`_run`, with the frame delivered every 3 ticks the last of ``frames`` (tick, frame)
    whose tick has come."""
    return _run(task, frames, ticks, **settings)


def test_ompl_replan_safe_mode_replans_at_a_dead_end_of_hidden_cells(free_task, open_space):
    """The arm waits short of an unknown cube on its path (only the swept cells are known); then a
    frame shows an occupied cell beside the cube, off the arm's way, so every cell of the cube is
    the unseen rest of a surface (``surface_margin`` 0.25 m): after its looks the arm may not go in
    (a dead end, ``stuck``). With ``dead_end = "replan"`` it drops the path and replans instead of
    waiting there (the default); the margin is not relaxed for it, and the arm never enters the
    cube nor meets the cell."""
    grid, path = open_space
    robot = free_task.robot
    body, swept, block, known = _swept_and_cube(free_task, grid, path)
    centre = np.argwhere(~block).mean(axis=0)  # the cube's centre [cells]
    far = np.argwhere(~ndimage.binary_dilation(swept, iterations=2))
    cell = tuple(far[int(np.argmin(np.linalg.norm(far - centre, axis=1)))])  # the nearest off the arm's way
    assert np.linalg.norm(np.array(cell) - centre) * grid.resolution < 0.15
    data = grid.data.copy()
    data[cell] = 1.0
    shown = known.copy()
    shown[cell] = True
    first = _seeing(grid, known)
    later = Observation(0.0, OccupancyGrid(data, grid.origin, grid.resolution, known=shown))
    settings = dict(unknown="occupied", surface_margin=0.25, plan_time=0.3, known_plan_time=0.1, look_frames=60)
    settings.update(known_checks_per_tick=0, plan_sliced_when="never")  # every plan at once: counted as made
    frames = [(0, first), (150, later)]
    _, c = _run_frames(free_task, frames, 700, **settings)
    info = c.info()
    assert info["stuck"] >= 1 and info["relaxed"] == 0 and info["plans"] == 2, info  # waits: no new plan
    qs, c = _run_frames(free_task, frames, 700, dead_end="replan", **settings)
    info = c.info()
    assert info["stuck"] >= 1 and info["relaxed"] == 0, info
    assert info["plans"] >= 3, info  # its first plan and the one in known space, then replanned
    cube = ~block
    assert not any(body.in_unknown(q, ~cube) for q in qs[60:]), info  # never in the cube
    checker = cells_checker(robot, grid, np.array([np.ravel_multi_index(cell, grid.shape)]))
    assert not any(checker.in_collision(q) for q in qs)  # never into the occupied cell


def test_ompl_replan_slices_its_plan_in_known_space_only_while_standing_still_may_not_be_safe(free_task, open_space):
    """``known_sliced_when = "threat"``: with one frame (no motion can be told from it), or with an
    obstacle that came in between two frames 0.25-0.3 m from the arm, the plan in known space round
    an unknown cube runs in slices while the arm moves; with two frames and nothing that moved it
    is made at once, the arm held still. Either way the arm never enters the cube."""
    grid, path = open_space
    body = ArmBody(free_task.robot, grid.origin, grid.shape, grid.resolution)
    known = _block_on_path(free_task, grid, path, body)
    settings = dict(unknown="occupied", known_checks_per_tick=50, known_sliced_when="threat", plan_sliced_when="never")
    seen = _seeing(grid, known)

    qs, c = _run(free_task, seen, 300, **settings)  # one frame at the first plan
    info = c.info()
    assert info["known_slices"] > 1 and info["known_calm"] == 0, info
    assert not any(body.in_unknown(q, known) for q in qs), info

    qs, c = _run(free_task, seen, 300, before=seen, **settings)  # two frames, nothing moved
    info = c.info()
    assert info["known_calm"] >= 1 and info["known_slices"] == 0 and info["known_plans"] >= 1, info
    assert not any(body.in_unknown(q, known) for q in qs), info

    centres = grid.origin + (np.indices(grid.shape).reshape(3, -1).T + 0.5) * grid.resolution
    samples = ArmSamples(free_task.robot)
    near_start = cKDTree(samples.at(path[0])).query(centres)[0]
    near_goal = cKDTree(samples.at(path[-1])).query(centres)[0]
    spot = np.flatnonzero((near_start > 0.25) & (near_start < 0.3) & (near_goal > 0.25) & known.reshape(-1))[0]
    ijk = np.unravel_index(spot, grid.shape)
    data = np.zeros(grid.shape)
    data[tuple(slice(i - 1, i + 2) for i in ijk)] = 1.0  # a 3-cell cube, seen, where the first frame saw free space
    came = Observation(0.0, OccupancyGrid(data, grid.origin, grid.resolution, known=known))
    qs, c = _run(free_task, came, 300, before=seen, **settings)
    info = c.info()
    assert info["known_threat_slices"] >= 1 and info["known_calm"] == 0 and info["known_slices"] > 1, info
    assert not any(body.in_unknown(q, known) for q in qs), info


def _came_in(task: ControlTask, grid: OccupancyGrid, path: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """A 3-cell cube of occupied cells whose centre lies ``lo``-``hi`` m from the arm's body at the
    start and more than 0.25 m from it at the goal (the grid's data)."""
    centres = grid.origin + (np.indices(grid.shape).reshape(3, -1).T + 0.5) * grid.resolution
    samples = ArmSamples(task.robot)
    near_start = cKDTree(samples.at(path[0])).query(centres)[0]
    near_goal = cKDTree(samples.at(path[-1])).query(centres)[0]
    spot = np.flatnonzero((near_start > lo) & (near_start < hi) & (near_goal > 0.25))[0]
    data = np.zeros(grid.shape)
    data[tuple(slice(i - 1, i + 2) for i in np.unravel_index(spot, grid.shape))] = 1.0
    return data


def test_ompl_replan_slices_its_plan_to_the_goal_only_while_standing_still_may_not_be_safe(free_task, open_space):
    """``plan_sliced_when = "threat"``: with one frame, or with a cube that came in between two
    frames 0.25-0.3 m from the arm, the plan to the goal runs in slices, the arm standing until it
    has a path; with two frames and nothing that moved it is made at once. The arm reaches the
    goal each time, and its path starts where it stood."""
    grid, path = open_space
    every = np.ones(grid.shape, dtype=bool)
    seen = Observation(0.0, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=every))
    settings = dict(known_checks_per_tick=20, plan_sliced_when="threat")

    qs, c = _run(free_task, seen, 600, **settings)  # one frame at the plan
    info = c.info()
    assert info["sliced_plans"] == 1 and info["plan_slices"] > 1 and info["plans"] == 1, info
    assert np.allclose(qs[1], qs[0]) and np.allclose(qs[-1], free_task.goal.q, atol=1e-6), info

    qs, c = _run(free_task, seen, 600, before=seen, **settings)  # two frames, nothing moved
    info = c.info()
    assert info["plan_calm"] >= 1 and info["sliced_plans"] == 0 and info["plan_slices"] == 0, info
    assert np.allclose(qs[-1], free_task.goal.q, atol=1e-6), info

    data = _came_in(free_task, grid, path, 0.25, 0.3)
    came = Observation(0.0, OccupancyGrid(data, grid.origin, grid.resolution, known=every))
    qs, c = _run(free_task, came, 900, before=seen, **settings)
    info = c.info()
    assert info["plan_threat_slices"] >= 1 and info["plan_calm"] == 0 and info["plan_slices"] > 1, info
    assert info["evasions"] == 0 and np.allclose(qs[1], qs[0]), info  # farther than evade_distance: it waits
    checker = cells_checker(free_task.robot, grid, np.flatnonzero(data > 0.5))
    assert not any(checker.in_collision(q) for q in qs)


def test_ompl_replan_retreat_drops_its_plan_in_slices(free_task, open_space):
    """A cube comes in 0.08-0.12 m from the standing arm while its plan to the goal runs in slices
    (5 checks a tick): the arm retreats at once, from where it stood, and plans again afterwards;
    the dropped plan gave it no path."""
    grid, path = open_space
    every = np.ones(grid.shape, dtype=bool)
    seen = Observation(0.0, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=every))
    data = _came_in(free_task, grid, path, 0.08, 0.12)
    came = Observation(0.0, OccupancyGrid(data, grid.origin, grid.resolution, known=every))
    settings = dict(known_checks_per_tick=5, plan_sliced_when="threat")
    qs, c = _run(free_task, [(0, seen), (6, came)], 300, **settings)
    info = c.info()
    assert info["evasions"] >= 1 and info["sliced_plans"] >= 2, info  # the dropped plan, one after the retreat
    moved = int(np.argmax(np.any(np.abs(qs - qs[0]) > 1e-9, axis=1)))
    assert 6 <= moved <= 8, moved  # stood through the slices, left on the frame that showed the cube
    cube = grid.origin + (np.argwhere(data > 0.5) + 0.5) * grid.resolution
    samples = ArmSamples(free_task.robot)
    gap = [cKDTree(cube).query(samples.at(q))[0].min() for q in (qs[0], qs[moved + 5])]
    assert gap[1] > gap[0], gap  # the first motion is away from the cube, not along a path to the goal
    checker = cells_checker(free_task.robot, grid, np.flatnonzero(data > 0.5))
    assert not any(checker.in_collision(q) for q in qs)


def _cube_frames(grid: OccupancyGrid, centre: np.ndarray, step: np.ndarray, n: int, rate: float = 30.0):
    """``n`` frames at ``rate`` [Hz] of a 3-cell cube whose centre [cells] moves by ``step`` [cells]
    a frame (rounded to whole cells), every cell seen."""
    every = np.ones(grid.shape, dtype=bool)
    frames = []
    for k in range(n):
        i = np.round(centre + k * step).astype(int)
        data = np.zeros(grid.shape)
        data[tuple(slice(j - 1, j + 2) for j in i)] = 1.0
        frames.append(Observation(k / rate, OccupancyGrid(data, grid.origin, grid.resolution, known=every), frame=k))
    return frames


@pytest.mark.parametrize(
    ("speed", "sign", "lo", "hi", "contact_slices"),
    [(0.1, -1.0, 0.44, 0.49, False), (1.2, 1.0, 0.55, 0.6, True)],
    ids=["slow-and-near", "fast-and-far"],
)
def test_ompl_replan_contact_rule_reads_the_tracked_speed(free_task, open_space, speed, sign, lo, hi, contact_slices):
    """``plan_sliced_when = "contact"``: after frames of a cube moving at ``speed`` [m/s] (tracked,
    its velocity trusted), ``lo``-``hi`` m from the standing arm, the plan to the goal runs in
    slices only when the cube covers that distance while a plan made at once would hold the arm
    (``hold_time`` 1.5 s, plus ``evade_distance`` 0.15 m). The slow cube comes straight at the arm
    and the fast one goes straight away (``sign``), since only the speed counts, and either way the
    cells the fixed rule reads (the moving face, what the track sweeps) are no nearer than the
    cube. The fixed ``"threat"`` rule (0.5 m) decides the other way in
    both cases: a slow cube near the arm, a fast one beyond 0.5 m."""
    grid, path = open_space
    samples = ArmSamples(free_task.robot)
    centres = grid.origin + (np.indices(grid.shape).reshape(3, -1).T + 0.5) * grid.resolution
    tree = cKDTree(samples.at(path[0]))
    distance = tree.query(centres)[0]
    cells_per_frame = speed / 30.0 / grid.resolution
    n = max(6, int(np.ceil(3 / cells_per_frame)) + 3)  # 4 frames of a track at least, 3 cells moved
    travel = (n - 1) * cells_per_frame * grid.resolution
    for spot in np.flatnonzero((distance > lo - sign * travel - 0.05) & (distance < hi - sign * travel + 0.05))[::37]:
        away = centres[spot] - samples.at(path[0])[int(tree.query(centres[spot])[1])]
        step = sign * away / np.linalg.norm(away) * cells_per_frame
        start = np.array(np.unravel_index(spot, grid.shape), dtype=float)
        end = np.round(start + step * (n - 1)).astype(int)
        if np.any(np.round(start) < 2) or np.any(end < 2) or np.any(end > np.array(grid.shape) - 3):
            continue
        cube = np.argwhere(np.ones((3, 3, 3))) - 1 + end
        if lo <= tree.query(grid.origin + (cube + 0.5) * grid.resolution)[0].min() <= hi:
            break
    else:
        raise AssertionError("no place for the cube")
    for rule, sliced in (("contact", contact_slices), ("threat", not contact_slices)):
        c = make_controller("ompl-replan", known_checks_per_tick=20, plan_sliced_when=rule)
        c.setup(free_task)
        c.reset(np.array(free_task.start, dtype=float), np.random.default_rng(0))
        for frame in _cube_frames(grid, start, step, n):
            c.update(frame)
        speeds = [float(np.linalg.norm(tr.velocity)) for tr in c.tracks if tr.velocity is not None]
        assert len(speeds) == 1, [tr.velocity for tr in c.tracks]
        reach = (
            speeds[0] * c.config.hold_time + c.config.evade_distance
        )  # what the rule reads, on the side of the cube's distance it should be
        assert reach > hi if contact_slices else reach < lo, speeds
        c.step(0.0, np.array(free_task.start, dtype=float), None, free_task.goal)
        info = c.info()
        assert info["plan_threat_slices" if sliced else "plan_calm"] == 1, (rule, info)
        assert info["sliced_plans"] == int(sliced), (rule, info)
