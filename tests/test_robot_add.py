"""Continuous joints in the robot loader."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from planbench.robot import CONTINUOUS_RANGE, Robot, RobotSettings, example_robot_data_dir

if sys.version_info >= (3, 11):
    pass
else:  # pragma: no cover
    pass

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
    args = ARMS[name]
    return [str(ERD / args[0]), *(str(ERD / a) if a.endswith(".srdf") else a for a in args[1:])]


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
