"""Portable bundles (planbench.problems.bundle): a problem folder that loads anywhere."""

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import planbench
import planbench.robot
from planbench import Problem, Scene
from planbench.checking.collision import CollisionChecker
from planbench.errors import OutputFileError, RobotFileError
from planbench.problems.bundle import resolve_resource, save_bundle
from planbench.robot import load_robot, package_dirs
from planbench.scene import Obstacle

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


@pytest.fixture
def hide_example_robot_data(monkeypatch):
    """Call it to go on as if example-robot-data were not installed and no ROS package path were
    set: a robot file found after that can only come from the bundle itself."""

    def missing():
        raise RobotFileError("example-robot-data", "the package is not installed (test)")

    def hide():
        monkeypatch.setattr(planbench.robot, "example_robot_data_dir", missing)
        monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
        planbench.robot._cached_robot.cache_clear()
        with pytest.raises(RobotFileError, match="not installed"):
            load_robot("panda")  # the shipped robot's settings name example-robot-data's files

    yield hide
    planbench.robot._cached_robot.cache_clear()


def _files(folder):
    return sorted(p for p in folder.rglob("*") if p.is_file())


def _paths_in_bundle(folder):
    """Every file name a bundle's JSON, TOML and URDF files hold, as written."""
    names = []
    for path in _files(folder):
        if path.suffix == ".json":
            d = json.loads(path.read_text())
            names.append(d["robot"])
            names += [o["path"] for o in d["scene"]["obstacles"] if "path" in o]
        elif path.suffix == ".toml":
            raw = tomllib.loads(path.read_text())
            names += [raw["urdf"], raw.get("srdf")]
        elif path.suffix == ".urdf":
            import xml.etree.ElementTree as ET

            names += [m.get("filename") for m in ET.parse(path).getroot().iter("mesh")]
    return [n for n in names if n]


def _verdicts(problem, configurations):
    checker = CollisionChecker.for_problem(problem)
    return [checker.collisions(q) for q in configurations]


def _same_problem(a, b, configurations, verdicts):
    """``b`` is ``a`` read back; ``verdicts``: ``a``'s collisions at ``configurations``."""
    np.testing.assert_array_equal(a.start, b.start)
    np.testing.assert_array_equal(a.goal.q, b.goal.q)
    np.testing.assert_allclose(a.goal.pose.position, b.goal.pose.position)
    np.testing.assert_allclose(a.goal.pose.rotation, b.goal.pose.rotation, atol=1e-12)
    assert a.id == b.id and a.tolerances == b.tolerances
    assert [o.name for o in a.scene.obstacles] == [o.name for o in b.scene.obstacles]
    assert a.robot.name == b.robot.name and a.robot.joint_names == b.robot.joint_names
    np.testing.assert_array_equal(a.robot.lower, b.robot.lower)
    np.testing.assert_array_equal(a.robot.upper, b.robot.upper)
    np.testing.assert_array_equal(a.robot.velocity_limit, b.robot.velocity_limit)
    np.testing.assert_array_equal(a.robot.home, b.robot.home)
    assert a.robot.collision_model.ngeoms == b.robot.collision_model.ngeoms
    assert len(a.robot.collision_model.collisionPairs) == len(b.robot.collision_model.collisionPairs)
    assert _verdicts(b, configurations) == verdicts


def _configurations(problem, n=12):
    rng = np.random.default_rng(3)
    r = problem.robot
    return [problem.start, problem.goal.q] + [rng.uniform(r.lower, r.upper) for _ in range(n)]


def test_a_bundled_panda_problem_loads_after_a_move_without_example_robot_data(
    tmp_path, monkeypatch, hide_example_robot_data
):
    original = planbench.load_problems("mbm:box/0001")[0]
    configurations = _configurations(original)
    verdicts = _verdicts(original, configurations)
    (out,) = save_bundle(original, tmp_path / "made" / "here", ["problem.json"])  # folders made
    assert out == tmp_path / "made" / "here" / "problem.json"
    folder = out.parent
    names = _paths_in_bundle(folder)
    assert len(names) > 10  # robot TOML, URDF, SRDF, meshes
    for name in names:  # every reference is relative and inside the bundle
        assert not Path(name).is_absolute() and "://" not in name and ".." not in Path(name).parts, name
    moved = tmp_path / "elsewhere" / "bundle"
    shutil.copytree(folder, moved)
    shutil.rmtree(folder)
    monkeypatch.chdir(tmp_path)
    hide_example_robot_data()
    back = Problem.load(moved / "problem.json")
    # the robot came from the bundle: its files, and every collision mesh pinocchio loaded
    assert back.robot.settings.urdf.is_relative_to(moved.resolve())
    assert back.robot.settings.srdf.is_relative_to(moved.resolve())
    meshes = [Path(g.meshPath) for g in back.robot.collision_model.geometryObjects if "/" in g.meshPath]
    assert meshes and all(m.resolve().is_relative_to(moved.resolve()) for m in meshes)
    _same_problem(original, back, configurations, verdicts)
    assert any(verdicts) and not all(verdicts)  # the comparison saw both verdicts


def test_a_bundle_takes_the_scenes_mesh_and_point_cloud_files_along(tmp_path, hide_example_robot_data):
    import trimesh

    from planbench.geometry.pointcloud import write_points

    assets = tmp_path / "assets"
    assets.mkdir()
    trimesh.creation.box((0.3, 0.3, 0.3)).export(assets / "block.stl")
    write_points(assets / "cloud.npz", np.array([[0.0, 0.5, 0.5], [0.02, 0.5, 0.5]]))
    other = tmp_path / "other"
    other.mkdir()
    shutil.copyfile(assets / "block.stl", other / "block.stl")  # the same name twice
    scene = Scene(
        (
            Obstacle("block", "mesh", position=(0.3, 0.0, 0.75), path=str(assets / "block.stl")),
            Obstacle("again", "mesh", position=(-0.5, 0.0, 0.3), path=str(other / "block.stl")),
            Obstacle("cloud", "pointcloud", radius=0.02, path=str(assets / "cloud.npz")),
        )
    )
    panda = load_robot("panda")
    original = Problem.create(panda, scene, panda.home, goal_q=panda.home, id="meshy")
    configurations = _configurations(original)
    verdicts = _verdicts(original, configurations)
    [out] = save_bundle(original, tmp_path / "bundle")
    assert out.name == "meshy.json"
    paths = [o["path"] for o in json.loads(out.read_text())["scene"]["obstacles"]]
    assert paths == ["scene-files/block.stl", "scene-files/block-2.stl", "scene-files/cloud.npz"]
    moved = tmp_path / "moved"
    shutil.move(tmp_path / "bundle", moved)
    shutil.rmtree(assets)
    shutil.rmtree(other)
    hide_example_robot_data()
    back = Problem.load(moved / "meshy.json")
    assert all(Path(o.path).is_relative_to(moved) for o in back.scene.obstacles)
    _same_problem(original, back, configurations, verdicts)
    hit = {obstacle.removeprefix("obstacle:") for v in verdicts for _, obstacle in v}
    assert hit & {"block", "again", "cloud"}  # the scene files take part in the verdicts


def test_a_suite_bundle_writes_each_robot_and_file_once(tmp_path, hide_example_robot_data):
    problems = planbench.load_problems("mbm:box/0001") + planbench.load_problems("mbm:box/0002")
    for name in ("ur5", "xarm7"):
        robot = load_robot(name)
        problems.append(Problem.create(robot, Scene(), robot.home, goal_q=robot.home, id=name))
    configurations = [_configurations(p, 4) for p in problems]
    verdicts = [_verdicts(p, c) for p, c in zip(problems, configurations, strict=True)]
    paths = save_bundle(problems, tmp_path / "suite")
    hide_example_robot_data()
    assert [p.name for p in paths] == ["mbm_box_0001.json", "mbm_box_0002.json", "ur5.json", "xarm7.json"]
    assert sorted(p.name for p in (tmp_path / "suite" / "robots").glob("*.toml")) == [
        "panda.toml",
        "ur5.toml",
        "xarm7.toml",
    ]
    for path, problem, qs, v in zip(paths, problems, configurations, verdicts, strict=True):
        _same_problem(problem, Problem.load(path), qs, v)


def test_the_bundle_finds_each_mesh_where_pinocchio_does():
    """Our copy of pinocchio's lookup gives, for every collision mesh of the shipped robots, the
    file pinocchio loaded."""
    import xml.etree.ElementTree as ET

    for name in planbench.robot.robot_names():
        robot = load_robot(name)
        loaded = {Path(g.meshPath).resolve() for g in robot.collision_model.geometryObjects if "/" in g.meshPath}
        root = ET.parse(robot.settings.urdf).getroot()
        found = set()
        for collision in root.iter("collision"):
            for mesh in collision.iter("mesh"):
                found.add(resolve_resource(mesh.get("filename"), package_dirs(robot.settings.urdf)))
        assert loaded and loaded <= found, name


def test_plain_save_makes_missing_folders_and_refuses_a_folder(tmp_path):
    problem = planbench.load_problems("mbm:box/0001")[0]
    out = problem.save(tmp_path / "a" / "b" / "p.json")
    assert json.loads(out.read_text())["robot"] == "panda"  # not a bundle: the shipped name
    assert Problem.load(out).robot is problem.robot
    with pytest.raises(OutputFileError, match="is a folder"):
        problem.save(tmp_path / "a")


def test_a_bundle_target_that_is_a_file_or_unwritable_is_refused(tmp_path):
    problem = planbench.load_problems("mbm:box/0001")[0]
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputFileError, match="is a file; a bundle is a folder"):
        save_bundle(problem, tmp_path / "file")
    with pytest.raises(OutputFileError, match="is a file, not a folder"):
        save_bundle(problem, tmp_path / "file" / "inside")
    if Path("/sys/kernel").is_dir():  # sysfs: no folder can be made there, not even by root
        with pytest.raises(OutputFileError, match="cannot make the bundle folder"):
            save_bundle(problem, "/sys/planbench-bundle")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        with pytest.raises(OutputFileError, match="not writable"):
            save_bundle(problem, locked)
        with pytest.raises(OutputFileError, match="cannot make the bundle folder"):
            save_bundle(problem, locked / "sub")
    finally:
        locked.chmod(0o700)


def test_a_bundle_of_a_robot_with_a_missing_mesh_names_it(tmp_path):
    panda = load_robot("panda")
    text = panda.settings.urdf.read_text().replace("visual/link3.dae", "visual/nowhere.dae")  # visual: the robot loads
    (tmp_path / "broken.urdf").write_text(text)
    robot = load_robot("panda", urdf=str(tmp_path / "broken.urdf"))
    problem = Problem.create(robot, Scene(), robot.home, goal_q=robot.home)
    with pytest.raises(RobotFileError, match="nowhere.dae.*not found"):
        save_bundle(problem, tmp_path / "bundle")


def test_planbench_bundle_writes_a_suites_problems_that_a_suite_then_names_by_folder(tmp_path, capsys):
    from planbench.bench.suite import expand_problems, load_suite
    from planbench.cli.main import main

    suite = tmp_path / "mine.toml"
    suite.write_text(
        '[suite]\nname = "mine"\nproblems = ["mbm:box/0001-0002", "mbm:cage/0001"]\n\n'
        '[[planners]]\nplanner = "straight-line"\n'
    )
    assert main(["bundle", "--suite", str(suite), "--problem", "mbm:box/0002", "--out", str(tmp_path / "b")]) == 0
    assert "3 problems bundled" in capsys.readouterr().out
    (tmp_path / "b" / "suite.toml").write_text(
        suite.read_text().replace('"mbm:box/0001-0002", "mbm:cage/0001"', '"./"')
    )
    refs = expand_problems(load_suite(tmp_path / "b" / "suite.toml").problems)
    assert [r.id for r in refs] == ["mbm:box/0001", "mbm:box/0002", "mbm:cage/0001"]
    assert main(["bundle", "--out", str(tmp_path / "c")]) == 2
    assert "--problem SELECTOR" in capsys.readouterr().err


def test_a_file_that_cannot_be_written_into_the_bundle_is_a_named_error(tmp_path, monkeypatch):
    """What a full disk or a read-only file does (root passes the permission test above)."""
    import planbench.problems.bundle

    def refuse(source, dest):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(planbench.problems.bundle.shutil, "copyfile", refuse)
    problem = planbench.load_problems("mbm:box/0001")[0]
    with pytest.raises(OutputFileError, match=r"meshes/.*: cannot copy .* Permission denied"):
        save_bundle(problem, tmp_path / "b")
