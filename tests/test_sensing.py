"""The sensing models: truth (the scene voxelised, cached over unmoved obstacles) and simulated
depth cameras (front surfaces, range noise, dropout, max range, the robot removed)."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import coal
import numpy as np
import pinocchio as pin
import pytest
import trimesh

from conftest import box
from planbench import Obstacle, OccupancyGrid, Scene
from planbench.reactive.meshes import geometry_triangles
from planbench.reactive.scenario import CameraSettings, SensingSettings
from planbench.reactive.sensing import ROBOT_EDGE, Sensor, camera_rays

RES = 0.02
# a camera at x = 0.8 looking along +x, away from the arm at the origin
AHEAD = dict(position=(0.8, 0.0, 0.4), look_at=(2.0, 0.0, 0.4))
N_PIXELS = 160 * 120


def depth(**camera):
    return SensingSettings(model="depth", resolution=RES, cameras=(CameraSettings(**{**AHEAD, **camera}),))


def cloud_of(robot, scene, q=None, seed=0, settings=None, **camera):
    sensor = Sensor(settings or depth(**camera), robot)
    q = robot.home if q is None else q
    return sensor.capture(scene, q, 0.0, 0, np.random.default_rng(seed))


def wall(x, half=3.0):
    """A wall whose front face is the plane x = ``x`` - 0.01, wide enough to fill the image."""
    return Scene((box("wall", (x, 0.0, 0.4), (0.02, 2 * half, 2 * half)),))


def wall_range_errors(points, face_x=1.99):
    """Measured minus true range [m] of points on the wall x = face_x seen from AHEAD."""
    v = points - np.array(AHEAD["position"])
    measured = np.linalg.norm(v, axis=1)
    true = (face_x - AHEAD["position"][0]) / (v[:, 0] / measured)
    return measured - true


# --- cameras --------------------------------------------------------------------------------------
def test_camera_rays_span_the_field_of_view_with_square_pixels():
    cam = CameraSettings(position=(0, 0, 0), look_at=(1, 0, 0), width=4, height=2, fov=90.0)
    origin, d = camera_rays(cam)
    assert d.shape == (8, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    np.testing.assert_allclose(origin, 0.0)
    p = d / d[:, :1]  # on the image plane x = 1: y to the left, z up
    # vertical fov 90 deg over 2 rows: pixel size 1 at unit focal length, centres at +-0.5
    np.testing.assert_allclose(p[:4, 2], 0.5)  # first row is the top
    np.testing.assert_allclose(p[4:, 2], -0.5)
    np.testing.assert_allclose(p[:4, 1], [1.5, 0.5, -0.5, -1.5])  # left to right: y decreasing


# --- depth: what a camera sees --------------------------------------------------------------------
def test_a_camera_sees_the_front_face_of_a_box_not_its_back(panda):
    scene = Scene((box("b", (1.1, 0.0, 0.4), (0.2, 0.3, 0.3)),))  # front face x = 1.0, back x = 1.2
    obs = cloud_of(panda, scene)
    assert obs.scene is None and obs.points is not None and len(obs.points) > 1000
    np.testing.assert_allclose(obs.points[:, 0], 1.0, atol=1e-6)
    x = obs.grid.cell_centers()[obs.grid.data > 0][:, 0]
    assert len(x) > 50
    assert np.all(np.abs(x - 1.0) <= RES)  # the front face, within one cell
    assert not np.any(x > 1.1)  # nothing behind it, least of all the back face at 1.2
    truth = OccupancyGrid.from_scene(scene, RES, bounds=Sensor(depth(), panda).bounds)
    xt = truth.cell_centers()[truth.data > 0][:, 0]
    assert np.any(np.abs(xt - 1.2) < RES) and np.any(np.abs(xt - 1.0) < RES)


@pytest.mark.parametrize(
    "obstacle",
    [
        Obstacle("ball", "sphere", position=(1.3, 0.0, 0.4), radius=0.1),
        Obstacle("can", "cylinder", position=(1.3, 0.0, 0.4), radius=0.1, length=0.3),
        Obstacle(  # axis along y: rotated a quarter turn about x
            "bar",
            "capsule",
            position=(1.3, 0.0, 0.4),
            radius=0.1,
            length=0.2,
            orientation_xyzw=(math.sin(math.pi / 4), 0.0, 0.0, math.cos(math.pi / 4)),
        ),
        box("tilted", (1.3, 0.0, 0.4), (0.2, 0.2, 0.2), orientation_xyzw=(0.0, 0.0, math.sin(0.3), math.cos(0.3))),
    ],
    ids=lambda o: o.type,
)
def test_every_shape_is_seen_on_its_surface_at_its_pose(panda, obstacle):
    points = cloud_of(panda, Scene((obstacle,))).points
    assert len(points) > 500
    # triangulated shapes are inscribed: on the true surface within 0.5 % of the radius
    assert np.abs(obstacle.signed_distance(points)).max() < 1e-3
    if obstacle.type != "box":  # the nearest surface point is at x = 1.2
        assert points[:, 0].min() == pytest.approx(1.2, abs=2e-3)


def test_a_mesh_obstacle_is_loaded_scaled_and_placed(panda, tmp_path):
    path = tmp_path / "cube.stl"
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(path)
    mesh = Obstacle("m", "mesh", position=(1.3, 0.0, 0.4), path=str(path), scale=(2.0, 3.0, 1.0))
    points = cloud_of(panda, Scene((mesh,))).points
    np.testing.assert_allclose(points[:, 0], 1.2, atol=1e-6)  # front face at 1.3 - 0.1 * 2 / 2
    assert points[:, 1].max() == pytest.approx(0.15, abs=0.01)  # y half width 0.1 * 3 / 2


def test_range_noise_is_gaussian_along_the_ray_with_the_set_std(panda):
    points = cloud_of(panda, wall(2.0), noise_std=0.01).points
    assert len(points) == N_PIXELS
    err = wall_range_errors(points)
    assert np.std(err) == pytest.approx(0.01, rel=0.03)
    assert abs(np.mean(err)) < 4 * 0.01 / math.sqrt(N_PIXELS)
    assert points.dtype == np.float32  # as depth drivers deliver them: float32 resolution at 2 m is 2.4e-7 m
    exact = cloud_of(panda, wall(2.0)).points.astype(float)
    np.testing.assert_allclose(wall_range_errors(exact), 0.0, atol=2.4e-7)
    # along the ray: each noisy point lies on its pixel's ray (to float32's rounding of a point 2 m away)
    _, dirs = camera_rays(CameraSettings(**AHEAD))
    v = points.astype(float) - np.array(AHEAD["position"])
    np.testing.assert_allclose(v / np.linalg.norm(v, axis=1, keepdims=True), dirs, atol=2.4e-7)


def test_dropout_removes_that_fraction_of_pixels(panda):
    assert len(cloud_of(panda, wall(2.0)).points) == N_PIXELS
    kept = len(cloud_of(panda, wall(2.0), dropout=0.3).points) / N_PIXELS
    assert kept == pytest.approx(0.7, abs=0.02)


def test_nothing_beyond_max_range_is_seen(panda):
    far = wall(0.8 + 3.5 + 0.01, half=4.0)  # front face 3.5 m ahead
    assert len(cloud_of(panda, far).points) == 0  # max_range 3 m by default
    assert len(cloud_of(panda, far, max_range=5.0).points) == N_PIXELS
    # a wall 2.5 m ahead: the centre of the image is in range, its corners (3.5 m) are not
    points = cloud_of(panda, wall(0.8 + 2.5 + 0.01, half=4.0)).points
    assert 0 < len(points) < N_PIXELS
    assert np.linalg.norm(points - np.array(AHEAD["position"]), axis=1).max() <= 3.0


def test_cameras_add_up_and_the_grid_holds_the_points_in_bounds(panda):
    scene = Scene((box("b", (1.1, 0.0, 0.4), (0.2, 0.3, 0.3)),))
    one = depth()
    two = replace(one, cameras=one.cameras + (CameraSettings(position=(1.1, 0.8, 0.4), look_at=(1.1, 0.0, 0.4)),))
    a, b = cloud_of(panda, scene, settings=one), cloud_of(panda, scene, settings=two)
    assert len(b.points) > len(a.points)
    np.testing.assert_array_equal(b.points[: len(a.points)], a.points)
    assert np.any(np.abs(b.points[:, 1] - 0.15) < 1e-6)  # the second camera sees the side y = 0.15
    expected = OccupancyGrid.from_points(b.points, RES, bounds=Sensor(two, panda).bounds)
    np.testing.assert_array_equal(b.grid.data, expected.data)


# --- depth: the robot removed from its own view ---------------------------------------------------
ARM_CAMERA = dict(position=(1.2, 0.4, 0.9), look_at=(0.3, 0.0, 0.3))
Q_ARM = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
TABLE = Scene((box("table", (0.4, 0.0, -0.02), (1.6, 1.6, 0.04)),))  # top at z = 0, under the base


def distance_to_robot(robot, q, points, cutoff=0.2):
    """Exact distance [m] from each point to the robot's collision geometry (coal), capped at cutoff."""
    data, gdata = robot.model.createData(), pin.GeometryData(robot.collision_model)
    pin.updateGeometryPlacements(robot.model, data, robot.collision_model, gdata, q)
    out = np.full(len(points), cutoff)
    dot = coal.Sphere(1e-9)
    for obj, M in zip(robot.collision_model.geometryObjects, gdata.oMg, strict=True):
        g = obj.geometry
        g.computeLocalAABB()
        centre = M.act(np.array(g.aabb_center))
        for i in np.flatnonzero(np.linalg.norm(points - centre, axis=1) < g.aabb_radius + cutoff):
            res = coal.DistanceResult()
            tf = coal.Transform3s(np.eye(3), points[i])
            coal.distance(g, coal.Transform3s(M.rotation, M.translation), dot, tf, coal.DistanceRequest(), res)
            out[i] = min(out[i], res.min_distance)
    return out


def test_the_arm_is_in_view_and_removed_from_the_cloud(panda):
    hand = panda.frame_pose(Q_ARM).translation
    origin, dirs = camera_rays(CameraSettings(**ARM_CAMERA))
    to_hand = (hand - origin) / np.linalg.norm(hand - origin)
    assert (dirs @ to_hand).max() > 0.9999  # some pixel looks straight at the hand
    # without obstacles the camera sees only the arm, and every arm pixel is removed
    settings = replace(depth(**ARM_CAMERA), robot_margin=0.0)
    assert len(cloud_of(panda, Scene(), Q_ARM, settings=settings).points) == 0
    bare = cloud_of(panda, TABLE, Q_ARM, settings=settings).points
    kept = cloud_of(panda, TABLE, Q_ARM, settings=replace(settings, robot_margin=0.03)).points
    d_bare = distance_to_robot(panda, Q_ARM, bare)
    d_kept = distance_to_robot(panda, Q_ARM, kept)
    assert np.sum(d_bare < 0.03) > 20  # the table around the base lies within the margin...
    assert d_kept.min() >= 0.03  # ...and is removed
    # the margin test removes no point farther than margin + ROBOT_EDGE / sqrt(3) from the arm
    far = bare[d_bare > 0.03 + ROBOT_EDGE / math.sqrt(3.0)]
    assert len(far) > 5000 and np.all(np.abs(far[:, 2]) < 1e-9)  # the table, seen around the arm
    keep_set = {tuple(p) for p in kept}
    assert all(tuple(p) in keep_set for p in far)


def test_the_arm_hides_the_table_behind_it(panda):
    settings = replace(depth(**ARM_CAMERA), robot_margin=0.0)
    points = cloud_of(panda, TABLE, Q_ARM, settings=settings).points
    # the pixels whose ray meets the table top (z = 0, |x - 0.4| and |y| <= 0.8) were the arm not there
    origin, dirs = camera_rays(CameraSettings(**ARM_CAMERA))
    t = -origin[2] / np.minimum(dirs[:, 2], -1e-12)
    top = origin + t[:, None] * dirs
    on_table = (np.abs(top[:, 0] - 0.4) <= 0.8) & (np.abs(top[:, 1]) <= 0.8)
    assert np.all(np.abs(points[:, 2]) < 1e-9)  # only the table top is seen
    assert 100 < on_table.sum() - len(points) < 0.5 * on_table.sum()  # less the pixels the arm covers


def test_noisy_points_near_the_arm_are_removed_too(panda):
    obs = cloud_of(panda, TABLE, Q_ARM, seed=3, noise_std=0.01, **ARM_CAMERA)
    assert distance_to_robot(panda, Q_ARM, obs.points).min() >= 0.03


# --- depth: what a frame knows --------------------------------------------------------------------
def _state(grid, point):
    """``"occupied"``, ``"free"`` or ``"unknown"``: the cell of ``point`` [m]."""
    i = tuple(grid.index_of(np.array([point]))[0])
    if not grid.known_mask[i]:
        return "unknown"
    return "occupied" if grid.data[i] > 0 else "free"


def test_a_box_in_view_leaves_free_space_before_it_and_an_unknown_shadow_behind_it(panda):
    scene = Scene((box("b", (1.1, 0.0, 0.4), (0.2, 0.3, 0.3)),))  # front face x = 1.0, back x = 1.2
    grid = cloud_of(panda, scene).grid
    assert grid.known is not None and grid.known.dtype == bool and grid.known.shape == grid.shape
    assert _state(grid, (0.9, 0.0, 0.4)) == "free"  # between the camera and the face
    assert _state(grid, (1.005, 0.0, 0.4)) == "occupied"  # the face (in the cell [1.0, 1.02))
    for x in (1.05, 1.15, 1.25, 1.35):  # inside the box, its back face, the shadow beyond it
        assert _state(grid, (x, 0.0, 0.4)) == "unknown", x
    assert _state(grid, (0.95, 0.1, 0.4)) == "free"  # in front of the face, off the axis
    assert _state(grid, (0.4, 0.0, 0.4)) == "unknown"  # behind the camera: never in view
    assert np.all(grid.known[grid.data > 0])  # every occupied cell was seen


def test_a_ray_that_meets_nothing_is_free_up_to_max_range_and_a_dropped_pixel_says_nothing(panda):
    far = cloud_of(panda, Scene(()), max_range=0.6).grid  # from x = 0.8: free up to x = 1.4
    assert _state(far, (1.3, 0.0, 0.4)) == "free" and _state(far, (1.41, 0.0, 0.4)) == "unknown"
    blind = cloud_of(panda, wall(1.9), dropout=0.999).grid
    seeing = cloud_of(panda, wall(1.9)).grid
    arm = arm_cells(panda, blind, panda.home)
    assert np.all(blind.known.reshape(-1)[arm])  # the arm's own cells are known without a ray
    by_rays = [np.count_nonzero(np.delete(g.known.reshape(-1), arm)) for g in (blind, seeing)]
    assert by_rays[0] < 0.1 * by_rays[1]  # 1 pixel in 1,000 left: its few rays


def arm_cells(robot, grid, q):
    from planbench.reactive.body import ArmBody

    body = ArmBody(robot, grid.origin, grid.shape, grid.resolution).mark(np.zeros(grid.shape, dtype=bool), q)
    return np.flatnonzero(body)


@pytest.mark.parametrize("memory", ["frame", "map"])
def test_the_arm_is_known_free_of_obstacles_and_what_touches_it_is_not_claimed_free(panda, memory):
    settings = replace(depth(**ARM_CAMERA), memory=memory)
    grid = cloud_of(panda, TABLE, Q_ARM, settings=settings).grid
    arm = arm_cells(panda, grid, Q_ARM)
    assert np.all(grid.known.reshape(-1)[arm]) and not np.any(grid.data.reshape(-1)[arm])
    # every cell the arm's body covers whole is one of them (the cell's 8 corners inside a link)
    centres = grid.cell_centers().reshape(-1, 3)
    deep = np.zeros(len(centres), dtype=bool)
    data, gdata = panda.model.createData(), pin.GeometryData(panda.collision_model)
    pin.updateGeometryPlacements(panda.model, data, panda.collision_model, gdata, Q_ARM)
    for obj, M in zip(panda.collision_model.geometryObjects, gdata.oMg, strict=True):
        mesh = trimesh.Trimesh(*geometry_triangles(obj))
        near = np.flatnonzero(np.all(np.abs(centres - M.translation) < 0.3, axis=1))
        corners = centres[near, None, :] + RES / 2 * np.array(list(itertools.product((-1, 1), repeat=3)))
        inside = mesh.contains(((corners - M.translation) @ M.rotation).reshape(-1, 3)).reshape(-1, 8)
        deep[near[inside.all(axis=1)]] = True
    assert deep.sum() > 100 and np.isin(np.flatnonzero(deep), arm).all()
    # beyond them, a ray stops robot_margin short of the arm it meets, so a free cell holds a point
    # outside the arm: its centre lies at most half a cell's diagonal inside the arm's surface
    free = grid.known & (grid.data == 0)
    free.reshape(-1)[arm] = False
    assert distance_to_robot(panda, Q_ARM, centres[free.reshape(-1)]).min() > -RES * math.sqrt(3) / 2


def test_truth_knows_every_cell(panda):
    obs = Sensor(SensingSettings(model="truth", resolution=RES), panda).capture(TABLE, panda.home, 0.0, 0, None)
    assert obs.grid.known is None and obs.grid.known_mask.all() and obs.grid.known_mask.shape == obs.grid.shape


def test_the_known_mask_crosses_to_the_controller_unchanged(panda):
    from planbench.reactive.remote import GridRing, GridView

    sensor = Sensor(depth(), panda)
    ring, view = GridRing(), GridView()
    shape = sensor.capture(Scene(()), panda.home, 0, 0, np.random.default_rng(0)).grid.shape
    ring.prepared(shape)
    view.prepare(shape)
    for k in range(6):  # more frames than the ring has slots, the box moving across the view
        scene = Scene((box("b", (1.3, -0.3 + 0.1 * k, 0.4), (0.2, 0.2, 0.2)),))
        sent = sensor.capture(scene, panda.home, 0.03 * k, k, np.random.default_rng(k))
        got = view.read(ring.write(sent))
        assert np.array_equal(got.grid.known, sent.grid.known) and not got.grid.known.flags.writeable
        assert np.array_equal(got.grid.data, sent.grid.data)
        del got
    truth = Sensor(SensingSettings(model="truth", resolution=RES), panda).capture(TABLE, panda.home, 0.0, 0, None)
    assert view.read(ring.write(truth)).grid.known is None


def test_known_at_reads_the_bits_of_some_cells_as_the_whole_mask_gives_them():
    from planbench.reactive.controller import Observation
    from planbench.reactive.remote import GridRing, GridView

    rng = np.random.default_rng(0)
    shape = (13, 17, 19)  # 4199 cells: not a multiple of 8
    known = rng.random(shape) < 0.6
    grid = OccupancyGrid((rng.random(shape) < 0.1).astype(float), np.zeros(3), 0.02, known=known)
    ring, view = GridRing(), GridView()
    ring.prepared(shape)
    view.prepare(shape)
    delivered = view.read(ring.write(Observation(time=0.0, grid=grid))).grid
    cells = np.concatenate([rng.integers(0, known.size, 500), [0, known.size - 1]])
    assert np.array_equal(grid.known_at(cells), known.reshape(-1)[cells])
    assert np.array_equal(delivered.known_at(cells), known.reshape(-1)[cells])  # from the packed bits
    assert "_known" not in delivered.__dict__  # no bool per cell was made
    assert np.array_equal(delivered.known, known)
    assert np.array_equal(delivered.known_at(cells), known.reshape(-1)[cells])  # from the unpacked mask
    assert OccupancyGrid(np.zeros(shape), np.zeros(3), 0.02).known_at(cells).all()  # no mask: every cell known


def test_a_known_mask_of_another_shape_or_type_is_refused():
    with pytest.raises(ValueError, match="known must be a bool array"):
        OccupancyGrid(np.zeros((2, 2, 2)), np.zeros(3), 0.1, known=np.ones((2, 2, 3), bool))
    with pytest.raises(ValueError, match="known must be a bool array"):
        OccupancyGrid(np.zeros((2, 2, 2)), np.zeros(3), 0.1, known=np.ones((2, 2, 2)))


# --- truth --------------------------------------------------------------------------------------
def test_truth_is_the_voxelised_scene(panda):
    scene = TABLE.with_obstacles([box("b", (0.5, 0.2, 0.3), (0.1, 0.1, 0.2))])
    sensor = Sensor(SensingSettings(resolution=RES), panda)
    obs = sensor.capture(scene, Q_ARM, 1.5, 7, np.random.default_rng(0))
    assert (obs.time, obs.frame, obs.points, obs.scene) == (1.5, 7, None, scene)
    fresh = OccupancyGrid.from_scene(scene, RES, bounds=sensor.bounds, rule="any")
    np.testing.assert_array_equal(obs.grid.data, fresh.data)
    np.testing.assert_array_equal(obs.grid.origin, fresh.origin)
    assert obs.grid.data.sum() > 0


def test_truth_grid_follows_moving_obstacles_and_its_cache_agrees_with_fresh_grids(panda):
    sensor = Sensor(SensingSettings(resolution=RES), panda)
    ball = Obstacle("ball", "sphere", position=(0.5, -0.5, 0.4), radius=0.06)
    can = Obstacle("can", "cylinder", position=(0.3, 0.4, 0.2), radius=0.04, length=0.2)
    bar = Obstacle("bar", "capsule", position=(-0.3, 0.3, 0.5), radius=0.03, length=0.3)

    def frame(k):
        moving = [replace(ball, position=(0.5, -0.5 + 0.1 * min(k, 4), 0.4))]  # stops after frame 4
        if 2 <= k < 6:
            moving.append(can)  # appears, stays, disappears
        if k % 3 != 1:
            moving.append(replace(bar, position=(-0.3, 0.3, 0.5 + 0.05 * k)))  # and blinks
        return TABLE.with_obstacles(moving)

    origins = set()
    for k in range(9):
        scene = frame(k)
        grid = sensor.capture(scene, Q_ARM, 0.1 * k, k, np.random.default_rng(0)).grid
        fresh = OccupancyGrid.from_scene(scene, RES, bounds=sensor.bounds, rule="any")
        np.testing.assert_array_equal(grid.data, fresh.data, err_msg=f"frame {k}")
        origins.add((tuple(grid.origin), grid.shape))
        at = scene.obstacles[1].position
        assert grid.occupancy_at(np.array(at))[0] == 1.0
        if 0 < k <= 4:  # the ball left where it was a frame ago
            assert grid.occupancy_at(np.array(at) - [0.0, 0.1, 0.0])[0] == 0.0
    assert len(origins) == 1  # one grid shape for the whole run


def test_default_bounds_cover_the_reach_on_the_resolution_lattice(panda):
    sensor = Sensor(SensingSettings(resolution=0.03), panda)
    lower, upper = sensor.bounds
    half = panda.reach() + 0.1
    assert np.all(lower <= -half) and np.all(upper >= half) and np.all(upper - lower < 2 * half + 0.06)
    np.testing.assert_allclose(np.round(lower / 0.03) * 0.03, lower, atol=1e-12)
    np.testing.assert_allclose(np.round(upper / 0.03) * 0.03, upper, atol=1e-12)


# --- determinism and bad input ------------------------------------------------------------------
def test_the_same_seed_gives_the_same_cloud(panda):
    kw = dict(noise_std=0.01, dropout=0.2, **ARM_CAMERA)
    a = cloud_of(panda, TABLE, Q_ARM, seed=11, **kw)
    b = cloud_of(panda, TABLE, Q_ARM, seed=11, **kw)
    c = cloud_of(panda, TABLE, Q_ARM, seed=12, **kw)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.grid.data, b.grid.data)
    assert len(a.points) != len(c.points) or not np.array_equal(a.points, c.points)


@pytest.mark.parametrize("model", ["truth", "depth"])
def test_bad_configurations_are_rejected(panda, model):
    sensor = Sensor(SensingSettings(model=model, resolution=0.05), panda)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="shape"):
        sensor.capture(TABLE, np.zeros(6), 0.0, 0, rng)
    with pytest.raises(ValueError, match="finite"):
        sensor.capture(TABLE, np.full(7, np.nan), 0.0, 0, rng)


def test_bad_bounds_are_rejected(panda):
    with pytest.raises(ValueError, match="upper > lower"):
        Sensor(SensingSettings(), panda, bounds=(np.ones(3), np.zeros(3)))
    with pytest.raises(ValueError, match="3 finite"):
        Sensor(SensingSettings(), panda, bounds=(np.zeros(2), np.ones(2)))
