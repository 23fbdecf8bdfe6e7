"""The calibrated field (docs/method.md, section 8): a distance in metres from separable Gaussian
kernels, its gradient, its evaluation modes, and the planner and controller that push with it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

import planbench
from planbench import Obstacle, Problem, Scene
from planbench.errors import InvalidConfigError, ResourceLimitError
from planbench.field.calibrated import CalibratedSpec, calibrated_at, calibrated_full
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.conformance import check_controller
from planbench.registry import make_controller
from planbench.robot import load_robot
from planbench_plugins.controllers.matrix_field import GridField, MatrixFieldController
from planbench_plugins.matrix_field import MatrixFieldConfig, MatrixFieldPlanner
from planbench_plugins.matrix_field.calibrated import CalibratedRepulsion

SIDE = 0.6  # the test grids are cubes of SIDE [m] from the origin


def box_grid(resolution: float, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> OccupancyGrid:
    """A grid of SIDE^3 with the box lo..hi [m] occupied; its faces lie on cell faces at 0.02 and 0.01 m."""
    n = int(round(SIDE / resolution))
    data = np.zeros((n, n, n))
    a = np.rint(np.array(lo) / resolution).astype(int)
    b = np.rint(np.array(hi) / resolution).astype(int)
    data[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = 1.0
    return OccupancyGrid(data, np.zeros(3), resolution)


def exact_box_distance(points: np.ndarray, lo: tuple, hi: tuple) -> np.ndarray:
    gap = np.maximum(np.maximum(np.array(lo) - points, points - np.array(hi)), 0.0)
    return np.linalg.norm(gap, axis=1)


WALL = ((0.30, 0.0, 0.0), (0.40, SIDE, SIDE))  # a 10 cm slab across the whole grid, face at x = 0.3
BLOCK = ((0.24, 0.24, 0.24), (0.36, 0.36, 0.36))  # a 12 cm cube in the middle


def test_a_flat_face_gives_its_distance_within_a_fraction_of_a_cell():
    r = 0.02
    grid = box_grid(r, *WALL)
    kernel = CalibratedSpec().build(r)
    d_face = np.array([0.0, 0.01, 0.03, 0.05, 0.1, 0.14])
    pts = np.column_stack([0.3 - d_face, np.full(6, 0.31), np.full(6, 0.29)])
    d, grad = calibrated_at(grid, kernel, pts)
    assert np.all(np.abs(d - d_face) < 0.25 * r)
    assert np.all(grad[:, 0] < 0) and np.allclose(grad[:, 1:], 0.0, atol=1e-9)  # away from the face: -x
    assert np.allclose(np.linalg.norm(grad, axis=1), 1.0, atol=0.06)  # a distance: unit slope
    inside, _ = calibrated_at(grid, kernel, np.array([[0.32, 0.3, 0.3]]))
    assert inside[0] < 0  # signed: negative in the obstacle


def test_the_distance_matches_the_exact_distance_transform_within_a_cell():
    """Every free cell centre within the reach of a block: against scipy's EDT to the cells' faces."""
    r = 0.02
    grid = box_grid(r, *BLOCK)
    occupied = grid.data > 0
    edt = distance_transform_edt(~occupied, sampling=r) - 0.5 * r  # centre -> face
    field = calibrated_full(grid, CalibratedSpec().build(r))
    d = 0.15 + field.deficit.components[0]
    near = ~occupied & (edt <= 0.14)
    err = d[near] - edt[near]
    assert np.abs(err).max() < 1.0 * r  # worst at the block's corners (1.15 sigma at contact)
    assert np.median(np.abs(err)) < 0.5 * r


def test_a_single_cell_is_seen_within_about_a_cell():
    """An obstacle smaller than sigma holds less mass than a face: its distance comes out longer,
    by about a cell at 2 cm (docs/method.md, section 8), never shorter."""
    r = 0.02
    grid = box_grid(r, (0.30, 0.30, 0.30), (0.32, 0.32, 0.32))
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    pts = 0.31 + dirs * 0.08
    exact = exact_box_distance(pts, (0.30,) * 3, (0.32,) * 3)
    d, grad = calibrated_at(grid, CalibratedSpec().build(r), pts)
    assert np.all(d > exact) and np.all(d - exact < 1.3 * r)
    assert np.all(np.einsum("ij,ij->i", grad, pts - 0.31) > 0)  # the gradient points away


def test_values_do_not_depend_on_the_resolution():
    """The same points near the same block at 0.02 and 0.01 m: the same distance to a few mm (the
    sums are normalised by the cell volume), while the raw sums differ 8x."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(0.1, 0.5, size=(200, 3))
    exact = exact_box_distance(pts, *BLOCK)
    pts = pts[(exact > 0.01) & (exact < 0.14)]
    d = {}
    for r in (0.02, 0.01):
        d[r], _ = calibrated_at(box_grid(r, *BLOCK), CalibratedSpec().build(r), pts)
    assert len(pts) > 50
    assert np.abs(d[0.02] - d[0.01]).max() < 0.006


def test_the_gradient_points_away_from_the_obstacle():
    r = 0.02
    grid = box_grid(r, *BLOCK)
    rng = np.random.default_rng(2)
    pts = rng.uniform(0.12, 0.48, size=(300, 3))
    exact = exact_box_distance(pts, *BLOCK)
    pts, exact = pts[(exact > 0.005) & (exact < 0.14)], exact[(exact > 0.005) & (exact < 0.14)]
    nearest = np.clip(pts, BLOCK[0], BLOCK[1])
    away = (pts - nearest) / exact[:, None]
    _, grad = calibrated_at(grid, CalibratedSpec().build(r), pts)
    unit = grad / np.linalg.norm(grad, axis=1)[:, None]
    cos = np.einsum("ij,ij->i", unit, away)
    assert np.all(cos > 0.7) and np.median(cos) > 0.98  # near an edge it blends both faces


def test_lazy_equals_full_at_cell_centres_and_numpy_equals_numba():
    r = 0.02
    grid = box_grid(r, *BLOCK)
    kernel = CalibratedSpec().build(r)
    idx = np.array([[5, 15, 15], [8, 9, 10], [15, 15, 22], [3, 3, 3], [13, 14, 15]])
    centres = (idx + 0.5) * r
    lazy_d, lazy_g = calibrated_at(grid, kernel, centres, backend="numba")
    full = calibrated_full(grid, kernel, backend="numba")
    full_d, full_g = full.sample(centres)
    assert np.allclose(np.minimum(lazy_d, 0.15), full_d, atol=1e-9)
    assert np.allclose(lazy_g, full_g, rtol=1e-6, atol=1e-9)
    np_d, np_g = calibrated_at(grid, kernel, centres, backend="numpy")
    assert np.allclose(np_d, lazy_d, atol=1e-9) and np.allclose(np_g, lazy_g, rtol=1e-6, atol=1e-9)
    full_np = calibrated_full(grid, kernel, backend="numpy")
    assert np.allclose(full_np.deficit.components, full.deficit.components, atol=1e-9)


def test_far_from_every_obstacle_the_distance_is_unbounded_and_nothing_pushes():
    grid = box_grid(0.02, *BLOCK)
    d, grad = calibrated_at(grid, CalibratedSpec().build(0.02), np.array([[2.0, 2.0, 2.0]]))
    assert d[0] == np.inf and np.all(grad == 0)


def test_bad_settings_are_refused_by_name():
    with pytest.raises(InvalidConfigError, match="sigma"):
        CalibratedSpec(sigma=0.0).build(0.02)
    with pytest.raises(InvalidConfigError, match="reach"):
        CalibratedSpec(reach=float("nan")).build(0.02)
    with pytest.raises(ResourceLimitError, match="coarser"):
        CalibratedSpec(reach=1.0).build(0.001)
    kernel = CalibratedSpec().build(0.02)
    with pytest.raises(InvalidConfigError, match="resolution"):
        calibrated_at(box_grid(0.01, *BLOCK), kernel, np.zeros((1, 3)))
    with pytest.raises(InvalidConfigError, match="field_kind"):
        MatrixFieldConfig(field_kind="edt").validate()
    with pytest.raises(InvalidConfigError, match="field_sigma"):
        MatrixFieldConfig(field_kind="calibrated", field_sigma=-0.01).validate()
    with pytest.raises(InvalidConfigError, match="distance_floor"):
        MatrixFieldConfig(field_kind="calibrated", distance_floor=0.2).validate()
    MatrixFieldConfig(field_kind="calibrated").validate()


@pytest.fixture(scope="module")
def wall_problem():
    robot = load_robot("panda")
    start = np.array(robot.home)
    goal = start.copy()
    goal[0] = 0.3
    wall = Obstacle("wall", "box", position=(0.5, 0.0, 0.4), size=(0.2, 0.6, 0.8))  # face at x = 0.4
    return Problem.create(robot, Scene((wall,), name="wall"), start, goal, id="test:calibrated-wall")


def test_the_preset_pushes_like_edt_field_at_the_standoff(wall_problem):
    """``matrix-field:calibrated``: Khatib's push along the calibrated gradient, as ``edt-field``
    pushes along its distance transform's: near a flat face (voxelized, so up to a cell nearer
    than the box) both push alike, away from the wall; the same in full and lazy mode."""
    planner = planbench.make_planner("matrix-field:calibrated")
    assert planner.config.field_kind == "calibrated"
    assert planner.hierarchy_for(7) == "nullspace"
    assert MatrixFieldPlanner(field_kind="matrix").hierarchy_for(7) == "nullspace"  # both fields (issue 32)
    planner.setup(wall_problem)
    rep = planner.stepper.repulsion
    rep = getattr(rep, "inner", rep)
    assert isinstance(rep, CalibratedRepulsion) and rep.field is not None
    c = planner.config
    point = np.array([[0.4 - c.standoff, 0.0, 0.4]])
    push = rep.at(point)[0]
    assert push[0] < 0 and abs(push[1]) < 1e-6 * abs(push[0])
    edt = planbench.make_planner("edt-field")
    edt.setup(wall_problem)
    erep = getattr(edt.stepper.repulsion, "inner", edt.stepper.repulsion)
    d, _ = rep.distance_at(point)
    d_edt = erep.d0 + erep.deficit.sample(point)[0, 0]
    assert abs(d[0] - d_edt) < 0.25 * c.grid_resolution
    assert d[0] <= c.standoff and np.linalg.norm(push) >= c.speed_max  # the voxelized face is nearer
    lazy = planbench.make_planner("matrix-field:calibrated", field_mode="lazy")
    lazy.setup(wall_problem)
    lrep = getattr(lazy.stepper.repulsion, "inner", lazy.stepper.repulsion)
    assert lrep.field is None
    assert np.allclose(lrep.at(point), push, rtol=0.05)


def test_the_controller_setting_builds_the_calibrated_push():
    """The matrix-field controller with ``field_kind="calibrated"``: lazy (default) and full give
    the same push at a grid's cell centres; the original field stays the default."""
    assert MatrixFieldController().config.field_kind == "matrix"
    grid = box_grid(0.02, *BLOCK)
    centres = (np.array([[5, 15, 15], [15, 8, 15], [15, 15, 22]]) + 0.5) * 0.02
    pushes = {}
    for mode in ("lazy", "full"):
        controller = MatrixFieldController(field_kind="calibrated", field_mode=mode)
        rep = controller.field.repulsion(grid)
        assert isinstance(rep, CalibratedRepulsion)
        pushes[mode] = rep.at(centres)
    assert np.linalg.norm(pushes["lazy"], axis=1).min() > 0
    assert np.allclose(pushes["lazy"], pushes["full"], rtol=1e-6, atol=1e-9)
    assert GridField(MatrixFieldController(field_kind="calibrated").config).repulsion(grid) is not None
    preset = make_controller("matrix-field:calibrated")
    assert preset.config.field_kind == "calibrated" and preset.config.field_mode == "lazy"
    assert isinstance(preset.field.repulsion(grid), CalibratedRepulsion)


def test_forces_at_control_points_equal_the_push_at_those_points(wall_problem):
    """The loop's query (``forces``, buffers bound to the control points) gives :meth:`at`'s push,
    in full and lazy mode, and the same arrays every step."""
    for mode in ("full", "lazy"):
        planner = planbench.make_planner("matrix-field:calibrated", field_mode=mode)
        planner.setup(wall_problem)
        rep = getattr(planner.stepper.repulsion, "inner", planner.stepper.repulsion)
        kin = planner.stepper.kin
        q = np.array(wall_problem.start)
        q[3] += 0.3  # the arm nearer the wall
        kin.update(q)
        points, F, _, _ = rep.forces(kin)
        assert np.linalg.norm(F, axis=1).max() > 0
        assert np.allclose(F, rep.at(points), rtol=1e-9, atol=1e-12)
        kin.update(np.array(wall_problem.start))
        points2, F2, _, _ = rep.forces(kin)
        assert F2 is F and np.allclose(F2, rep.at(points2), rtol=1e-9, atol=1e-12)


def test_the_calibrated_controller_conforms():
    """The preset as a controller passes planbench's controller checks (frames, ticks, goal)."""
    assert check_controller("matrix-field:calibrated") == []
