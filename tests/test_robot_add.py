"""``planbench robot add`` (planbench.problems.robot_setup) and continuous joints in the robot loader.

A small URDF of primitives (below) has every case of the collision-pair rules; four arms of
example-robot-data that planbench does not ship (Kinova Jaco 2, UR10, UR3, Unitree Z1) are added by
the command as a user would (slow: seconds each).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from planbench.cli.main import main
from planbench.errors import RobotFileError, UnknownNameError
from planbench.problems.robot_setup import ALWAYS_FRACTION, plan_check, propose, settings_text
from planbench.robot import CONTINUOUS_RANGE, Robot, RobotSettings, example_robot_data_dir, link_of, load_robot

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

# base (box) -j1 continuous z- link1 (a sphere of 0.6 m) -j2 y- link2 (a rod) -j3 y- link3 (a small ball,
# always inside link1's sphere: 0.1 + 0.3 m from its centre) -j4 y- link4 (a box 0.5 m further: sometimes
# touches the base or link1) -fixed- tool0 (no geometry); link4 -finger prismatic- finger (a small box),
# far: the far_post (on the base, 3 m away) touches nothing.
TOY_URDF = """<?xml version="1.0"?>
<robot name="toy">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
  <link name="far_post"><collision><origin xyz="3 0 0"/>
    <geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <joint name="post" type="fixed"><parent link="base"/><child link="far_post"/></joint>
  <joint name="j1" type="continuous"><parent link="base"/><child link="link1"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit effort="1" velocity="2"/></joint>
  <link name="link1"><collision><geometry><sphere radius="0.6"/></geometry></collision></link>
  <joint name="j2" type="revolute"><parent link="link1"/><child link="link2"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="2"/></joint>
  <link name="link2"><collision><origin xyz="0 0 0.15"/>
    <geometry><box size="0.04 0.04 0.3"/></geometry></collision></link>
  <joint name="j3" type="revolute"><parent link="link2"/><child link="link3"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="2"/></joint>
  <link name="link3"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="j4" type="revolute"><parent link="link3"/><child link="link4"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="2"/></joint>
  <link name="link4"><collision><origin xyz="0 0 0.5"/>
    <geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <joint name="tool" type="fixed"><parent link="link4"/><child link="tool0"/><origin xyz="0 0 0.55"/></joint>
  <link name="tool0"/>
  <joint name="finger_joint" type="prismatic"><parent link="link4"/><child link="finger"/><origin xyz="0 0 0.6"/>
    <axis xyz="1 0 0"/><limit lower="0.01" upper="0.04" effort="1" velocity="0.1"/></joint>
  <link name="finger"><collision><geometry><box size="0.02 0.02 0.02"/></geometry></collision></link>
</robot>
"""

ERD = example_robot_data_dir() / "robots"
ARMS = {  # the command line of each arm: one command, no edit
    "kinova": ["kinova_description/robots/kinova.urdf", "--srdf", "kinova_description/srdf/kinova.srdf"],
    "ur10": ["ur_description/urdf/ur10_robot.urdf"],
    "ur3": ["ur_description/urdf/ur3_robot.urdf"],
    "z1": ["z1_description/urdf/z1.urdf", "--srdf", "z1_description/srdf/z1.srdf", "--fix", "jointGripper"],
}


@pytest.fixture
def toy(tmp_path: Path) -> Path:
    path = tmp_path / "toy.urdf"
    path.write_text(TOY_URDF)
    return path


def _arm_args(name: str) -> list[str]:
    """The arm's command line, its files by their paths inside example-robot-data's robots/ folder
    (or, for the UR10, by a full path)."""
    args = ARMS[name]
    return [str(ERD / args[0]), *args[1:]] if name == "ur10" else args


# --- continuous joints in the loader ------------------------------------------------------------------


def test_a_continuous_joint_is_planned_over_one_turn_or_over_its_position_limits(toy: Path) -> None:
    settings = RobotSettings(name="toy", urdf=toy, ee_frame="tool0", fixed_joints={"finger_joint": 0.02})
    robot = Robot(settings)
    assert robot.continuous_joints == ("j1",)
    assert robot.nq == robot.model.nv == 4
    assert (robot.lower[0], robot.upper[0]) == CONTINUOUS_RANGE == (-math.pi, math.pi)
    assert robot.velocity_limit[0] == 2.0  # the URDF's <limit velocity> is kept
    wide = Robot(settings.replace(position_limits={"j1": (-2 * math.pi, 2 * math.pi)}))
    assert (wide.lower[0], wide.upper[0]) == (-2 * math.pi, 2 * math.pi)


def test_kinova_with_continuous_joints_loads_without_editing_its_urdf() -> None:
    robot = Robot(
        RobotSettings(
            name="kinova", urdf=ERD / "kinova_description/robots/kinova.urdf", ee_frame="j2s6s200_end_effector"
        )
    )
    assert robot.continuous_joints == ("j2s6s200_joint_1", "j2s6s200_joint_4", "j2s6s200_joint_6")
    assert robot.nq == 6
    assert np.allclose(robot.lower[[0, 3, 5]], -math.pi) and np.allclose(robot.upper[[0, 3, 5]], math.pi)


# --- the proposal on the toy URDF ---------------------------------------------------------------------


def test_the_toy_proposal_follows_moveits_rules(toy: Path) -> None:
    p = propose(toy, ee_frame="tool0", samples=500)
    reasons = {(d.a, d.b): d.reason for d in p.disabled}
    # adjacent: parent/child links with geometry; far_post is fixed to the base (one body for pinocchio)
    for pair in [("base", "link1"), ("link1", "link2"), ("link2", "link3"), ("link3", "link4"), ("finger", "link4")]:
        assert reasons[pair] == "adjacent", pair
    assert reasons[("link1", "link3")] == "always"  # inside link1's sphere in every sample
    always = next(d for d in p.disabled if d.reason == "always")
    assert always.fraction >= ALWAYS_FRACTION
    assert reasons[("far_post", "link2")] == "never"  # 3 m away
    assert ("link1", "link4") in p.kept or ("base", "link4") in p.kept  # sometimes in collision: still checked
    assert not set(p.kept) & set(reasons)
    # the finger is off the chain to tool0: held at its default (0 is outside [0.01, 0.04]: mid-range)
    assert p.settings.fixed_joints == {"finger_joint": pytest.approx(0.025)}
    assert p.continuous == ("j1",)
    assert p.settings.position_limits == {"j1": CONTINUOUS_RANGE}


def test_the_written_file_loads_and_continuous_joints_get_the_documented_range(toy: Path, tmp_path: Path) -> None:
    p = propose(toy, ee_frame="tool0", samples=500)
    out = tmp_path / "toy.toml"
    out.write_text(settings_text(p, out))
    raw = tomllib.loads(out.read_text())
    assert raw["position_limits"] == {"j1": [-math.pi, math.pi]}
    assert raw["urdf"] == "toy.urdf"  # beside the settings file: they move together
    robot = load_robot(out)
    assert robot.joint_names == ("j1", "j2", "j3", "j4")
    assert robot.settings.ee_frame == "tool0"
    assert len(robot.home) == 4 and not robot.limit_violations(robot.home)
    # every disabled pair is off the robot's self-collision pairs
    geoms = robot.collision_model.geometryObjects
    checked = {
        frozenset((link_of(geoms[c.first].name), link_of(geoms[c.second].name)))
        for c in robot.collision_model.collisionPairs
    }
    assert not checked & {frozenset((d.a, d.b)) for d in p.disabled}


def test_the_same_seed_gives_the_same_file_and_another_may_differ(toy: Path, tmp_path: Path) -> None:
    out = tmp_path / "toy.toml"
    a = settings_text(propose(toy, ee_frame="tool0", samples=300, seed=3), out)
    b = settings_text(propose(toy, ee_frame="tool0", samples=300, seed=3), out)
    assert a == b
    assert "seed 3" in a


def test_the_tool_frame_proposed_is_the_leaf_with_most_movable_joints(toy: Path) -> None:
    p = propose(toy, samples=50)
    assert p.settings.ee_frame == "finger"  # 5 movable joints above it, tool0 has 4
    assert p.settings.fixed_joints == {}
    held = propose(toy, samples=50, fixed={"finger_joint": 0.03})
    assert held.settings.fixed_joints == {"finger_joint": 0.03}


def test_a_pair_touching_at_the_default_configuration_and_in_other_ones_stays_checked() -> None:
    """The Z1 rests folded at all-zero joints, link02 on link06; they touch in other configurations
    too, so the pair is checked (MoveIt's assistant would disable it), and home is free of it."""
    p = propose(
        "z1_description/urdf/z1.urdf", "z1_description/srdf/z1.srdf", fixed={"jointGripper": None}, samples=2000
    )
    assert ("link02", "link06") in p.default_kept and ("link02", "link06") in p.kept
    assert ("link02", "link06") not in {(d.a, d.b) for d in p.disabled}
    assert p.settings.home != (0.0,) * 6 and p.home_source == "the SRDF's group_state 'arm_up'"


# --- the command ---------------------------------------------------------------------------------------


def test_bad_input_is_a_named_error_with_exit_code_2(
    toy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = str(tmp_path / "r.toml")
    assert main(["robot", "add", str(tmp_path / "missing.urdf"), "--out", out]) == 2
    assert "no such file" in capsys.readouterr().err
    not_xml = tmp_path / "notes.urdf"
    not_xml.write_text("this is not XML\n")
    assert main(["robot", "add", str(not_xml), "--out", out]) == 2
    assert "not a URDF" in capsys.readouterr().err
    srdf_like = tmp_path / "arm.xml"
    srdf_like.write_text("<scene/>")
    assert main(["robot", "add", str(srdf_like), "--out", out]) == 2
    assert "root element is <scene>" in capsys.readouterr().err
    assert main(["robot", "add", str(toy), "--ee-frame", "tool9", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "unknown link" in err and "tool0" in err
    assert main(["robot", "add", str(toy), "--fix", "nope", "--out", out]) == 2
    assert "unknown movable joint" in capsys.readouterr().err
    assert main(["robot", "add", str(toy), "--out", str(tmp_path / "r.json")]) == 2
    assert ".toml" in capsys.readouterr().err
    assert not Path(out).exists()
    with pytest.raises(RobotFileError):
        propose(not_xml)
    with pytest.raises(UnknownNameError):
        propose(toy, ee_frame="nope")


def test_the_command_will_not_overwrite_a_file_without_force(
    toy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "toy.toml"
    out.write_text("# mine\n")
    assert main(["robot", "add", str(toy), "--out", str(out), "--no-check", "--samples", "50"]) == 2
    assert out.read_text() == "# mine\n"
    assert main(["robot", "add", str(toy), "--out", str(out), "--no-check", "--samples", "50", "--force"]) == 0
    assert load_robot(out).nq == 5


@pytest.mark.slow
@pytest.mark.parametrize("arm", sorted(ARMS))
def test_each_new_arm_is_added_by_one_command_and_plans(
    arm: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / f"{arm}.toml"
    assert main(["robot", "add", *_arm_args(arm), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "plan check: ompl-rrtconnect planned" in printed
    robot = load_robot(out)
    assert robot.name == arm and robot.nq == 6
    text = out.read_text()
    assert str(ERD) not in text  # example-robot-data's files by their path inside it, as shipped robots do
    raw = tomllib.loads(text)
    assert len(raw["ignore_collision_pairs"]) > 5


@pytest.mark.slow
def test_a_new_arm_solves_a_generated_problem_with_rrtconnect_and_the_guided_field(tmp_path: Path) -> None:
    import planbench
    from planbench.problems.generators import write_problem_files

    out = tmp_path / "ur3.toml"
    assert main(["robot", "add", *_arm_args("ur3"), "--out", str(out), "--no-check"]) == 0
    assert plan_check(out).success
    (path,) = write_problem_files(tmp_path / "gen", [str(out)], ["pillars"], 1, log=lambda _: None)
    problem = planbench.load_problems(path)[0]
    assert problem.robot.name == "ur3" and problem.id == "gen:ur3_pillars/0001"
    for planner in ("ompl-rrtconnect", "matrix-field-guided"):
        result = planbench.plan(problem, planner, seed=0, time_limit=10.0)
        assert planbench.evaluate(problem, result).success, planner
