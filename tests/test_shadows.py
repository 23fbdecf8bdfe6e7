"""What hides an unknown cell from the cameras (planbench.reactive.shadows): the arm, an observed
surface, nothing, or no camera has it in view; and the cameras a controller is told of."""

from __future__ import annotations

import numpy as np
import pytest

import planbench
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.runner import control_task
from planbench.reactive.scenario import CameraSettings
from planbench.reactive.shadows import ARM, NOT_IN_VIEW, OPEN, SURFACE, occluders

CAMERA = CameraSettings(position=(1.0, 0.0, 0.5), look_at=(0.0, 0.0, 0.5), max_range=3.0)


def _grid() -> OccupancyGrid:
    return OccupancyGrid.empty(np.array([-0.5, -0.5, 0.0]), np.array([0.9, 0.5, 1.0]), 0.02)


def _cell(grid: OccupancyGrid, point) -> int:
    ijk = np.floor((np.asarray(point) - grid.origin) / grid.resolution).astype(int)
    return int(np.ravel_multi_index(tuple(ijk), grid.shape))


def test_a_cell_behind_a_wall_behind_the_arm_in_front_and_out_of_view():
    grid = _grid()
    # an occupied wall at x = 0.5 over y in [-0.1, 0.1]; an arm block at x = 0.5 over y in [0.2, 0.3]
    wall = (slice(*[int((v - grid.origin[0]) / 0.02) for v in (0.5, 0.52)]),)
    iy = [int((v - grid.origin[1]) / 0.02) for v in (-0.1, 0.1, 0.2, 0.3)]
    iz = [int((v - grid.origin[2]) / 0.02) for v in (0.4, 0.6)]
    grid.data[wall[0], iy[0] : iy[1], iz[0] : iz[1]] = 1.0
    arm = np.zeros(grid.shape, dtype=bool)
    arm[wall[0], iy[2] : iy[3], iz[0] : iz[1]] = True
    cells = np.array(
        [
            _cell(grid, (0.2, 0.0, 0.5)),  # behind the wall
            _cell(grid, (0.2, 0.4, 0.5)),  # behind the arm (the line from the camera crosses it at y = 0.25)
            _cell(grid, (0.7, 0.0, 0.5)),  # between the camera and the wall
            _cell(grid, (0.2, 0.0, 0.99)),  # above the image (vertical field of view 60 degrees)
        ]
    )
    assert list(occluders(cells, grid, arm, [CAMERA])) == [SURFACE, ARM, OPEN, NOT_IN_VIEW]


def test_the_arm_wins_over_a_surface_another_camera_sees():
    """A second camera that sees the cell behind a wall does not stop the arm's shadow from the first
    from being shown by moving the arm."""
    grid = _grid()
    ix = [int((v - grid.origin[0]) / 0.02) for v in (0.5, 0.52)]
    iz = [int((v - grid.origin[2]) / 0.02) for v in (0.4, 0.6)]
    arm = np.zeros(grid.shape, dtype=bool)
    arm[ix[0] : ix[1], :, iz[0] : iz[1]] = True  # the arm across the first camera's view
    other = CameraSettings(position=(0.2, 0.0, 2.0), look_at=(0.2, 0.0, 0.0), up=(1.0, 0.0, 0.0))
    iy = int((0.0 - grid.origin[1]) / 0.02)
    grid.data[ix[0] - 20 : ix[0] - 10, iy - 5 : iy + 5, int((0.8 - grid.origin[2]) / 0.02)] = 1.0  # a plate above it
    cell = np.array([_cell(grid, (0.2, 0.0, 0.5))])
    assert occluders(cell, grid, np.zeros_like(arm), [other])[0] == SURFACE
    assert occluders(cell, grid, arm, [CAMERA, other])[0] == ARM
    assert occluders(np.zeros(0, dtype=np.intp), grid, arm, [CAMERA]).shape == (0,)


def test_a_controller_is_told_its_depth_cameras_and_none_with_truth():
    depth = planbench.load_scenarios("dynamic:panda_crossing_fast_depth/0001")[0]
    truth = planbench.load_scenarios("dynamic:panda_crossing_fast_truth/0001")[0]
    task = control_task(depth)
    assert task.cameras == tuple(depth.sensing.cameras) and len(task.cameras) >= 1
    assert task.robot_margin == depth.sensing.robot_margin
    assert control_task(truth).cameras == () and control_task(truth).robot_margin == 0.0


def test_the_compiled_walk_and_numpy_agree():
    pytest.importorskip("numba")
    rng = np.random.default_rng(3)
    grid = _grid()
    grid.data[...] = rng.random(grid.shape) < 0.01
    arm = rng.random(grid.shape) < 0.01
    cells = rng.choice(grid.data.size, 3000, replace=False)
    other = CameraSettings(position=(0.2, 0.4, 1.5), look_at=(0.2, 0.0, 0.3))
    a = occluders(cells, grid, arm, [CAMERA, other], backend="numba")
    b = occluders(cells, grid, arm, [CAMERA, other], backend="numpy")
    assert np.array_equal(a, b)
    assert len(set(a.tolist())) == 4  # every answer occurs
