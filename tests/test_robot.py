import json
from importlib import resources

import numpy as np
import pytest

import planbench
from planbench.errors import RobotFileError, UnknownNameError
from planbench.robot import Robot, RobotSettings, example_robot_data_dir, load_robot


def mbm_family(name):
    return json.loads((resources.files("planbench") / "data" / "mbm" / f"{name}.json").read_text())


def test_panda_plans_seven_joints_with_fingers_locked(panda):
    assert panda.nq == 7
    assert panda.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    assert panda.settings.fixed_joints == {"panda_finger_joint1": 0.065, "panda_finger_joint2": 0.065}
    np.testing.assert_allclose(panda.lower, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    np.testing.assert_allclose(panda.velocity_limit, [2.175] * 4 + [2.61] * 3)
    assert not panda.lower.flags.writeable


@pytest.mark.parametrize(
    "family", ["bookshelf_small", "bookshelf_tall", "bookshelf_thin", "box", "cage", "table_pick", "table_under_pick"]
)
def test_flange_fk_matches_mbm_goal_poses(panda, family):
    data = mbm_family(family)
    for p in data["problems"]:
        ref = p["goal_ee_pose"]["panda_link8"]
        M = panda.frame_pose(p["goal"], "panda_link8")
        np.testing.assert_allclose(M.translation, ref["position"], atol=1e-6, err_msg=p["id"])
        from scipy.spatial.transform import Rotation

        err = Rotation.from_matrix(M.rotation).inv() * Rotation.from_quat(ref["orientation_xyzw"])
        assert err.magnitude() < 1e-6, p["id"]


def test_finger_opening_is_configurable(panda):
    narrow = load_robot("panda", fixed_joints={"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04})
    wide = panda.frame_pose(panda.home, "panda_leftfinger").translation
    hand = panda.frame_pose(panda.home, "panda_hand")
    left_in_hand = hand.actInv(narrow.frame_pose(panda.home, "panda_leftfinger")).translation
    assert left_in_hand[1] == pytest.approx(0.04)
    assert hand.actInv(panda.frame_pose(panda.home, "panda_leftfinger")).translation[1] == pytest.approx(0.065)
    assert not np.allclose(wide, narrow.frame_pose(panda.home, "panda_leftfinger").translation)


def test_ur5_loads_with_six_joints():
    ur5 = load_robot("ur5")
    assert ur5.nq == 6 and ur5.settings.ee_frame == "tool0"
    assert np.all(ur5.velocity_limit > 0)


def test_any_urdf_loads_from_python_with_settings_as_arguments():
    urdf = example_robot_data_dir() / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf"
    robot = Robot(RobotSettings(name="my-ur5", urdf=urdf, ee_frame="ee_link", velocity_limits={"elbow_joint": 1.0}))
    assert robot.nq == 6
    assert robot.velocity_limit[robot.joint_names.index("elbow_joint")] == 1.0


def test_srdf_pairs_are_not_checked(panda):
    pairs = {
        (
            panda.collision_model.geometryObjects[p.first].name.rsplit("_", 1)[0],
            panda.collision_model.geometryObjects[p.second].name.rsplit("_", 1)[0],
        )
        for p in panda.collision_model.collisionPairs
    }
    assert ("panda_link0", "panda_link1") not in pairs  # adjacent, disabled in the SRDF
    assert ("panda_link0", "panda_hand") in pairs or ("panda_hand", "panda_link0") in pairs


def test_unknown_robot_suggests_close_name():
    with pytest.raises(UnknownNameError, match="Did you mean 'panda'"):
        load_robot("pandaa")


@pytest.mark.parametrize(
    "content, message",
    [
        ("name = 'x'\nurdf = \n", "not valid TOML"),
        ("name = 'x'\nee_frame = 'a'\n", "missing required key 'urdf'"),
        ("name = 'x'\nurdf = 'nope.urdf'\nee_frame = 'a'\n", "URDF file not found"),
        (
            "name = 'x'\nurdf = 'panda_description/urdf/panda.urdf'\nee_frame = 'panda_link8'\ncolour = 1\n",
            "unknown keys",
        ),
        (
            "name = 'x'\nurdf = 'panda_description/urdf/panda.urdf'\nee_frame = 'panda_link8'\n"
            "[fixed_joints]\nnot_a_joint = 0.1\n",
            "not_a_joint",
        ),
    ],
)
def test_bad_robot_files_name_the_file_and_the_problem(tmp_path, content, message):
    path = tmp_path / "bad.toml"
    path.write_text(content)
    with pytest.raises(planbench.PlanbenchError, match=message) as info:
        load_robot(path)
    assert "bad.toml" in str(info.value) or "nope.urdf" in str(info.value)


def test_malformed_urdf_is_reported(tmp_path):
    urdf = tmp_path / "broken.urdf"
    urdf.write_text("<robot name='x'><link name='a'></robot")
    with pytest.raises(RobotFileError, match="broken.urdf"):
        Robot(RobotSettings(name="x", urdf=urdf, ee_frame="a"))


def test_unknown_end_effector_frame_lists_frames():
    with pytest.raises(UnknownNameError, match="panda_link8"):
        load_robot("panda", ee_frame="panda_link88")
