"""Obstacle motion predicted from frames (:mod:`planbench_plugins.controllers.prediction`): a moving
box's velocity within a tolerance, a static box and lone noisy points predict nothing, a vanished
track is dropped, a box split in two stays one track; bad settings are named errors; with
``prediction = "swept"`` a field controller's command changes before the box is within the field's
reach, and without it does not. Frames are built by hand: points on a box's surface, their cells
occupied, every cell known."""

from __future__ import annotations

import numpy as np
import pytest

from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.conformance import conformance_task
from planbench.reactive.controller import Observation
from planbench.registry import make_controller
from planbench_plugins.controllers.prediction import MotionPredictor, PredictionSettings, predicted_grid

RATE = 30.0  # [Hz] frames
RES = 0.02  # [m]
GRID = OccupancyGrid.empty(np.array([-0.6, -0.6, 0.0]), np.array([0.6, 0.6, 0.8]), RES)


def box_points(centre: np.ndarray, half: float = 0.05, spacing: float = 0.005) -> np.ndarray:
    """Points [m] on the surface of the cube of half side ``half`` around ``centre``."""
    u = np.arange(-half, half + 1e-9, spacing)
    a, b = np.meshgrid(u, u, indexing="ij")
    a, b = a.ravel(), b.ravel()
    faces = []
    for axis in range(3):
        for side in (-half, half):
            p = np.zeros((len(a), 3))
            p[:, axis] = side
            p[:, (axis + 1) % 3], p[:, (axis + 2) % 3] = a, b
            faces.append(p)
    return np.vstack(faces) + centre


def frame(points: np.ndarray, t: float, k: int, grid: OccupancyGrid = GRID) -> Observation:
    """An observation of ``points``: their cells occupied, every cell known (free elsewhere)."""
    data = np.zeros(grid.shape)
    idx = grid.index_of(points)
    ok = np.all((idx >= 0) & (idx < np.array(grid.shape)), axis=1)
    data[tuple(idx[ok].T)] = 1.0
    known = np.ones(grid.shape, dtype=bool)
    return Observation(t, OccupancyGrid(data, grid.origin, grid.resolution, known=known), k, points.astype(np.float32))


def run(predictor: MotionPredictor, centres, extra=None):
    """Observe a box at each of ``centres`` (one frame each at 30 Hz); the last prediction."""
    out = None
    for k, c in enumerate(centres):
        pts = box_points(np.asarray(c, dtype=float))
        if extra is not None:
            pts = extra(k, pts)
        out = predictor.observe(frame(pts, k / RATE, k))
    return out


def moving(tracks):
    return [t for t in tracks if t.velocity is not None]


@pytest.mark.parametrize("velocity", [(0.5, 0.0, 0.0), (0.0, -1.0, 0.0), (0.3, 0.3, -0.2)])
def test_a_moving_box_gets_its_velocity_and_a_sweep_ahead_of_it(velocity):
    v = np.array(velocity)
    start = np.array([-0.2, 0.5, 0.4]) if v[1] < 0 else np.array([-0.4, -0.2, 0.5])
    centres = [start + v * k / RATE for k in range(24)]
    p = run(MotionPredictor(PredictionSettings(prediction="swept", prediction_horizon=0.3)), centres)
    assert p is not None
    tracks = moving(p.tracks)
    assert len(tracks) == 1, [(t.id, t.velocity) for t in p.tracks]
    assert np.linalg.norm(tracks[0].velocity - v) < 0.15 * np.linalg.norm(v) + 0.03  # [m/s]
    swept = GRID.origin + (np.column_stack(np.unravel_index(p.cells, GRID.shape)) + 0.5) * RES
    ahead = (swept - centres[-1]) @ (v / np.linalg.norm(v))
    assert ahead.max() > 0.3 * np.linalg.norm(v) - 0.02  # the sweep reaches where the box will be
    assert ahead.min() > -0.1  # and nothing behind the box


def test_a_static_box_predicts_nothing():
    p = run(MotionPredictor(PredictionSettings(prediction="swept")), [np.array([0.1, 0.0, 0.3])] * 20)
    assert p is not None and not len(p.cells) and not p.tracks and p.moving_cells == 0


def test_lone_noisy_points_predict_nothing():
    rng = np.random.default_rng(3)
    static = np.array([0.1, 0.0, 0.3])

    def noise(k, pts):  # three stray points a frame, anywhere in the grid
        return np.vstack([pts, rng.uniform(GRID.origin + 0.05, GRID.upper - 0.05, size=(3, 3))])

    p = run(MotionPredictor(PredictionSettings(prediction="swept")), [static] * 30, extra=noise)
    assert p is not None and not len(p.cells) and not moving(p.tracks)


def test_a_vanished_track_is_dropped():
    s = PredictionSettings(prediction="swept", prediction_track_timeout=0.15)
    predictor = MotionPredictor(s)
    v = np.array([0.6, 0.0, 0.0])
    p = run(predictor, [np.array([-0.3, 0.0, 0.3]) + v * k / RATE for k in range(12)])
    assert p is not None and len(moving(p.tracks)) == 1
    empty = np.zeros((0, 3))
    for k in range(12, 12 + 6):  # 0.2 s without it, more than the timeout
        p = predictor.observe(frame(empty, k / RATE, k))
    assert not p.tracks and not len(p.cells)


def test_a_box_split_by_an_occluder_stays_one_track():
    v = np.array([0.0, 0.5, 0.0])

    def occluded(k, pts):  # a 4 cm band through the box's middle hidden from frame 8 on
        return pts[np.abs(pts[:, 2] - 0.4) > 0.02] if k >= 8 else pts

    p = run(
        MotionPredictor(PredictionSettings(prediction="swept")),
        [np.array([0.0, -0.3, 0.4]) + v * k / RATE for k in range(16)],
        extra=occluded,
    )
    assert p is not None
    tracks = moving(p.tracks)
    assert len(tracks) == 1 and np.linalg.norm(tracks[0].velocity - v) < 0.15 * 0.5 + 0.03


def test_predicted_grid_holds_exactly_the_cells():
    cells = np.ravel_multi_index(np.array([[3, 4, 5], [6, 4, 9]]).T, GRID.shape)
    g = predicted_grid(GRID, cells)
    assert g is not None and g.shape == (4, 1, 5) and int(g.data.sum()) == 2
    assert np.allclose(g.origin, GRID.origin + np.array([3, 4, 5]) * RES)
    assert predicted_grid(GRID, np.zeros(0, dtype=np.intp)) is None


@pytest.mark.parametrize(
    "setting",
    [
        {"prediction": "ahead"},
        {"prediction_horizon": 0.0},
        {"prediction_max_speed": float("nan")},
        {"prediction_min_speed": -1.0},
        {"prediction_min_cells": 0},
        {"prediction_min_frames": 1},
        {"prediction_fit_frames": 2, "prediction_min_frames": 3},
    ],
)
@pytest.mark.parametrize("name", ["matrix-field", "matrix-field-guided"])
def test_bad_prediction_settings_are_named_errors(name, setting):
    with pytest.raises(InvalidConfigError, match=next(iter(setting))):
        make_controller(name, **setting)


@pytest.mark.parametrize("name", ["matrix-field", "matrix-field-guided"])
def test_prediction_pushes_before_the_box_is_within_the_fields_reach(name):
    """A box flies at 1 m/s straight at the arm's hand, seen for 0.4 s while its surface is at
    least 0.3 m from the hand (beyond the field's 0.15 m reach from a link's surface): without
    prediction the commands are those of free space; with it the sweep is within reach and the
    command changes."""
    task = conformance_task().task
    robot, q = task.robot, np.array(task.start, dtype=float)
    hand = robot.frame_pose(q, task.goal.pose.frame).translation.copy()
    grid = OccupancyGrid.empty(hand - 0.8, hand + 0.8, RES)
    v = np.array([0.0, -1.0, 0.0])

    def commands(mode: str, with_box: bool) -> np.ndarray:
        # guided: a check a slice, so that no plan ends within the 13 ticks (only the push is compared)
        slices = {"plan_checks_per_tick": 1} if name == "matrix-field-guided" else {}
        c = make_controller(name, prediction=mode, prediction_horizon=0.5, **slices)
        c.setup(task)
        c.reset(q.copy(), np.random.default_rng(0))
        out = []
        for k in range(13):
            pts = box_points(hand - v * (0.75 - k / RATE)) if with_box and k else np.zeros((0, 3))
            obs = frame(pts, k / RATE, k, grid)
            c.update(obs)
            out.append(c.step(k / RATE, q.copy(), obs, task.goal))
        return np.array(out)

    free = commands("none", with_box=False)
    assert np.allclose(commands("none", with_box=True), free, atol=1e-9)  # the box beyond reach
    swept = commands("swept", with_box=True)
    assert np.allclose(swept[:4], free[:4], atol=1e-9)  # no velocity yet: nothing predicted
    assert np.linalg.norm(swept[-1] - free[-1]) > 1e-3
