"""vamp-rrtc (VAMP as a baseline, the optional extra planbench[vamp]): the scene conversion, the
robot match, the planner, and the named errors when the extra or the robot is missing.

The tests that need VAMP are skipped, with the reason, where the extra is not installed (CI: VAMP's
source build fetches its dependencies from GitHub; docs/planners.md, "VAMP").
"""

import importlib.util
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import planbench
from planbench.conformance import trivial_problem
from planbench.problem import Problem
from planbench.robot import load_robot
from planbench.scene import Obstacle, Scene
from planbench.validate import evaluate

HAVE_VAMP = importlib.util.find_spec("vamp") is not None
needs_vamp = pytest.mark.skipif(
    not HAVE_VAMP, reason="the VAMP extra is not installed (pip install 'planbench[vamp]', docs/planners.md)"
)


def _cli(args, hide_vamp=False):
    """planbench's command line in a fresh interpreter (``hide_vamp``: as if vamp were not installed)."""
    hide = "sys.modules['vamp'] = None; " if hide_vamp else ""
    code = f"import sys; {hide}from planbench.cli.main import main; sys.exit(main({args!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_without_the_extra_a_vamp_planner_is_a_named_error_with_the_install_hint():
    out = _cli(["plan", "--planner", "vamp-rrtc", "--problem", "mbm:box/0001"], hide_vamp=True)
    assert out.returncode == 2
    assert "planner 'vamp-rrtc' is registered but cannot be loaded" in out.stderr
    assert 'pip install "planbench[vamp]"' in out.stderr
    assert "Traceback" not in out.stderr


@needs_vamp
def test_a_robot_vamp_has_no_model_of_is_refused_before_planning():
    out = _cli(["plan", "--planner", "vamp-rrtc", "--problem", "gen:xarm7_shelf/0001"])
    assert out.returncode == 2
    assert "plans for robots panda, ur5" in out.stderr and "'xarm7'" in out.stderr
    assert "Traceback" not in out.stderr


@needs_vamp
def test_the_robot_match_checks_more_than_the_name():
    from planbench_plugins.vamp_planners import UnsupportedRobotError, vamp_robot

    assert vamp_robot(load_robot("panda")).module.__name__.endswith("panda")
    with pytest.raises(UnsupportedRobotError, match="xarm7"):
        vamp_robot(load_robot("xarm7"))
    with pytest.raises(UnsupportedRobotError, match="VAMP's joints"):  # another arm under VAMP's name
        vamp_robot(load_robot("xarm7", name="panda"))


def _ee(robot_name):
    robot = load_robot(robot_name)
    return robot, robot.frame_pose(robot.home).translation.copy()


def _vamp_free(robot, scene, q, **settings):
    from planbench_plugins.vamp_planners import environment, vamp_robot

    vr = vamp_robot(robot)
    env, counts = environment(scene, vr, **settings)
    return bool(vr.module.validate(np.asarray(q, dtype=np.float32), env)), counts


# A rotation whose inverse turns local z elsewhere: a bar placed with it passes through the hand only
# if the conversion applies the rotation as planbench means it.
TURN = Rotation.from_euler("xyz", [0.7, -0.4, 1.1])


def _bar(kind, through, **shape):
    axis = TURN.as_matrix()[:, 2]
    centre = through + 0.3 * axis  # the point `through` lies on the bar's axis, 0.3 m from its centre
    return Obstacle("bar", kind, position=tuple(centre), orientation_xyzw=tuple(TURN.as_quat()), **shape)


@needs_vamp
@pytest.mark.parametrize("robot_name", ["panda", "ur5"])
@pytest.mark.parametrize(
    "kind, shape, cylinders",
    [
        ("box", {"size": (0.03, 0.03, 0.8)}, "box"),
        ("cylinder", {"radius": 0.015, "length": 0.8}, "box"),
        ("cylinder", {"radius": 0.015, "length": 0.8}, "capsule"),
        ("capsule", {"radius": 0.015, "length": 0.8}, "box"),
    ],
)
def test_turned_primitives_stand_where_planbench_puts_them(robot_name, kind, shape, cylinders):
    robot, ee = _ee(robot_name)
    bar = _bar(kind, ee, **shape)
    assert planbench.checking.collision.CollisionChecker(robot, Scene((bar,))).in_collision(robot.home)
    free, counts = _vamp_free(robot, Scene((bar,)), robot.home, cylinders=cylinders)
    assert not free
    expected = "cuboids" if kind == "box" or (kind == "cylinder" and cylinders == "box") else "capsules"
    assert counts[expected] == 1
    away = Obstacle("bar", kind, position=tuple(ee + 3.0), orientation_xyzw=bar.orientation_xyzw, **shape)
    assert _vamp_free(robot, Scene((away,)), robot.home, cylinders=cylinders)[0]


@needs_vamp
@pytest.mark.parametrize("robot_name", ["panda", "ur5"])
def test_a_sphere_at_the_hand_collides_and_one_far_away_does_not(robot_name):
    robot, ee = _ee(robot_name)
    assert not _vamp_free(robot, Scene((Obstacle("ball", "sphere", position=tuple(ee), radius=0.03),)), robot.home)[0]
    assert _vamp_free(robot, Scene((Obstacle("ball", "sphere", position=tuple(ee + 3.0), radius=0.03),)), robot.home)[0]


@needs_vamp
def test_a_point_cloud_and_a_mesh_become_vamp_points(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    robot, ee = _ee("panda")
    cloud = tmp_path / "cloud.npz"
    rng = np.random.default_rng(0)
    np.savez(cloud, points=rng.uniform(-0.03, 0.03, size=(200, 3)))
    mesh = tmp_path / "cube.stl"
    trimesh.creation.box(extents=(0.06, 0.06, 0.06)).export(mesh)
    for ob in (
        Obstacle("cloud", "pointcloud", position=tuple(ee), radius=0.005, path=str(cloud)),
        Obstacle("cube", "mesh", position=tuple(ee), path=str(mesh)),
    ):
        free, counts = _vamp_free(robot, Scene((ob,)), robot.home, mesh_spacing=0.01)
        assert not free and counts["cloud_points"] > 0
        moved = Obstacle(ob.name, ob.type, position=tuple(ee + 3.0), radius=ob.radius, path=ob.path)
        assert _vamp_free(robot, Scene((moved,)), robot.home)[0]
    # the mesh's surface points lie no farther apart than the spacing along its edges: a 6 cm cube
    # at 1 cm has at least 7 points along each of its 12 edges
    from planbench_plugins.vamp_planners.convert import mesh_surface_points

    points = mesh_surface_points(Obstacle("cube", "mesh", path=str(mesh)), 0.01)
    on_edge = np.sum(np.isclose(np.abs(points), 0.03).sum(axis=1) >= 2)
    assert on_edge >= 12 * 5 + 8


@needs_vamp
def test_vamp_rrtc_plans_a_free_problem_to_the_exact_goal_and_repeats_with_a_seed():
    problem = trivial_problem("panda")
    first = planbench.plan(problem, "vamp-rrtc", seed=3)
    assert first.status is planbench.PlanStatus.SUCCESS and first.target == "configuration"
    assert np.array_equal(first.path[0], problem.start) and np.array_equal(first.path[-1], problem.goal.q)
    assert first.info["vamp_verdict"] == "free" and first.info["vamp_robot"] == "panda"
    assert evaluate(problem, first).success
    again = planbench.plan(problem, "vamp-rrtc", seed=3)
    assert np.array_equal(first.path, again.path) and first.info["sampler_offset"] == again.info["sampler_offset"]


@needs_vamp
def test_simplification_is_a_setting():
    problem = planbench.load_problems("mbm:cage/0002")[0]
    raw = planbench.plan(problem, "vamp-rrtc", seed=0, simplify=False)
    simple = planbench.plan(problem, "vamp-rrtc", seed=0, simplify=True)
    assert raw.status is simple.status is planbench.PlanStatus.SUCCESS
    assert "vamp_simplify_time" in simple.info and "vamp_simplify_time" not in raw.info
    length = [float(np.linalg.norm(np.diff(r.path, axis=0), axis=1).sum()) for r in (raw, simple)]
    assert length[1] < length[0]


@needs_vamp
def test_goals_vamp_cannot_plan_to_are_statuses():
    problem = trivial_problem("panda")
    pose_only = Problem.create(problem.robot, problem.scene, problem.start, goal_pose=problem.goal.pose)
    result = planbench.plan(pose_only, "vamp-rrtc")
    assert result.status is planbench.PlanStatus.INVALID_GOAL and "pose" in result.message
    robot, ee = _ee("panda")
    goal = np.array(problem.goal.q)
    ball = Obstacle("ball", "sphere", position=tuple(robot.frame_pose(goal).translation), radius=0.12)
    blocked = Problem.create(robot, Scene((ball,)), problem.start, goal)
    assert planbench.plan(blocked, "vamp-rrtc").status is planbench.PlanStatus.INVALID_GOAL


@needs_vamp
def test_vamps_own_verdict_sees_an_obstacle_on_a_segment():
    from planbench_plugins.vamp_planners import environment, own_verdict, vamp_robot

    problem = trivial_problem("panda")
    vr = vamp_robot(problem.robot)
    a = problem.robot.frame_pose(problem.start).translation
    b = problem.robot.frame_pose(problem.goal.q).translation
    wall = Obstacle("wall", "box", position=tuple(0.5 * (a + b)), size=(0.05, 0.05, 0.05))
    path = np.stack([problem.start, problem.goal.q])
    assert own_verdict(vr.module, path, environment(Scene(()), vr)[0])
    assert not own_verdict(vr.module, path, environment(Scene((wall,)), vr)[0])


@needs_vamp
@pytest.mark.parametrize(
    "settings", [{"sampler": "mersenne"}, {"cylinders": "cone"}, {"range": -1.0}, {"max_iterations": 0}]
)
def test_bad_settings_are_refused(settings):
    with pytest.raises(planbench.errors.InvalidConfigError):
        planbench.registry.REGISTRY.make("vamp-rrtc", **settings)


def _task(robot_name):
    from planbench.problem import Tolerances
    from planbench.reactive.controller import ControlTask

    problem = trivial_problem(robot_name)
    return ControlTask(problem.robot, problem.start, problem.goal, Tolerances(), 0.01)


@needs_vamp
def test_vamp_replan_conforms():
    from planbench.reactive.conformance import check_controller
    from planbench_plugins.controllers.vamp_replan import VampReplanController

    assert check_controller(VampReplanController) == []


@needs_vamp
def test_vamp_replan_refuses_a_robot_vamp_has_no_model_of():
    from planbench_plugins.controllers.vamp_replan import VampReplanController
    from planbench_plugins.vamp_planners import UnsupportedRobotError

    with pytest.raises(UnsupportedRobotError, match="xarm7"):
        VampReplanController().setup(_task("xarm7"))


@needs_vamp
def test_vamp_replan_plans_around_a_frames_points_and_leaves_out_those_the_arm_touches():
    from planbench.geometry.occupancy import OccupancyGrid
    from planbench.reactive.controller import Observation
    from planbench_plugins.controllers.vamp_replan import VampReplanController

    task = _task("panda")
    robot, q = task.robot, np.array(task.start)
    hand = robot.frame_pose(q).translation
    a, b = robot.frame_pose(q).translation, robot.frame_pose(task.goal.q).translation
    rng = np.random.default_rng(0)
    touching = hand + rng.uniform(-0.02, 0.02, size=(50, 3))  # on the hand: left out
    wall = 0.5 * (a + b) + rng.uniform(-0.06, 0.06, size=(400, 3))  # across the straight line
    grid = OccupancyGrid(np.zeros((2, 2, 2)), np.zeros(3), 0.02)
    controller = VampReplanController()
    controller.setup(task)
    controller.reset(q, np.random.default_rng(0))
    controller.update(Observation(0.0, grid, 0, points=np.vstack([touching, wall])))
    qd = controller.step(0.0, q, None, task.goal)
    assert qd.shape == q.shape and np.any(qd != 0)
    module, env = controller.robot.module, controller.env
    assert module.validate(q.astype(np.float32), env)  # the points on the hand were left out
    assert not module.validate_motion(q.astype(np.float32), np.asarray(task.goal.q, dtype=np.float32), env, False)
    path = controller.path
    assert path is not None and np.array_equal(path[0], q) and np.array_equal(path[-1], task.goal.q)
    assert all(
        module.validate_motion(x, y, env, False)
        for x, y in zip(path[:-1].astype(np.float32), path[1:].astype(np.float32), strict=True)
    )
    assert controller.info()["plans"] == 1 and controller.info()["failed_plans"] == 0
