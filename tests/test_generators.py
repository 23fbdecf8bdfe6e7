"""planbench.problems.generators: seeded scene families for any arm, and the shipped ``gen:`` set."""

from __future__ import annotations

import hashlib
import json
from importlib import resources

import numpy as np
import pytest

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.errors import UnknownNameError
from planbench.problems import generators
from planbench.problems.datasets import problem_sets
from planbench.robot import Robot, RobotSettings, example_robot_data_dir
from planbench.scene import Scene
from planbench.validate import verdict_checker

GEN_DIR = resources.files("planbench") / "data" / "gen"


def _ur10() -> Robot:
    """A third arm, not in robots/: the UR10 of example-robot-data (reach 1.55 m against the UR5's 1.08 m)."""
    d = example_robot_data_dir() / "robots" / "ur_description"
    settings = RobotSettings(
        name="ur10",
        urdf=d / "urdf" / "ur10_joint_limited_robot.urdf",
        srdf=d / "srdf" / "ur5.srdf",  # same link names
        ee_frame="tool0",
        home=(0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0),
    )
    return Robot(settings)


def _problem_lines(text: str) -> list[str]:
    return [line.rstrip(",") for line in text.splitlines() if line.startswith('  {"id":')]


def test_same_seed_same_problem_other_seed_other_problem():
    a = generators.generate_problem("ur5", "window", 3)
    b = generators.generate_problem("ur5", "window", 3)
    assert a.to_dict() == b.to_dict()
    c = generators.generate_problem("ur5", "window", 3, seed=1)
    assert c.id == "gen-s1:ur5_window/0003"
    assert c.to_dict()["scene"] != a.to_dict()["scene"]


@pytest.mark.parametrize("family", generators.FAMILIES)
def test_regenerating_gives_the_shipped_bytes(family):
    """The first two problems of each shipped UR5 file come out byte for byte (the whole set: slow test)."""
    text, entry = generators.family_file(planbench.load_robot("ur5"), family, 2)
    again, _ = generators.family_file(planbench.load_robot("ur5"), family, 2)
    assert text == again
    shipped = (GEN_DIR / f"ur5_{family}.json").read_text()
    assert _problem_lines(text) == _problem_lines(shipped)[:2]
    assert text.split('"problems"')[0] == shipped.split('"problems"')[0]  # the header


def _same_numbers(a, b, tol: float) -> bool:
    """``a == b`` for parsed JSON, numbers within ``tol``."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same_numbers(a[k], b[k], tol) for k in a)
    if isinstance(a, list):
        same = isinstance(b, list) and len(a) == len(b)
        return same and all(_same_numbers(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(b, (int, float)) and abs(a - b) <= tol
    return a == b


@pytest.mark.slow
def test_regenerating_the_whole_set_gives_the_shipped_problems(tmp_path):
    """The same scenes, starts and goals, every number within 1e-4 (rad or m). Not byte for byte:
    goal IK runs through OpenBLAS, whose kernels differ by processor, and one UR5 pillars goal
    comes out 7e-5 rad apart on a Haswell kernel (the same 1e-6-rounded file on one machine)."""
    generators.main(["--out", str(tmp_path)])
    for name in [f"{s}.json" for s in generators.shipped_sets()]:
        again, shipped = json.loads((tmp_path / name).read_text()), json.loads((GEN_DIR / name).read_text())
        assert _same_numbers(again, shipped, 1e-4), name
    again, shipped = (json.loads((d / "manifest.json").read_text()) for d in (tmp_path, GEN_DIR))
    for entry in [*again["sets"].values(), *shipped["sets"].values()]:
        entry.pop("sha256")
    assert again == shipped


def test_manifest_matches_the_files():
    manifest = json.loads((GEN_DIR / "manifest.json").read_text())
    assert manifest["generator"] == generators.GENERATOR
    robots = ("panda", "ur5", "xarm7")
    assert generators.SHIPPED_ROBOTS == robots
    assert sorted(manifest["sets"]) == [f"{r}_{f}" for r in robots for f in sorted(generators.FAMILIES)]
    for name, entry in manifest["sets"].items():
        text = (GEN_DIR / entry["file"]).read_text()
        assert hashlib.sha256(text.encode()).hexdigest() == entry["sha256"], name
        data = json.loads(text)
        assert len(data["problems"]) == entry["problems"] == 25
        assert [p["index"] for p in data["problems"]] == list(range(1, 26))
    assert (GEN_DIR / "README.md").read_text().count(generators.COMMAND) >= 1


def test_shipped_problems_are_valid():
    """Every shipped start and goal within limits and collision-free, the goal's end effector on its
    target; on a sample, the straight line collides (no trivial problem)."""
    problems = planbench.load_problems("gen")
    assert len(problems) == 300
    assert len({p.id for p in problems}) == 300
    for p in problems:
        assert p.check().ok, (p.id, p.check().messages())
        assert np.linalg.norm(p.goal.pose.position - np.array(p.metadata["target"])) < 1e-3, p.id
        assert p.metadata["generator"] == generators.GENERATOR and p.metadata["seed"] == 0
    for p in problems[::25]:
        assert not verdict_checker(p).check_path(np.stack([p.start, p.goal.q])).free, p.id


def test_loaded_problem_equals_the_generated_one():
    loaded = planbench.load_problems("gen:ur5_pillars/0002")[0]
    made = generators.generate_problem("ur5", "pillars", 2)
    assert loaded.to_dict() == made.to_dict()


def test_selectors():
    three = planbench.load_problems("gen:ur5_shelf/0001-0003")
    assert [p.id for p in three] == [f"gen:ur5_shelf/000{i}" for i in (1, 2, 3)]
    assert all(p.robot.name == "ur5" and p.metadata["family"] == "shelf" for p in three)
    ur5 = planbench.load_problems("gen:ur5_*")
    assert len(ur5) == 100 and {p.robot.name for p in ur5} == {"ur5"}
    windows = planbench.load_problems("gen:*_window/0007")
    assert [p.id for p in windows] == ["gen:panda_window/0007", "gen:ur5_window/0007", "gen:xarm7_window/0007"]
    assert planbench.problems.datasets.load_problem("gen:panda_table_clutter/0025").robot.name == "panda"
    assert "gen" in problem_sets() and "ur5_pillars" in problem_sets()["gen"]
    full, bare = (planbench.load_problems(f"gen:ur5_table_clutter/0002{s}")[0] for s in ("", ":bare"))
    assert bare.id == "gen:ur5_table_clutter/0002:bare" and bare.scene.name == full.scene.name + "-bare"
    assert {o.name for o in bare.scene.obstacles} == {o.name for o in full.scene.obstacles if o.name[:6] != "object"}
    assert "table_top" in {o.name for o in bare.scene.obstacles}
    assert len(bare.scene.obstacles) < len(full.scene.obstacles)
    assert len(planbench.load_problems("gen:xarm7_*/0001:bare")) == 4


def test_the_xarm7_loads_with_its_limits_and_a_free_home():
    robot = planbench.load_robot("xarm7")
    assert robot.nq == 7 and robot.settings.ee_frame == "link_eef"
    assert np.allclose(robot.model.velocityLimit, 3.14)  # the URDF's, every joint
    home = np.array(robot.settings.home)
    assert not robot.limit_violations(home)
    assert not CollisionChecker(robot, Scene()).in_collision(home)  # no self-contact
    assert all(p.robot.name == "xarm7" for p in planbench.load_problems("gen:xarm7_table_clutter/0001-0003"))


def test_unknown_family_is_named():
    with pytest.raises(UnknownNameError, match="ur5_kitchen"):
        planbench.load_problems("gen:ur5_kitchen")
    with pytest.raises(UnknownNameError, match="kitchen"):
        generators.generate_problem("ur5", "kitchen", 1)
    with pytest.raises(planbench.PlanbenchError, match="0001-0025"):
        planbench.load_problems("gen:ur5_shelf/0026")


def test_every_family_works_for_a_third_robot():
    robot = _ur10()
    ws = generators.workspace(robot)
    assert ws.reach > 1.3 * generators.workspace(planbench.load_robot("ur5")).reach
    for family in generators.FAMILIES:
        p = generators.generate_problem(robot, family, 1)
        assert p.robot is robot and p.id == f"gen:ur10_{family}/0001"
        assert p.check().ok, p.check().messages()
        floor = next(o for o in p.scene.obstacles if o.name == "floor")
        assert floor.size is not None and floor.size[0] == pytest.approx(2.2 * ws.reach, abs=1e-3)  # scaled to the arm


def test_cli_writes_a_set(tmp_path, capsys):
    assert generators.main(["--out", str(tmp_path), "--robots", "ur5", "--families", "window", "-n", "2"]) == 0
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert list(manifest["sets"]) == ["ur5_window"]
    data = json.loads((tmp_path / "ur5_window.json").read_text())
    problems = [generators.problem_from_record(rec, data) for rec in data["problems"]]
    assert [p.id for p in problems] == ["gen:ur5_window/0001", "gen:ur5_window/0002"]
    capsys.readouterr()
    assert generators.main(["--out", str(tmp_path), "--families", "kitchen"]) == 2  # a named error, exit code 2
    err = capsys.readouterr().err
    assert "unknown generator family 'kitchen'" in err and "Traceback" not in err
