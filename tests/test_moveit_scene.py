"""MoveIt's text scenes (``.scene``): read as MoveIt writes them (both layouts), written back, refused
with the line at fault, and used with a robot (planbench.geometry.moveit_scene)."""

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

import planbench
from planbench import Obstacle, Problem, Scene
from planbench.checking.collision import CollisionChecker
from planbench.errors import PlanbenchError, ProblemFileError
from planbench.geometry.moveit_scene import MoveItSceneError, default_mesh_dir

DATA = Path(__file__).parent / "data" / "moveit"
NEW = DATA / "panda_table.scene"  # MoveIt >= 1.1 / MoveIt 2: object poses and subframes
OLD = DATA / "old_layout.scene"  # MoveIt before 1.0: shape poses in the scene frame
S = 0.5**0.5


def by_name(scene):
    return {o.name: o for o in scene.obstacles}


@pytest.fixture
def meshes(tmp_path):
    return tmp_path / "meshes"


def test_the_new_layout_reads_as_moveit_places_its_shapes(meshes):
    scene = Scene.load(NEW, mesh_dir=meshes)
    assert scene.name == "panda_table"
    o = by_name(scene)
    assert list(o) == ["table", "bottle", "fixture/0", "fixture/1", "tetra"]  # colours, subframes dropped
    assert o["table"].type == "box" and o["table"].size == (0.4, 0.8, 0.04)
    np.testing.assert_allclose(o["table"].position, (0.6, 0, 0.2))
    # the bottle: a cylinder along its local z, turned 90 degrees about y: its axis is the scene's x
    bottle = o["bottle"]
    assert (bottle.type, bottle.radius, bottle.length) == ("cylinder", 0.03, 0.2)
    np.testing.assert_allclose(bottle.rotation @ [0, 0, 1], [1, 0, 0], atol=1e-9)
    centre = np.array([0.5, -0.3, 0.35])
    assert bottle.contains(centre + [[0.09, 0, 0], [0, 0, 0.02]]).tolist() == [True, True]
    assert bottle.contains(centre + [[0.11, 0, 0], [0, 0, 0.04], [0, 0.04, 0]]).tolist() == [False] * 3
    # two shapes of one object: the object's pose (turned 90 degrees about z) times each shape's pose
    np.testing.assert_allclose(o["fixture/0"].position, (0.3, 0.5, 0.5), atol=1e-9)
    assert o["fixture/0"].radius == 0.05
    part = o["fixture/1"]
    np.testing.assert_allclose(part.position, (0.3, 0.4, 0.6), atol=1e-9)
    expected = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]])  # Rz(90) Rx(90)
    np.testing.assert_allclose(part.rotation, expected, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(part.orientation_xyzw), 1.0, atol=1e-12)  # normalised


def test_a_mesh_is_written_once_as_an_obj_file_with_its_vertices_and_triangles(meshes):
    tetra = by_name(Scene.load(NEW, mesh_dir=meshes))["tetra"]
    assert Path(tetra.path).parent == meshes and tetra.path.endswith(".obj")
    mesh = trimesh.load(tetra.path, force="mesh", process=False)
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]])
    np.testing.assert_array_equal(mesh.faces, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    np.testing.assert_allclose(tetra.position, (-0.4, 0.2, 0.1))
    before = {p: p.stat().st_mtime_ns for p in meshes.iterdir()}
    assert by_name(Scene.load(NEW, mesh_dir=meshes))["tetra"].path == tetra.path  # named by content
    assert {p: p.stat().st_mtime_ns for p in meshes.iterdir()} == before


def test_meshes_go_to_the_user_cache_unless_told(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert default_mesh_dir() == tmp_path / "cache" / "planbench" / "moveit-meshes"
    tetra = by_name(Scene.load(NEW))["tetra"]
    assert Path(tetra.path).parent == default_mesh_dir()


def test_the_old_layout_has_no_object_poses_and_no_subframes(meshes):
    scene = Scene.load(OLD, mesh_dir=meshes)
    assert scene.name == "old_scene"
    o = by_name(scene)
    assert o["box1"].size == (0.1, 0.1, 0.1)
    np.testing.assert_allclose(o["box1"].position, (0.5, 0, 0.5))
    can = o["can"]  # turned 90 degrees about x: its axis is the scene's y
    np.testing.assert_allclose(can.position, (0.4, 0.3, 0.2))
    np.testing.assert_allclose(can.rotation @ [0, 0, 1], [0, -1, 0], atol=1e-6)
    assert can.contains(np.array([[0.4, 0.35, 0.2], [0.4, 0.3, 0.23]])).all()
    assert not can.contains(np.array([[0.4, 0.3, 0.25]])).any()
    assert not meshes.exists()  # no mesh, nothing written


def test_a_scene_saved_as_moveit_text_reads_back(tmp_path, meshes):
    scene = Scene.load(NEW, mesh_dir=meshes)
    scene.save(tmp_path / "again.scene")
    again = Scene.load(tmp_path / "again.scene", mesh_dir=meshes)
    assert again.name == scene.name
    for a, b in zip(scene.obstacles, again.obstacles, strict=True):
        fields = ("name", "type", "size", "radius", "length", "path")
        assert [getattr(a, f) for f in fields] == [getattr(b, f) for f in fields]
        np.testing.assert_allclose(a.position, b.position, atol=1e-15)
        np.testing.assert_allclose(a.orientation_xyzw, b.orientation_xyzw, atol=1e-15)


def test_the_written_text_is_moveits_new_layout(tmp_path):
    scene = Scene(
        (
            Obstacle("table top", "box", position=(0.5, 0, -0.02), size=(1.0, 0.6, 0.04)),
            Obstacle("can", "cylinder", (0.1, 0.2, 0.3), (S, 0, 0, S), radius=0.03, length=0.1),
        ),
        "lab",
    )
    scene.save(tmp_path / "lab.scene")
    s = repr(S)
    assert (tmp_path / "lab.scene").read_text() == (
        "lab\n"
        "* table top\n0.5 0 -0.02\n0 0 0 1\n1\nbox\n1 0.6 0.04\n0 0 0\n0 0 0 1\n0 0 0 0\n0\n"
        f"* can\n0.1 0.2 0.3\n{s} 0 0 {s}\n1\ncylinder\n0.03 0.1\n0 0 0\n0 0 0 1\n0 0 0 0\n0\n"
        ".\n"
    )
    assert Scene.load(tmp_path / "lab.scene") == scene  # every number reads back exactly


def test_a_mesh_obstacle_is_written_with_its_scale_and_facing_out(tmp_path, meshes):
    tetra = by_name(Scene.load(NEW, mesh_dir=meshes))["tetra"]
    mirrored = Obstacle("m", "mesh", path=tetra.path, scale=(2.0, -1.0, 1.0))
    Scene((mirrored,)).save(tmp_path / "m.scene")
    back = by_name(Scene.load(tmp_path / "m.scene", mesh_dir=meshes))["m"]
    mesh = trimesh.load(back.path, force="mesh", process=False)
    np.testing.assert_allclose(mesh.vertices, [[0, 0, 0], [0.2, 0, 0], [0, -0.1, 0], [0, 0, 0.1]])
    assert mesh.is_winding_consistent and mesh.volume > 0  # the mirror's triangles turned to face out


@pytest.mark.parametrize(
    "obstacle",
    [
        Obstacle("arm", "capsule", radius=0.05, length=0.3),
        Obstacle(" shelf", "box", size=(1, 1, 1)),  # MoveIt would read its name back trimmed
    ],
    ids=["capsule", "untrimmed-name"],
)
def test_what_moveit_cannot_hold_is_refused_when_saving(tmp_path, obstacle):
    with pytest.raises(MoveItSceneError, match=repr(obstacle.name)):
        Scene((obstacle,)).save(tmp_path / "x.scene")


def _cut(text: str, lines: int) -> str:
    return "\n".join(text.split("\n")[:lines]) + "\n"


def _replace_line(text: str, line: int, new: str) -> str:
    rows = text.split("\n")
    rows[line - 1] = new
    return "\n".join(rows)


NEW_TEXT = NEW.read_text()
MALFORMED = {
    "truncated": (_cut(NEW_TEXT, 16), 16, "file ends where object 'bottle', shape 1 of 1: cylinder radius"),
    "truncated-mesh": (_cut(NEW_TEXT, 51), 51, "a mesh vertex coordinate"),
    "no-end-marker": (NEW_TEXT.replace("\n.\n", "\n"), 60, r"ends where an object \('\* <id>'\) or the end"),
    "nan-size": (_replace_line(NEW_TEXT, 7, "0.4 nan 0.04"), 7, "box size y must be a finite number, got 'nan'"),
    "overflow": (_replace_line(NEW_TEXT, 3, "0.6 0 1e999"), 3, "its pose: the position x y z must be a finite"),
    "negative-size": (_replace_line(NEW_TEXT, 7, "0.4 -0.8 0.04"), 7, "box size y must be > 0"),
    "bad-count": (_replace_line(NEW_TEXT, 5, "one"), 5, "the number of shapes must be a whole number"),
    "count-too-high": (_replace_line(NEW_TEXT, 15, "2"), 21, "'bottle', shape 2 of 2: unknown shape type '0'"),
    "unknown-shape": (_replace_line(NEW_TEXT, 6, "torus"), 6, "unknown shape type 'torus'"),
    "cone": (_replace_line(NEW_TEXT, 16, "cone"), 16, "'bottle', shape 1 of 1 is a cone.*by a cylinder"),
    "plane": (_replace_line(_replace_line(NEW_TEXT, 6, "plane"), 7, "0 0 1 0"), 6, "is a plane.*thin box"),
    "index-out-of-range": (_replace_line(NEW_TEXT, 55, "1 2 4"), 55, "vertex index must be below 4, got 4"),
    "huge-count": (_replace_line(NEW_TEXT, 48, "999999999999 1"), 61, "vertex coordinate must be a finite .*got '.'"),
    "no-triangles": (_replace_line(NEW_TEXT, 48, "4 0"), 48, "a mesh without triangles"),
    "not-a-rotation": (_replace_line(NEW_TEXT, 14, "0 0.5 0 0.5"), 14, r"is not a rotation \(norm 0.707107"),
    "duplicate": (NEW_TEXT.replace("* bottle", "* table"), 12, r"'table' appears twice \(lines 2 and 12\)"),
    "bad-marker": (NEW_TEXT.replace("* tetra", "*tetra"), 43, r"got '\*tetra'"),
    "no-id": (NEW_TEXT.replace("* tetra", "*"), 43, "without the object's id"),
    "empty": ("", 1, "the file is empty"),
}


@pytest.mark.parametrize("text, line, message", MALFORMED.values(), ids=MALFORMED.keys())
def test_a_malformed_file_is_a_named_error_with_its_line(tmp_path, meshes, text, line, message):
    path = tmp_path / "bad.scene"
    path.write_text(text)
    with pytest.raises(MoveItSceneError, match=message) as info:
        Scene.load(path, mesh_dir=meshes)
    assert isinstance(info.value, ProblemFileError)  # what a problem's loader and the CLI report
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}: line {line}: ")


def test_an_unreadable_path_is_a_named_error(tmp_path):
    with pytest.raises(MoveItSceneError, match="no such file"):
        Scene.load(tmp_path / "missing.scene")
    (tmp_path / "folder.scene").mkdir()
    with pytest.raises(MoveItSceneError, match="it is a folder"):
        Scene.load(tmp_path / "folder.scene")


def test_a_mesh_folder_that_cannot_be_written_is_named(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(PlanbenchError, match="cannot write the mesh of object 'tetra'.*give Scene.load a mesh_dir"):
        Scene.load(NEW, mesh_dir=tmp_path / "file")


@pytest.fixture(scope="module")
def panda_problem():
    return planbench.load_problems("mbm:table_pick/0001")[0]


def _scene_with_a_box_at(point) -> str:
    """A .scene text as MoveIt 2 writes it: one 10 cm box at ``point``, 6 significant digits."""
    x, y, z = (f"{v:g}" for v in point)
    return f"hand_box\n* box\n{x} {y} {z}\n0 0 0 1\n1\nbox\n0.1 0.1 0.1\n0 0 0\n0 0 0 1\n0 0 0 0\n0\n.\n"


def test_a_problem_from_a_robot_and_a_moveit_scene_collides_where_the_box_is(tmp_path, panda_problem):
    robot, start = panda_problem.robot, panda_problem.start
    away = start.copy()
    away[0] += np.pi / 2  # the whole arm turned a quarter about the base
    hand = robot.frame_pose(start).translation
    assert np.linalg.norm(robot.frame_pose(away).translation - hand) > 0.4
    path = tmp_path / "hand_box.scene"
    path.write_text(_scene_with_a_box_at(hand))
    problem = Problem.create(robot, Scene.load(path), start, goal_q=away, id="moveit")
    checker = CollisionChecker.for_problem(problem)
    assert checker.in_collision(start)
    assert any(b == "obstacle:box" for _, b in checker.collisions(start))
    assert not checker.in_collision(away)
    assert not CollisionChecker(robot, Scene()).in_collision(start)  # the box, not the arm itself
    assert problem.check().start and not problem.check().goal_configuration


def test_a_problem_file_may_name_a_moveit_scene(tmp_path, panda_problem):
    (tmp_path / "lab.scene").write_text(OLD.read_text())
    d = panda_problem.to_dict()
    d["scene"] = "lab.scene"  # relative to the problem file
    (tmp_path / "p.json").write_text(json.dumps(d))
    problem = Problem.load(tmp_path / "p.json")
    assert [o.name for o in problem.scene.obstacles] == ["box1", "can"]
