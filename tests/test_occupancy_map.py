"""The map over time: depth frames fused with OctoMap's sensor model (log-odds, clamping, ray
clearing), so that what the cameras stop seeing is remembered and what leaves is cleared."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import box
from planbench.errors import ScenarioFileError
from planbench.geometry.occupancy_map import MapSettings, OccupancyMap
from planbench.reactive.scenario import CameraSettings, Scenario, SensingSettings
from planbench.reactive.sensing import Sensor
from planbench.scene import Scene

RES = 0.02
ARM_CAMERA = CameraSettings(position=(1.2, 0.4, 0.9), look_at=(0.3, 0.0, 0.3))
Q_ARM = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])  # the arm over the table, in view
Q_AWAY = np.array([2.5, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])  # turned away, behind its base
TABLE = Scene((box("table", (0.4, 0.0, -0.02), (1.6, 1.6, 0.04)),))


def depth(memory, **camera):
    return SensingSettings(model="depth", resolution=RES, memory=memory, cameras=(replace(ARM_CAMERA, **camera),))


def capture(sensor, scene, q, k):
    return sensor.capture(scene, q, k / 30, k, np.random.default_rng(k)).grid


def state(grid, flat):
    """Each cell's state: 0 unknown, 1 free, 2 occupied."""
    known, occupied = grid.known.reshape(-1)[flat], grid.data.reshape(-1)[flat] > 0
    return np.where(~known, 0, np.where(occupied, 2, 1))


# --- the update -----------------------------------------------------------------------------------
def one_cell_map(settings=None):
    return OccupancyMap(np.zeros(3), (1, 1, 2), 1.0, settings)


def hit(m, cell=0):
    m.integrate(np.zeros(m.shape, dtype=bool), np.array([cell]))


def miss(m, cell=0):
    seen = np.zeros(m.shape, dtype=bool)
    seen.reshape(-1)[cell] = True
    m.integrate(seen, np.zeros(0, dtype=np.int64))


def test_a_cell_is_unknown_until_a_frame_says_something_of_it():
    m = one_cell_map()
    assert not m.known.any() and not m.occupied().any()
    hit(m)
    assert m.known.reshape(-1).tolist() == [True, False] and m.occupied().reshape(-1).tolist() == [True, False]
    miss(m, 1)
    assert m.known.all() and m.occupied().reshape(-1).tolist() == [True, False]


def test_a_cell_hit_and_seen_free_in_one_frame_counts_as_a_hit():
    m = one_cell_map()
    m.integrate(np.ones(m.shape, dtype=bool), np.array([0]))
    assert m.log_odds.reshape(-1)[0] == pytest.approx(np.log(MapSettings().hit / (1 - MapSettings().hit)))
    assert m.log_odds.reshape(-1)[1] == pytest.approx(np.log(0.4 / 0.6))


@pytest.mark.parametrize("settings", [MapSettings(), MapSettings(hit=0.9, miss=0.2, clamp_max=0.9)])
def test_clamping_bounds_the_frames_a_long_occupied_cell_takes_to_clear(settings):
    m = one_cell_map(settings)
    for _ in range(200):  # an obstacle that sat still for seconds
        hit(m)
    n = settings.frames_to_clear()
    for k in range(n):
        assert m.occupied().reshape(-1)[0], k
        miss(m)
    assert not m.occupied().reshape(-1)[0]  # cleared after exactly n frames of misses
    for _ in range(200):
        miss(m)
    for k in range(settings.frames_to_occupy()):
        assert not m.occupied().reshape(-1)[0], k
        hit(m)
    assert m.occupied().reshape(-1)[0]


def test_marking_known_without_evidence_changes_no_occupancy():
    m = one_cell_map()
    hit(m)
    m.integrate(np.zeros(m.shape, dtype=bool), np.zeros(0, dtype=np.int64), known=np.ones(m.shape, dtype=bool))
    assert m.known.all() and m.occupied().reshape(-1).tolist() == [True, False]


@pytest.mark.parametrize(
    "bad",
    [dict(hit=0.4), dict(miss=0.6), dict(clamp_min=0.6), dict(clamp_max=0.3), dict(hit=1.0), dict(miss=float("nan"))],
)
def test_bad_map_settings_are_named(bad):
    with pytest.raises(ValueError, match="map"):
        MapSettings(**bad)


# --- the map in the sensor ------------------------------------------------------------------------
SIDE = dict(position=(0.3, 1.2, 0.6), look_at=(0.3, 0.0, 0.5))  # a camera beside the arm


def behind_the_hand(robot):
    """A scene with a box on the side camera's line of sight through the hand, 30 cm beyond it."""
    hand = robot.frame_pose(Q_ARM).translation
    ray = hand - np.array(SIDE["position"])
    return Scene(TABLE.obstacles + (box("hidden", hand + 0.3 * ray / np.linalg.norm(ray), (0.1, 0.1, 0.1)),))


def cells_the_arm_hides(panda, scene):
    """Occupied cells seen with the arm turned away and hidden by the arm over the table."""
    open_view = capture(Sensor(depth("frame", **SIDE), panda), scene, Q_AWAY, 0)
    hidden_view = capture(Sensor(depth("frame", **SIDE), panda), scene, Q_ARM, 0)
    cells = np.flatnonzero((open_view.data > 0).reshape(-1) & ~hidden_view.known.reshape(-1))
    assert len(cells) > 10  # the arm's shadow on the box
    return cells


def test_a_static_obstacle_hidden_behind_the_arm_is_remembered_by_the_map_not_by_a_frame(panda):
    scene = behind_the_hand(panda)
    shadow = cells_the_arm_hides(panda, scene)
    for memory, expected in (("map", 2), ("frame", 0)):
        sensor = Sensor(depth(memory, **SIDE), panda)
        capture(sensor, scene, Q_AWAY, 0)
        grid = capture(sensor, scene, Q_ARM, 1)
        assert np.all(state(grid, shadow) == expected), memory


def test_a_moving_obstacle_leaves_the_map_as_its_cells_are_seen_free_again(panda):
    sensor = Sensor(depth("map"), panda)
    ball = box("ball", (0.6, -0.3, 0.25), (0.1, 0.1, 0.1))
    for k in range(20):  # in view for 20 frames: its front cells reach the clamp
        grid = capture(sensor, Scene(TABLE.obstacles + (ball,)), Q_AWAY, k)
    was = np.flatnonzero((grid.data > 0).reshape(-1) & (grid.cell_centers()[..., 2] > 0.1).reshape(-1))
    assert len(was) > 10
    n = MapSettings().frames_to_clear()
    for k in range(20, 20 + n - 1):  # it has gone: one frame short of clearing, it is still there
        grid = capture(sensor, TABLE, Q_AWAY, k)
    assert np.any(state(grid, was) == 2)
    grid = capture(sensor, TABLE, Q_AWAY, 20 + n)
    assert np.all(state(grid, was) == 1)  # every cell it left is seen free again


def test_the_map_and_a_frame_agree_on_the_first_frame_but_for_nothing(panda):
    scene = Scene(TABLE.obstacles + (box("b", (0.6, -0.3, 0.25), (0.1, 0.1, 0.1)),))
    one = capture(Sensor(depth("map"), panda), scene, Q_ARM, 0)
    other = capture(Sensor(depth("frame"), panda), scene, Q_ARM, 0)
    assert np.array_equal(one.known, other.known) and np.array_equal(one.data, other.data)


# --- settings ---------------------------------------------------------------------------------------
def test_depth_remembers_by_default_and_truth_has_no_map():
    assert SensingSettings(model="depth").memory == "map" and SensingSettings().memory == "frame"
    with pytest.raises(ValueError, match="memory 'map' applies to depth"):
        SensingSettings(model="truth", memory="map")
    with pytest.raises(ValueError, match="memory must be one of"):
        SensingSettings(model="depth", memory="forever")


def test_the_map_settings_go_through_json(free_problem):
    sensing = SensingSettings(model="depth", map=MapSettings(hit=0.8, miss=0.3))
    d = {"problem": free_problem.to_dict(), "sensing": sensing.to_dict()}
    assert Scenario.from_dict(d).sensing == sensing
    d["sensing"]["map"]["hot"] = 0.5
    with pytest.raises(ScenarioFileError, match="sensing map: unknown keys"):
        Scenario.from_dict(d)
    d["sensing"]["map"] = {"hit": 0.3}
    with pytest.raises(ScenarioFileError, match="map hit must be > 0.5"):
        Scenario.from_dict(d)


def test_the_compiled_and_the_numpy_update_agree_cell_for_cell():
    pytest.importorskip("numba")
    rng = np.random.default_rng(0)
    maps = [OccupancyMap(np.zeros(3), (20, 30, 40), 0.02, backend=b) for b in ("numba", "numpy")]
    for _ in range(12):  # random frames, enough to reach both clamps
        seen = rng.random(maps[0].shape) < 0.6
        hits = np.unique(rng.integers(0, seen.size, 3000))
        body = rng.random(maps[0].shape) < 0.05
        for m in maps:
            m.integrate(seen.copy(), hits, known=body)
    (a, b) = maps
    assert np.array_equal(a.log_odds, b.log_odds) and np.array_equal(a.known, b.known)
    assert np.array_equal(a.grid().data, b.grid().data) and a.occupied().any() and not a.occupied().all()
