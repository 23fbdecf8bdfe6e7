import numpy as np
import pytest

from conftest import box
from planbench import Obstacle, OccupancyGrid, Scene

BOUNDS = (np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0]))


def test_cell_centres_and_axis_order():
    grid = OccupancyGrid.empty([0.0, -1.0, 2.0], [0.4, -0.8, 2.1], 0.1)
    assert grid.shape == (4, 2, 1)
    np.testing.assert_allclose(grid.cell_centers()[3, 1, 0], [0.35, -0.85, 2.05])


def test_aligned_box_covers_exactly_its_cells_with_every_rule():
    # box spanning x in [0.2, 0.5], y in [0.3, 0.4], z in [0.0, 0.7]: whole cells at 0.1 m
    scene = Scene((box("b", (0.35, 0.35, 0.35), (0.3, 0.1, 0.7)),))
    for rule in ("any", "center", "fraction"):
        grid = OccupancyGrid.from_scene(scene, 0.1, bounds=BOUNDS, rule=rule)
        expected = np.zeros((10, 10, 10))
        expected[2:5, 3:4, 0:7] = 1.0
        np.testing.assert_array_equal(grid.data, expected, err_msg=rule)


def test_partly_covered_cells_follow_the_rule():
    # a box covering 30 % of cell x=2 (x in [0.2, 0.23]) and all of cell x=1
    scene = Scene((box("b", (0.165, 0.55, 0.55), (0.13, 0.1, 0.1)),))
    any_ = OccupancyGrid.from_scene(scene, 0.1, bounds=BOUNDS, rule="any", subsamples=10)
    center = OccupancyGrid.from_scene(scene, 0.1, bounds=BOUNDS, rule="center")
    fraction = OccupancyGrid.from_scene(scene, 0.1, bounds=BOUNDS, rule="fraction", subsamples=10)
    assert any_.data[2, 5, 5] == 1.0 and center.data[2, 5, 5] == 0.0
    assert fraction.data[2, 5, 5] == pytest.approx(0.3)
    assert any_.data[1, 5, 5] == center.data[1, 5, 5] == fraction.data[1, 5, 5] == 1.0
    assert any_.data.sum() == 2 and center.data.sum() == 1


def test_fraction_rule_measures_volume_of_rotated_and_round_obstacles():
    quat = (0.0, 0.0, np.sin(0.3), np.cos(0.3))
    scene = Scene(
        (
            box("b", (0.5, 0.5, 0.5), (0.3, 0.2, 0.1), orientation_xyzw=quat),
            Obstacle("s", "sphere", position=(0.2, 0.2, 0.2), radius=0.1),
            Obstacle("c", "cylinder", position=(0.8, 0.2, 0.5), radius=0.05, length=0.4),
        )
    )
    grid = OccupancyGrid.from_scene(scene, 0.02, bounds=BOUNDS, rule="fraction", subsamples=6)
    volume = 0.3 * 0.2 * 0.1 + 4 / 3 * np.pi * 0.1**3 + np.pi * 0.05**2 * 0.4
    assert grid.data.sum() * 0.02**3 == pytest.approx(volume, rel=0.01)
    any_ = OccupancyGrid.from_scene(scene, 0.02, bounds=BOUNDS, rule="any")
    assert np.all(any_.data >= (grid.data > 0))  # "any" never misses a covered cell


def test_default_bounds_hold_the_scene_with_padding():
    scene = Scene((box("b", (0.35, 0.35, 0.35), (0.3, 0.1, 0.7)),))
    grid = OccupancyGrid.from_scene(scene, 0.05, padding=0.1)
    np.testing.assert_allclose(grid.origin, [0.1, 0.2, -0.1])
    assert grid.data.sum() * 0.05**3 == pytest.approx(0.3 * 0.1 * 0.7)


def test_point_cloud_grid():
    pts = np.array([[0.05, 0.05, 0.05], [0.06, 0.04, 0.05], [0.55, 0.05, 0.95], [5, 5, 5], [np.nan, 0, 0]])
    grid = OccupancyGrid.from_points(pts, 0.1, bounds=BOUNDS)
    assert grid.data[0, 0, 0] == 1 and grid.data[5, 0, 9] == 1 and grid.data.sum() == 2
    two = OccupancyGrid.from_points(pts, 0.1, bounds=BOUNDS, min_points=2)
    assert two.data.sum() == 1
    np.testing.assert_array_equal(grid.occupancy_at(np.array([[0.01, 0.01, 0.01], [-1, 0, 0]])), [1, 0])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(data=np.zeros((2, 2))), "3D"),
        (dict(data=np.full((2, 2, 2), 1.5)), r"\[0, 1\]"),
        (dict(data=np.zeros((2, 2, 2)), resolution=0.0), "resolution"),
        (dict(data=np.zeros((2, 2, 2)), outside=2.0), "outside"),
    ],
)
def test_bad_grids_are_refused(kwargs, message):
    args = dict(origin=np.zeros(3), resolution=0.1) | kwargs
    with pytest.raises(ValueError, match=message):
        OccupancyGrid(**args)


def test_bad_point_cloud_shape():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        OccupancyGrid.from_points(np.zeros((4, 2)), 0.1)


def test_any_rule_for_a_rotated_box_matches_coal_cell_by_cell():
    import coal

    quat = (0.1, 0.2, 0.3, 0.9)
    quat = tuple(np.array(quat) / np.linalg.norm(quat))
    obstacle = box("b", (0.51, 0.48, 0.5), (0.4, 0.25, 0.03), orientation_xyzw=quat)
    grid = OccupancyGrid.from_scene(Scene((obstacle,)), 0.05, bounds=BOUNDS, rule="any")
    shape = obstacle.collision_geometry()
    tf = coal.Transform3s(obstacle.rotation, np.array(obstacle.position))
    cell = coal.Box(0.05, 0.05, 0.05)
    expected = np.zeros(grid.shape)
    centres = grid.cell_centers()
    for idx in np.ndindex(*grid.shape):
        centre = centres[idx]
        result = coal.CollisionResult()
        request = coal.CollisionRequest()
        expected[idx] = coal.collide(cell, coal.Transform3s(np.eye(3), centre), shape, tf, request, result)
    assert expected.sum() > 50
    np.testing.assert_array_equal(grid.data, expected)


def test_mesh_obstacles_collide_and_voxelize_through_coal(panda):
    from planbench.checking.collision import CollisionChecker
    from planbench.robot import example_robot_data_dir

    stl = example_robot_data_dir() / "robots" / "panda_description" / "meshes" / "collision" / "link0.stl"
    mesh = Obstacle("base-copy", "mesh", position=(0.5, 0.0, 0.3), path=str(stl))
    scene = Scene((mesh,))
    lo, hi = mesh.aabb()
    assert np.all(hi - lo > 0.05) and np.all(hi - lo < 0.5)
    grid = OccupancyGrid.from_scene(scene, 0.02, padding=0.02)
    assert 0 < grid.data.sum() < grid.data.size
    checker = CollisionChecker(panda, scene)
    assert not checker.in_collision(panda.home)
    assert 0.0 < checker.clearance(panda.home) < 1.0


@pytest.mark.parametrize("cells", [0, 1, 2, 3])
def test_grow_cells_is_a_cube_dilation_that_does_not_wrap(cells):
    """The same cells as scipy's dilation by a cube of side 2 cells + 1; a cell on a face grows
    inward only."""
    from scipy import ndimage

    from planbench.geometry.occupancy import grow_cells

    rng = np.random.default_rng(cells)
    mask = rng.random((9, 11, 7)) < 0.02
    mask[0, 5, 3] = True  # on a face
    cube = np.ones((2 * cells + 1,) * 3, dtype=bool)
    expected = ndimage.binary_dilation(mask, structure=cube) if cells else mask
    grown = grow_cells(mask, cells)
    assert grown.dtype == bool and np.array_equal(grown, expected)
    assert not np.shares_memory(grown, mask)
    assert not grown[-1].any() or mask[-1 - cells :].any()  # nothing wrapped to the far face


def test_grow_cells_refuses_what_it_cannot_grow():
    from planbench.geometry.occupancy import grow_cells

    with pytest.raises(ValueError, match="3-D bool"):
        grow_cells(np.zeros((3, 3)), 1)
    with pytest.raises(ValueError, match=">= 0"):
        grow_cells(np.zeros((3, 3, 3), dtype=bool), -1)
