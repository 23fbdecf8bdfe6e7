"""What a pinhole camera has seen to be free (planbench.geometry.views.mark_seen): the cells whose
centre lies in its image and nearer than what their pixel saw; numba and numpy mark the same."""

from __future__ import annotations

import numpy as np
import pytest

from planbench.geometry.views import mark_seen
from planbench.reactive.scenario import CameraSettings
from planbench.reactive.sensing import camera_frame
from planbench.runtime.backend import have_numba

CAMERA = CameraSettings(position=(1.3, 0.37, 0.61), look_at=(0.05, -0.11, 0.13), width=40, height=30, fov=55.0)
LOWER, RES, SHAPE = np.array([-0.51, -0.49, -0.3]), 0.05, (24, 21, 19)


def _seen(free: np.ndarray, backend: str) -> np.ndarray:
    origin, axes, pixel = camera_frame(CAMERA)
    out = np.zeros(SHAPE, dtype=bool)
    return mark_seen(out, LOWER, RES, origin, axes, pixel, CAMERA.width, CAMERA.height, free, backend=backend)


def test_with_one_length_for_every_pixel_the_seen_cells_are_the_frustum_cut_at_that_range():
    length = 1.4
    seen = _seen(np.full(CAMERA.width * CAMERA.height, length), "numpy")
    origin, (forward, right, up), pixel = camera_frame(CAMERA)
    idx = np.indices(SHAPE).reshape(3, -1).T
    v = LOWER + (idx + 0.5) * RES - origin
    z = v @ forward
    x, y = (v @ right) / z, (v @ up) / z
    in_image = (z > 0) & (np.abs(x) < CAMERA.width / 2 * pixel) & (np.abs(y) < CAMERA.height / 2 * pixel)
    expected = (in_image & (np.linalg.norm(v, axis=1) <= length)).reshape(SHAPE)
    assert 100 < expected.sum() < expected.size - 100  # the frustum and the range both cut the grid
    np.testing.assert_array_equal(seen, expected)


def test_a_pixel_that_saw_nothing_marks_nothing_and_marks_only_add():
    assert not _seen(np.zeros(CAMERA.width * CAMERA.height), "numpy").any()
    out = np.ones(SHAPE, dtype=bool)
    origin, axes, pixel = camera_frame(CAMERA)
    mark_seen(out, LOWER, RES, origin, axes, pixel, CAMERA.width, CAMERA.height, np.zeros(1200), backend="numpy")
    assert out.all()


@pytest.mark.skipif(not have_numba(), reason="numba not installed")
def test_numba_and_numpy_mark_the_same_cells():
    free = np.random.default_rng(4).uniform(0.0, 2.0, CAMERA.width * CAMERA.height)
    free[::7] = 0.0
    a, b = _seen(free, "numba"), _seen(free, "numpy")
    assert a.any() and not a.all()
    np.testing.assert_array_equal(a, b)


def test_bad_arguments_are_named():
    origin, axes, pixel = camera_frame(CAMERA)
    with pytest.raises(ValueError, match="one length per pixel"):
        mark_seen(np.zeros(SHAPE, bool), LOWER, RES, origin, axes, pixel, 40, 30, np.zeros(5))
    with pytest.raises(ValueError, match="3D bool array"):
        mark_seen(np.zeros(SHAPE), LOWER, RES, origin, axes, pixel, 40, 30, np.zeros(1200))
