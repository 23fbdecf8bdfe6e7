"""Integration tests of the matrix-field planner, validated by the harness (planbench.evaluate)."""

from __future__ import annotations

import numpy as np
import pytest

import planbench
from planbench import Obstacle, PlanStatus, Problem, Scene
from planbench.checking.certified import CertifiedChecker
from planbench.checking.collision import CollisionChecker
from planbench.conformance import check_planner, trivial_problem
from planbench.errors import UnknownNameError
from planbench.robot import load_robot
from planbench_plugins.ik_loop import StepFailure
from planbench_plugins.matrix_field import MatrixFieldPlanner


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


def wall_problem(robot, top: float = 0.5) -> Problem:
    """The hand swings from left to right (joint 1 from +0.7 to -0.7 rad at the ready pose); a
    thin wall in front of the robot, 2 cm thick, rises to ``top`` [m], above the hand's straight
    way (the hand passes at about 0.59 m, its fingers lower). The arm can reach over it."""
    start = np.array(robot.home)
    start[0] = 0.7
    goal = np.array(robot.home)
    goal[0] = -0.7
    h = top - 0.2
    wall = Obstacle("wall", "box", position=(0.4, 0.0, 0.2 + h / 2), size=(0.3, 0.02, h))
    return Problem.create(robot, Scene((wall,), name="wall"), start, goal, id="test:wall")


def test_conformance():
    assert check_planner(MatrixFieldPlanner) == []


def test_free_space_reaches_goal_pose(robot):
    problem = trivial_problem()
    result = planbench.plan(problem, MatrixFieldPlanner, time_limit=5.0)
    ev = planbench.evaluate(problem, result)
    assert result.status is PlanStatus.SUCCESS and ev.success, ev.failure
    assert result.target == "pose"
    n = len(result.path)
    assert np.allclose(result.times, np.arange(n) * MatrixFieldPlanner.Config().dt)
    assert ev.max_velocity_ratio <= 1.0 + 1e-9
    for key in ("position_error", "orientation_error", "repulsion", "manipulability", "slowdown"):
        assert result.info[key].shape == (n,)
    assert result.info["position_error"][-1] <= 0.5 * problem.tolerances.position
    assert np.all(result.info["repulsion"][:-1] == 0.0)  # empty scene: no field


def test_wall_is_avoided_with_positive_clearance(robot):
    problem = wall_problem(robot)
    assert problem.check().ok
    # without repulsion the arm hits the wall ...
    blind = planbench.plan(problem, MatrixFieldPlanner, repulsion_gain=0.0, collision_check_every=0, escape_attempts=0)
    assert not planbench.evaluate(problem, blind).success
    # ... with it, the hand goes over the wall
    result = planbench.plan(problem, MatrixFieldPlanner, tool_repulsion_gain=1.0)
    ev = planbench.evaluate(problem, result)
    assert result.status is PlanStatus.SUCCESS and ev.success, ev.failure
    assert ev.min_clearance > 0.005
    assert np.nanmax(result.info["repulsion"]) > 0
    assert np.nanmin(result.info["slowdown"]) < 1.0


def test_full_and_lazy_field_give_the_same_path(robot):
    problem = wall_problem(robot, top=0.55)
    full = planbench.plan(problem, MatrixFieldPlanner, tool_repulsion_gain=1.0, field_mode="full")
    lazy = planbench.plan(problem, MatrixFieldPlanner, tool_repulsion_gain=1.0, field_mode="lazy")
    assert full.status is lazy.status
    assert full.path.shape == lazy.path.shape
    assert np.allclose(full.path, lazy.path, atol=1e-8)
    assert np.allclose(full.info["repulsion"], lazy.info["repulsion"], atol=1e-9, equal_nan=True)


def test_named_failures(robot):
    problem = wall_problem(robot)
    short = planbench.plan(problem, MatrixFieldPlanner, max_steps=5)
    assert short.status is PlanStatus.STEP_LIMIT and len(short.path) == 6
    crash = planbench.plan(problem, MatrixFieldPlanner, repulsion_gain=0.0, collision_check_every=1, escape_attempts=0)
    assert crash.status is PlanStatus.COLLISION
    assert not planbench.evaluate(problem, crash).success
    # the blind arm in collision: the path ends where the checker first found it

    checker = CollisionChecker(robot, problem.scene)
    assert checker.in_collision(crash.path[-1]) and not checker.in_collision(crash.path[-2])


class _FailsAtStepTen(MatrixFieldPlanner):
    """A step solver that has no valid step from the tenth step on (e.g. an infeasible QP)."""

    def solve_step(self, kin, q, inputs, points, F, support, tool, qd_out, diag):
        self._calls = getattr(self, "_calls", 0) + 1
        if self._calls > 10:  # the untimed warm-up step in setup is call 1
            raise StepFailure(PlanStatus.INFEASIBLE, "no step", {"why": "test"})
        super().solve_step(kin, q, inputs, points, F, support, tool, qd_out, diag)


def test_a_step_failure_ends_the_plan_with_the_path_so_far():
    problem = trivial_problem()
    result = planbench.plan(problem, _FailsAtStepTen, time_limit=5.0)
    assert result.status is PlanStatus.INFEASIBLE and result.message == "step 9: no step"
    assert len(result.path) == 10 and result.info["why"] == "test"  # steps 0-8 moved, step 9 had none
    assert np.all(np.isfinite(result.info["position_error"][:9])) and np.isnan(result.info["position_error"][9])
    assert not np.allclose(result.path[-1], problem.start)


def test_local_minimum_is_reported(robot):
    # A goal pose behind a wide wall, straight through it: attraction and repulsion cancel.
    start = np.array(robot.home)
    ee = robot.frame_pose(start).translation
    wall = Obstacle("wall", "box", position=(ee[0] + 0.2, ee[1], ee[2]), size=(0.02, 0.8, 0.8))
    goal_pose = planbench.Pose(ee + np.array([0.35, 0.0, 0.0]), robot.frame_pose(start).rotation, "panda_link8")
    problem = Problem.create(robot, Scene((wall,), name="behind"), start, None, goal_pose, id="test:behind")
    result = planbench.plan(problem, MatrixFieldPlanner, tool_repulsion_gain=1.0)
    assert result.status is PlanStatus.LOCAL_MINIMUM, result.message
    assert planbench.evaluate(problem, result).failure.startswith("goal not reached")


def test_time_limit(robot):
    problem = wall_problem(robot)
    result = planbench.plan(problem, MatrixFieldPlanner, time_limit=1e-4)
    assert result.status is PlanStatus.TIMEOUT


def test_positions_and_velocities_stay_in_limits_near_limits(robot):
    # start with joint 4 almost at its upper limit and drive to a pose that pulls it further
    start = np.array(robot.home)
    start[3] = robot.upper[3] - 0.01
    goal = start.copy()
    goal[3] = robot.upper[3] - 0.001
    goal[1] += 0.4
    problem = Problem.create(robot, Scene(name="empty"), start, goal, id="test:limits")
    result = planbench.plan(problem, MatrixFieldPlanner, time_limit=5.0)
    path = result.path
    assert np.all(path >= np.asarray(robot.lower)) and np.all(path <= np.asarray(robot.upper))
    speed = np.abs(np.diff(path, axis=0)) / np.diff(result.times)[:, None]
    assert np.all(speed <= np.asarray(robot.velocity_limit) * (1 + 1e-9))


def test_plot_result_writes_png(robot, tmp_path):
    from planbench_plugins.matrix_field import MatrixFieldConfig, plot_result

    problem = wall_problem(robot)
    planner = MatrixFieldPlanner(MatrixFieldConfig(tool_repulsion_gain=1.0))
    result = planbench.plan(problem, planner)
    fig = plot_result(problem, result, tmp_path / "plan.png", planner=planner)
    assert (tmp_path / "plan.png").stat().st_size > 10_000
    assert len(fig.axes) == 3


def test_numba_and_numpy_backends_give_the_same_path(robot):
    problem = wall_problem(robot)
    a = planbench.plan(problem, MatrixFieldPlanner, tool_repulsion_gain=1.0, backend="auto")
    b = planbench.plan(problem, MatrixFieldPlanner, tool_repulsion_gain=1.0, backend="numpy")
    assert a.status is b.status and a.path.shape == b.path.shape
    assert np.allclose(a.path, b.path, atol=1e-7)


def test_success_is_never_claimed_on_a_colliding_path(robot):
    """Blind to the wall (no repulsion, no periodic checks), the arm reaches the goal pose through
    it: with the dense path check the planner says COLLISION, not SUCCESS; without it, it claims
    success and the harness disagrees."""
    problem = wall_problem(robot)
    blind = dict(repulsion_gain=0.0, collision_check_every=0, escape_attempts=0)
    unchecked = planbench.plan(problem, MatrixFieldPlanner, verify_path=False, **blind)
    assert unchecked.status is PlanStatus.SUCCESS
    assert not planbench.evaluate(problem, unchecked).success
    checked = planbench.plan(problem, MatrixFieldPlanner, **blind)
    assert checked.status is PlanStatus.COLLISION, checked.message
    assert "certified path check" in checked.message
    hit = len(checked.path) - 1
    assert hit < len(unchecked.path) - 1  # the path ends where the collision was found
    certified = CertifiedChecker.for_problem(problem)
    verdict = certified.check_path(unchecked.path)
    assert hit == verdict.segment + (1 if verdict.fraction > 0 else 0)
    assert certified.check_path(unchecked.path[:hit]).free


def test_control_points_from_the_robot_file_and_from_settings(tmp_path):
    """A robot's TOML places control points per link; the planner's settings override it per link."""
    from planbench.robot import _settings_dir

    text = (_settings_dir() / "panda.toml").read_text()
    text = text.replace(
        "[fixed_joints]",
        "[control_points]\npanda_hand = [[0.0, 0.0, 0.05], [0.0, 0.0, 0.1]]\npanda_link1 = []\n\n[fixed_joints]",
    )
    path = tmp_path / "panda_cp.toml"
    path.write_text(text)
    robot = load_robot(path)
    assert robot.settings.control_points["panda_hand"] == ((0.0, 0.0, 0.05), (0.0, 0.0, 0.1))
    problem = Problem.create(robot, Scene(()), robot.home, goal_q=robot.home, id="test:cp")
    planner = MatrixFieldPlanner()
    planner.setup(problem)
    links = planner.control_points.link
    assert links.count("panda_hand") == 2 and "panda_link1" not in links
    planner = MatrixFieldPlanner(control_points={"panda_hand": [[0.0, 0.0, 0.02]]})
    planner.setup(problem)
    assert planner.control_points.link.count("panda_hand") == 1
    bad = tmp_path / "panda_badcp.toml"
    bad.write_text(text.replace("panda_link1 = []", "panda_lnk1 = []"))
    with pytest.raises(UnknownNameError, match="panda_link1"):
        load_robot(bad)


def test_repulsion_gain_means_the_same_push_at_any_resolution(robot):
    """The field in field units grows ~3x per halving of the cell size; the push [m/s] a planner
    derives from the stand-off (times repulsion_gain) stays within the profile's sampling error
    (a 0.2 m thick wall: its surface pass leaves one cell layer, the calibration wall)."""
    start = np.array(robot.home)
    goal = start.copy()
    goal[0] = 0.3
    for x in (0.36, 0.40):  # the nearest control point 5 and 9 cm from the wall
        wall = Obstacle("wall", "box", position=(x + 0.1, 0.0, 0.4), size=(0.2, 0.6, 0.8))
        problem = Problem.create(robot, Scene((wall,), name="wall"), start, goal, id="test:thick-wall")
        push, field = {}, {}
        for r in (0.04, 0.02, 0.01):
            planner = MatrixFieldPlanner(grid_resolution=r, repulsion_gain=2.0)
            planner.setup(problem)
            points, F = planner.repulsion_at(start)
            push[r] = float(np.linalg.norm(F, axis=1).max())
            field[r] = float(np.linalg.norm(planner.field_at(points), axis=1).max())
        assert push[0.02] > 0.3
        assert field[0.01] / field[0.02] > 2.0 and field[0.02] / field[0.04] > 2.0  # raw values scale
        assert 0.85 < push[0.01] / push[0.02] < 1.15 and 0.85 < push[0.04] / push[0.02] < 1.15
    half = MatrixFieldPlanner(grid_resolution=0.02, repulsion_gain=1.0)
    half.setup(problem)
    assert np.linalg.norm(half.repulsion_at(start)[1], axis=1).max() == pytest.approx(push[0.02] / 2, rel=1e-12)


def test_paper_preset_is_the_method_as_specified():
    """``matrix-field:paper`` resolves to the planner with the preset's settings; a setting given
    beside it wins; an unknown variant is still refused by name."""
    name, cls, implied = planbench.REGISTRY.resolve("matrix-field:paper")
    assert cls is MatrixFieldPlanner and implied == MatrixFieldPlanner.presets["paper"]
    planner = planbench.make_planner("matrix-field:paper", standoff=0.08)
    assert planner.config.damping == "fixed" and planner.config.goal_tolerance_scale == 1.0
    assert planner.config.standoff == 0.08
    with pytest.raises(planbench.PlanbenchError, match="planner"):
        planbench.make_planner("matrix-field:nonsense")


def ur5_wall_problem() -> Problem:
    ur5 = planbench.load_robot("ur5")
    wall = Obstacle("wall", "box", position=(0.8, 0.0, 0.3), size=(0.1, 0.6, 0.6))
    start = np.array(ur5.home)
    goal = start.copy()
    goal[0] += 0.5
    return Problem.create(ur5, Scene((wall,), name="wall"), start, goal, id="test:ur5-wall")


def test_a_six_joint_arm_is_warned_that_the_nullspace_repulsion_cannot_act(caplog):
    problem = ur5_wall_problem()
    with caplog.at_level("WARNING"):
        result = planbench.plan(problem, MatrixFieldPlanner, time_limit=2.0, max_steps=5, hierarchy="nullspace")
    assert any("no null space" in w for w in result.info["warnings"])
    auto = planbench.plan(problem, MatrixFieldPlanner, time_limit=2.0, max_steps=5)
    assert auto.info["hierarchy"] == "priority" and "warnings" not in auto.info
    panda = planbench.plan(wall_problem(planbench.load_robot("panda")), MatrixFieldPlanner, max_steps=5)
    assert panda.info["hierarchy"] == "nullspace" and "warnings" not in panda.info  # measured (test_hierarchy.py)


def test_on_a_six_joint_arm_the_priority_hierarchy_lets_the_repulsion_act():
    """A plate beside the UR5's hand as it swings. Null space: the path is the same whatever the
    repulsion gain (the field does nothing; the slow-down, which would also react, is off);
    priority: the push bends the path and the hand keeps more clearance."""
    ur5 = planbench.load_robot("ur5")
    plate = Obstacle("plate", "box", position=(0.55, 0.3, 0.55), size=(0.2, 0.02, 0.2))
    start = np.array(ur5.home)
    goal = start.copy()
    goal[0] += 0.5
    problem = Problem.create(ur5, Scene((plate,), name="plate"), start, goal, id="test:ur5-plate")

    def plan(**settings):  # the push at full strength (not scaled as on an arm without redundancy)
        return planbench.plan(
            problem,
            MatrixFieldPlanner,
            time_limit=5.0,
            slowdown_gain=0.0,
            repulsion_scale_without_redundancy=1.0,
            **settings,
        )

    deviation, clearance = {}, {}
    for hierarchy in ("nullspace", "priority"):
        a, b = plan(hierarchy=hierarchy, repulsion_gain=1.0), plan(hierarchy=hierarchy, repulsion_gain=1e-6)
        n = min(len(a.path), len(b.path))
        deviation[hierarchy] = float(np.abs(a.path[:n] - b.path[:n]).max())
        clearance[hierarchy] = planbench.evaluate(problem, a).min_clearance
    assert deviation["nullspace"] < 1e-9 and deviation["priority"] > 1e-3
    assert clearance["priority"] > clearance["nullspace"] + 1e-3
