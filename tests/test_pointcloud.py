"""Point-cloud obstacles: file reading and its errors, and one geometry (the union of lattice cubes)
seen the same way by coal's octree, ``contains``/``signed_distance``, the grids and the certified
checker; the shipped depth-camera example loads in every planner kind."""

import json
import math
import shutil
from pathlib import Path

import coal
import numpy as np
import pytest
import trimesh

import planbench
from planbench.checking.certified import CertifiedChecker
from planbench.checking.collision import CollisionChecker
from planbench.cli.main import main
from planbench.errors import ProblemFileError
from planbench.geometry.occupancy import OccupancyGrid, scene_grid
from planbench.geometry.pointcloud import PointCloudError, VoxelCloud, read_points, write_points
from planbench.problem import Problem
from planbench.problems.datasets import load_problems
from planbench.reactive.depth_example import shipped_example_dir
from planbench.scene import Obstacle, Scene

EXAMPLE = shipped_example_dir() / "depth_camera_table.json"
TILTED = tuple(np.array([0.2, 0.1, 0.3, 0.927]) / np.linalg.norm([0.2, 0.1, 0.3, 0.927]))


def _blob(tmp_path: Path, n: int = 600, seed: int = 0, name: str = "c.npz") -> Path:
    pts = np.random.default_rng(seed).normal([0.45, 0.1, 0.35], 0.03, (n, 3))
    path = tmp_path / name
    write_points(path, pts)
    return path


def _probe(geometry, pose, points):  # noqa: ANN001, ANN202 - tiny-sphere coal queries
    """coal's verdict and distance for points (spheres of 1e-7 m) against ``geometry``."""
    req, creq = coal.DistanceRequest(), coal.CollisionRequest()
    hit, dist = [], []
    for p in points:
        tf = coal.Transform3s(np.eye(3), p)
        hit.append(coal.collide(coal.Sphere(1e-7), tf, geometry, pose, creq, coal.CollisionResult()))
        dist.append(coal.distance(coal.Sphere(1e-7), tf, geometry, pose, req, coal.DistanceResult()) + 1e-7)
    return np.array(hit, dtype=bool), np.array(dist)


# --- files -----------------------------------------------------------------------------------------
def test_npz_and_ply_give_the_same_points(tmp_path):
    pts = np.random.default_rng(1).uniform(-1, 1, (50, 3))
    write_points(tmp_path / "a.npz", pts)
    trimesh.PointCloud(pts).export(tmp_path / "b.ply", encoding="binary")
    trimesh.PointCloud(pts).export(tmp_path / "c.ply", encoding="ascii")
    want = pts.astype(np.float32)
    for name in ("a.npz", "b.ply", "c.ply"):
        np.testing.assert_allclose(read_points(tmp_path / name), want, atol=1e-6)


@pytest.mark.parametrize(
    "content, message",
    [
        ({"points": np.zeros((0, 3))}, "no points"),
        ({"points": np.zeros((4, 2))}, "(N, 3)"),
        ({"points": np.array([[0.0, np.nan, 1.0]])}, "NaN"),
        ({"xyz": np.zeros((4, 3))}, "no array 'points'"),
        ({"points": np.array(["a", "b", "c"])}, "numeric"),
    ],
)
def test_bad_npz_is_a_named_error(tmp_path, content, message):
    path = tmp_path / "bad.npz"
    np.savez(path, **content)
    with pytest.raises(PointCloudError, match=message):
        read_points(path)


def test_unreadable_files_are_named_errors(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    (tmp_path / "junk.ply").write_text("ply\nformat nonsense\n")
    (tmp_path / "x.xyz").write_text("0 0 0\n")
    for name, message in (
        ("junk.npz", "readable .npz"),
        ("junk.ply", "PLY"),
        ("x.xyz", "unsupported"),
        ("no.npz", "not found"),
    ):
        with pytest.raises(PointCloudError, match=message):
            read_points(tmp_path / name)


def test_bad_cloud_in_a_problem_file_exits_2(tmp_path, capsys):
    d = json.loads(EXAMPLE.read_text())
    d["scene"]["obstacles"][0]["path"] = "missing.npz"
    (tmp_path / "p.json").write_text(json.dumps(d))
    with pytest.raises(ProblemFileError, match="missing.npz"):
        Problem.load(tmp_path / "p.json")
    assert main(["plan", "--problem", str(tmp_path / "p.json"), "--planner", "straight-line"]) == 2
    assert "Traceback" not in capsys.readouterr().err
    d["scene"]["obstacles"][0].update(path=str(EXAMPLE.with_suffix(".npz")), radius=0)
    with pytest.raises(ProblemFileError, match="radius"):
        Problem.from_dict(d, "p.json")


def test_path_is_relative_to_the_scene_file(tmp_path):
    _blob(tmp_path)
    scene = {"obstacles": [{"name": "c", "type": "pointcloud", "path": "c.npz", "radius": 0.005}]}
    (tmp_path / "s.json").write_text(json.dumps(scene))
    o = Scene.load(tmp_path / "s.json").obstacles[0]
    assert Path(o.path) == tmp_path / "c.npz"
    again = Obstacle.from_dict(o.to_dict())
    assert again == o and len(again.cloud()) == len(o.cloud())


# --- one geometry ----------------------------------------------------------------------------------
def test_octree_leaves_are_the_cubes(tmp_path):
    cloud = Obstacle("c", "pointcloud", path=str(_blob(tmp_path)), radius=0.004).cloud()
    boxes = np.asarray(cloud.octree().toBoxes())
    assert np.allclose(boxes[:, 3], cloud.cell)
    got = np.unique(np.round(boxes[:, :3] / cloud.cell - 0.5).astype(int), axis=0)
    np.testing.assert_array_equal(got, np.unique(cloud.cells, axis=0))


@pytest.mark.parametrize("orientation", [(0.0, 0.0, 0.0, 1.0), TILTED])
def test_coal_contains_and_signed_distance_agree(tmp_path, orientation):
    o = Obstacle("c", "pointcloud", (0.01, -0.02, 0.003), orientation, path=str(_blob(tmp_path)), radius=0.004)
    pose = coal.Transform3s(o.rotation, np.array(o.position))
    lo, hi = o.aabb()
    rng = np.random.default_rng(2)
    cubes = o.cloud().centres[rng.choice(len(o.cloud()), 200)] + rng.uniform(-0.006, 0.006, (200, 3))
    points = np.concatenate([rng.uniform(lo - 0.02, hi + 0.02, (200, 3)), cubes @ o.rotation.T + o.position])
    hit, dist = _probe(o.collision_geometry(), pose, points)
    sd = o.signed_distance(points)
    assert hit.sum() > 20 and (~hit).sum() > 20
    np.testing.assert_array_equal(o.contains(points), hit)
    np.testing.assert_allclose(sd[~hit], dist[~hit], atol=1e-9)
    _, surface = _probe(o.cloud().surface, pose, points)
    np.testing.assert_allclose(surface[~hit], sd[~hit], atol=1e-9)


def test_depth_inside_is_the_distance_to_the_nearest_free_cube():
    cells = np.array([(i, j, k) for i in range(4) for j in range(3) for k in range(2)])
    cloud = VoxelCloud(cells, 0.01)
    pts = np.random.default_rng(3).uniform(0, [0.04, 0.03, 0.02], (200, 3))
    lo, hi = pts, pts  # brute force: distance to the complement of the box [0, 4] x [0, 3] x [0, 2] cells
    brute = np.minimum.reduce([lo[:, 0], 0.04 - hi[:, 0], lo[:, 1], 0.03 - hi[:, 1], lo[:, 2], 0.02 - hi[:, 2]])
    np.testing.assert_allclose(cloud.signed_distance(pts), -brute, atol=1e-12)


@pytest.mark.parametrize("orientation", [(0.0, 0.0, 0.0, 1.0), TILTED])
@pytest.mark.parametrize("resolution", [0.008, 0.0137])
def test_grid_cells_overlap_the_cubes_exactly(tmp_path, orientation, resolution):
    o = Obstacle("c", "pointcloud", (0.003, 0.0, 0.0), orientation, path=str(_blob(tmp_path, 300)), radius=0.004)
    grid = OccupancyGrid.from_scene(Scene((o,)), resolution, padding=0.02)
    centres = grid.cell_centers().reshape(-1, 3)
    occupied = grid.data.reshape(-1) > 0
    # a cube overlapping a cell comes within half a cell's diagonal of its centre, and never closer
    # than the cell's inscribed radius when it misses
    sd = o.signed_distance(centres)
    assert np.all(sd[occupied] < 0.5 * math.sqrt(3) * resolution)
    assert np.all(sd[~occupied] >= 0.5 * resolution - 1e-12)
    # every cell holding a point of a cube is occupied (4^3 samples per cell)
    near = np.flatnonzero(np.abs(sd) < resolution)
    off = (np.arange(4) + 0.5) / 4
    sub = np.stack(np.meshgrid(off, off, off, indexing="ij"), -1).reshape(-1, 3)
    idx = np.argwhere(np.ones(grid.shape, dtype=bool))[near]
    samples = grid.origin + (idx[:, None, :] + sub[None]) * resolution
    touched = o.contains(samples.reshape(-1, 3)).reshape(len(near), -1).any(axis=1)
    assert occupied[near][touched].all()


def test_grid_on_the_cloud_lattice_is_the_cubes(tmp_path):
    o = Obstacle("c", "pointcloud", path=str(_blob(tmp_path)), radius=0.005)
    grid = scene_grid(Scene((o,)), 0.01, 0.03, aligned=True)
    cells = np.argwhere(grid.data > 0) + np.round(grid.origin / 0.01).astype(int)
    np.testing.assert_array_equal(np.unique(cells, axis=0), np.unique(o.cloud().cells, axis=0))


# --- the robot against a cloud ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_problem(tmp_path_factory):
    """The example's robot, start and goal against a small cloud near its path."""
    example = Problem.load(EXAMPLE)
    robot = example.robot
    rng = np.random.default_rng(4)
    q = example.start + 0.5 * (example.goal.q - example.start)
    centre = robot.frame_pose(q).translation
    pts = centre + rng.normal(0, 0.05, (400, 3))
    path = tmp_path_factory.mktemp("cloud") / "small.npz"
    write_points(path, pts)
    scene = Scene((Obstacle("c", "pointcloud", path=str(path), radius=0.01),))
    return Problem.create(robot, scene, example.start, example.goal.q, id="small")


def test_certified_verdicts_agree_with_the_octree(small_problem):
    p = small_problem
    certified = CertifiedChecker(p.robot, p.scene)
    octree = CollisionChecker(p.robot, p.scene)
    rng = np.random.default_rng(5)
    mid = p.start + 0.5 * (p.goal.q - p.start)
    seen = {True: 0, False: 0}
    for _ in range(12):
        a, b = mid + rng.normal(0, 0.6, p.robot.nq), mid + rng.normal(0, 0.6, p.robot.nq)
        verdict = certified.check_path(np.stack([a, b]))
        dense = [octree.in_collision(a + t * (b - a)) for t in np.linspace(0, 1, 201)]
        seen[verdict.free] += 1
        if verdict.free:
            assert not any(dense)
        elif any(dense):
            t = np.flatnonzero(dense)[0] / 200
            assert verdict.fraction <= t + 1e-9
    assert seen[True] and seen[False]


def test_certified_clearance_is_coals_octree_distance(small_problem):
    p = small_problem
    certified = CertifiedChecker(p.robot, p.scene)
    octree = CollisionChecker(p.robot, p.scene)
    for q in (p.start, p.goal.q):
        assert certified.clearance(q) == pytest.approx(octree.clearance(q), abs=1e-6)


# --- the shipped example in every planner kind -----------------------------------------------------
def test_example_is_shipped_and_small():
    assert EXAMPLE.is_file() and EXAMPLE.with_suffix(".npz").stat().st_size < 1_000_000
    problem = Problem.load(EXAMPLE)
    assert problem.check().ok
    assert problem.scene.obstacles[0].type == "pointcloud"
    assert load_problems("examples:depth_camera_table")[0].id == problem.id


@pytest.mark.parametrize(
    "planner, limit", [("straight-line", 1.0), ("ompl-rrtconnect", 60.0), ("matrix-field", 1.0), ("edt-field", 1.0)]
)
def test_every_planner_kind_plans_on_the_example(planner, limit):
    problem = Problem.load(EXAMPLE)
    result = planbench.plan(problem, planbench.make_planner(planner), seed=0, time_limit=limit)
    ev = planbench.evaluate(problem, result)
    if planner == "straight-line":  # the straight motion crosses the cloud: the octree says so
        assert not ev.success and ev.status == "collision"
    if planner == "ompl-rrtconnect":  # it answers when it finds a path: the limit only spares a loaded machine
        assert ev.success


def test_regenerating_the_example_is_deterministic(tmp_path):
    from planbench.reactive.depth_example import make_example

    path = make_example(tmp_path)
    assert json.loads(path.read_text()) == json.loads(EXAMPLE.read_text())
    np.testing.assert_array_equal(
        read_points(tmp_path / "depth_camera_table.npz"), read_points(EXAMPLE.with_suffix(".npz"))
    )
    shutil.rmtree(tmp_path)
