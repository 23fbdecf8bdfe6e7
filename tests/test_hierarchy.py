"""The IK loop's task hierarchy (``hierarchy``: nullspace, priority, auto): the repulsion rows'
weights, the stacked least squares, the arms without redundancy, the warning, the paper preset."""

from __future__ import annotations

import logging

import numpy as np
import pytest

import planbench
from planbench import Obstacle, Problem, Scene
from planbench.errors import InvalidConfigError
from planbench.robot import load_robot
from planbench_plugins.ik_loop import ArmKinematics, ScaledRepulsion, fast
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.ik_loop.config import repulsion_scale, resolve_hierarchy
from planbench_plugins.matrix_field import MatrixFieldConfig, MatrixFieldPlanner, place_control_points


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5")


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda")


def ur5_plate_problem(ur5, scene: Scene | None = None) -> Problem:
    """The UR5's hand moves from home to the pose of joint 1 turned by +0.5 rad, past a thin
    vertical plate beside its way: with no null space, the method as specified drives the hand
    into it."""
    plate = Obstacle("plate", "box", position=(0.55, 0.2, 0.5), size=(0.2, 0.02, 0.3))
    start = np.array(ur5.home)
    goal = start.copy()
    goal[0] += 0.5
    scene = Scene((plate,), name="plate") if scene is None else scene
    return Problem.create(ur5, scene, start, goal, id="test:ur5-plate-near")


# --- settings ----------------------------------------------------------------------------
def test_auto_is_chosen_from_the_arms_redundancy(ur5, panda):
    """Without redundancy only the priority rows let the repulsion act, and they replace it (ramp
    from the field's edge to the stand-off); with redundancy ``"auto"`` is the planner's measured
    choice. The redundancy also sets the orientation rows' weight."""
    cfg = MatrixFieldConfig()
    assert cfg.hierarchy == "auto"
    assert resolve_hierarchy(cfg, 6) == ("priority", 0.0, 1.0, 0.1)
    assert resolve_hierarchy(cfg, 5).mode == "priority"
    assert resolve_hierarchy(cfg, 7) == ("nullspace", cfg.priority_onset, cfg.priority_full, 1.0)
    assert resolve_hierarchy(cfg, 7, "priority") == ("priority", cfg.priority_onset, cfg.priority_full, 1.0)
    explicit = MatrixFieldConfig(hierarchy="priority", priority_onset=1.5, priority_full=2.0)
    assert resolve_hierarchy(explicit, 7) == ("priority", 1.5, 2.0, 1.0)
    assert resolve_hierarchy(explicit, 6) == ("priority", 0.0, 1.0, 0.1)  # the ramp replaces the null space
    assert resolve_hierarchy(MatrixFieldConfig(hierarchy="nullspace"), 6, "priority").mode == "nullspace"
    prm = fast.step_params(cfg, 6)
    assert (prm.priority, prm.priority_onset, prm.priority_full, prm.orientation_weight) == (1.0, 0.0, 1.0, 0.1)
    assert fast.step_params(cfg, 7).priority == 0.0 and fast.step_params(cfg, 7, "priority").priority == 1.0
    # every loop planner takes the null space on a redundant arm (issue 32: the matrix field too)
    assert MatrixFieldPlanner.auto_hierarchy_redundant == "nullspace"
    wall = Obstacle("wall", "box", position=(0.6, 0.0, 0.3), size=(0.02, 0.6, 0.6))
    problem = Problem.create(panda, Scene((wall,), name="wall"), np.array(panda.home), np.array(panda.home))
    assert planbench.plan(problem, "matrix-field", max_steps=3).info["hierarchy"] == "nullspace"
    assert planbench.plan(problem, "matrix-field", max_steps=3, hierarchy="priority").info["hierarchy"] == "priority"
    assert planbench.plan(problem, "edt-field", max_steps=3).info["hierarchy"] == "nullspace"
    assert planbench.plan(ur5_plate_problem(ur5), "edt-field", max_steps=3).info["hierarchy"] == "priority"


def test_the_scene_push_is_scaled_where_the_rows_replace_the_null_space(ur5, panda):
    """On an arm without redundancy in the priority hierarchy the scene's push is scaled by
    ``repulsion_scale_without_redundancy``; a redundant arm, the null space and a 6-joint arm in
    it keep the push as it is."""
    cfg = MatrixFieldConfig(repulsion_scale_without_redundancy=0.4)
    assert repulsion_scale(cfg, 6, "priority") == 0.4
    assert repulsion_scale(cfg, 6, "nullspace") == 1.0
    assert repulsion_scale(cfg, 7, "priority") == 1.0
    planner = MatrixFieldPlanner(cfg)
    planner.setup(ur5_plate_problem(ur5))
    push = planner.stepper.repulsion
    scaled = push.inner  # the self-collision push wraps the scaled scene push
    assert isinstance(scaled, ScaledRepulsion) and scaled.scale == 0.4
    kin = planner.stepper.kin
    kin.update(np.asarray(ur5.home) + 0.3)
    _, F, _, _ = scaled.forces(kin)
    _, F_scene, _, _ = scaled.inner.forces(kin)
    assert np.any(F_scene != 0) and np.array_equal(F, 0.4 * F_scene)
    assert scaled.gain == 0.4 * scaled.inner.gain
    wall = Obstacle("wall", "box", position=(0.6, 0.0, 0.3), size=(0.02, 0.6, 0.6))
    redundant = MatrixFieldPlanner(cfg)
    redundant.setup(Problem.create(panda, Scene((wall,), name="wall"), np.array(panda.home), np.array(panda.home)))
    assert not isinstance(redundant.stepper.repulsion.inner, ScaledRepulsion)
    paper = planbench.make_planner("matrix-field:paper")
    paper.setup(ur5_plate_problem(ur5))
    assert not isinstance(paper.stepper.repulsion, ScaledRepulsion)


@pytest.mark.parametrize(
    "bad, name",
    [
        (dict(hierarchy="stacked"), "hierarchy"),
        (dict(priority_onset=-0.1), "priority_onset"),
        (dict(priority_onset=2.0, priority_full=2.0), "priority_full"),
        (dict(priority_weight=float("inf")), "priority_weight"),
        (dict(priority_fade_distance=0.0), "priority_fade_distance"),
        (dict(orientation_priority=-1.0), "orientation_priority"),
        (dict(repulsion_scale_without_redundancy=-0.1), "repulsion_scale_without_redundancy"),
    ],
)
def test_bad_hierarchy_settings_are_refused_by_name(bad, name):
    with pytest.raises(InvalidConfigError, match=name):
        MatrixFieldConfig(**bad)


# --- the activations ---------------------------------------------------------------------
def test_rows_are_off_far_away_and_switch_on_c1_near_obstacles():
    kw = dict(speed_max=0.25, onset=1.0, full=2.0, fade=0.1)
    push = np.linspace(0.0, 1.0, 4001)  # [m/s]: ratios 0 to 4
    a = T.priority_activation(push, 1.0, **kw)
    ratio = push / 0.25
    assert np.all(a[ratio <= 1.0] == 0.0) and np.allclose(a[ratio >= 2.0], 1.0)
    assert np.all(np.diff(a) >= 0.0)
    slope = np.diff(a) / np.diff(push)
    # C1: the slope (up to 6 s/m here) changes by at most its curvature times one sample (0.024);
    # a linear ramp would jump by 4 at the onset and at the full push
    assert np.max(np.abs(np.diff(slope))) < 0.03
    assert abs(slope[0]) < 1e-9 and abs(slope[-1]) < 1e-9
    # near the goal the rows fade linearly with the position error
    assert np.allclose(T.priority_activation(push, 0.05, **kw), 0.5 * a)
    assert np.all(T.priority_activation(push, 0.0, **kw) == 0.0)


# --- the least squares ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def panda_kin(panda):
    k = ArmKinematics(panda, panda.ee_frame_id, place_control_points(panda))
    k.update(np.asarray(panda.home) + 0.1)
    return k


def test_with_pose_rows_only_the_stack_is_the_nullspace_step(panda_kin):
    """The stacked least squares with the pose rows only is the DLS step plus the null-space
    projection of the secondary velocity, up to its (1 mm)^2 regularisation (relative effect
    ~mu / sigma^2, 2e-5 here)."""
    rng = np.random.default_rng(3)
    J = panda_kin.J
    for lam in (0.0, 0.05):
        v, x = rng.normal(size=6) * 0.2, rng.normal(size=7)
        qd1, nx = T.dls_with_nullspace(J, v, x, lam)
        qd = T.stacked_dls(J, v, x, lam * lam)
        assert np.allclose(qd, qd1 + nx, atol=1e-4)
        if lam == 0.0:
            assert np.allclose(J @ qd, v, atol=1e-4)  # the pose task is met


def correction_case(kin):
    """Two points of the Panda pushed (8 rows for 7 joints), and a null-space step to correct."""
    idx = np.array([len(kin.points) - 1, len(kin.points) - 4])
    F = np.array([[-0.5, 0.0, 0.1], [0.0, 0.4, -0.2]])
    rows = T.repulsion_rows(kin.S, kin.points[idx], F, kin.support[idx])
    qd = T.stacked_dls(kin.J, np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0]), np.zeros(7), 0.0)
    return rows, np.linalg.norm(F, axis=1), qd


def test_the_push_correction_is_continuous_and_a_heavy_row_wins_over_the_pose_task(panda_kin):
    """No correction while the rows switch on (activation 0, whatever the weight); fully on, the
    heavier the rows, the closer each point moves away at its push, at the pose task's expense."""
    kin = panda_kin
    rows, push, qd = correction_case(kin)
    assert np.allclose(rows[0], (rows[0] @ np.eye(7)))  # one row per point
    assert np.allclose(
        rows[0], (np.array([-0.5, 0.0, 0.1]) / push[0]) @ T.point_jacobians(kin.S, kin.points[-1:], kin.support[-1:])[0]
    )
    kw = dict(orientation_weight=1.0, damping2=0.0)
    for weight in (1.0, 1e3):
        assert np.all(T.push_correction(kin.J, rows, push, np.zeros(2), qd, weight=weight, **kw) == 0.0)
        for a in (1e-4, 1e-6):  # the correction vanishes with the activation (linearly or faster)
            small = T.push_correction(kin.J, rows, push, np.full(2, a), qd, weight=weight, **kw)
            assert np.abs(small).max() < a
    miss, pose = [], []
    for weight in (0.01, 1.0, 10.0, 1000.0):
        dq = T.push_correction(kin.J, rows, push, np.ones(2), qd, weight=weight, **kw)
        miss.append(float(np.linalg.norm(np.minimum(0.0, rows @ (qd + dq) - push))))  # slower than the push
        pose.append(float(np.linalg.norm(kin.J @ dq)))  # the end effector's twist changed
    assert all(a > b for a, b in zip(miss, miss[1:], strict=False))
    assert all(a < b for a, b in zip(pose, pose[1:], strict=False))
    assert miss[-1] < 0.01 * miss[0]


def test_a_point_already_moving_away_fast_enough_is_left_alone(panda_kin):
    kin = panda_kin
    rows, push, qd = correction_case(kin)
    slow = rows @ qd - 0.05  # pushes below what the step already does along them
    dq = T.push_correction(kin.J, rows, slow, np.ones(2), qd, weight=10.0, orientation_weight=1.0, damping2=0.0)
    assert np.abs(dq).max() < 1e-12


def test_without_redundancy_orientation_gives_way_before_position(ur5):
    """On the UR5 one active row makes 7 rows for 6 joints. With the orientation rows at
    ``orientation_priority`` (0.1) the conflict is taken from the orientation: its change grows
    tenfold, while the position and the push are kept (slightly) better."""
    kin = ArmKinematics(ur5, ur5.ee_frame_id, place_control_points(ur5))
    kin.update(np.asarray(ur5.home) + 0.05)
    i = int(np.argmax(kin.points[:, 0]))  # a forearm point, 0.4 m out
    v = np.array([0.0, 0.25, 0.0, 0.0, 0.0, 0.0])  # the hand towards +y, the point pushed towards -y
    F = np.array([[0.0, -0.6, 0.0]])
    row = T.repulsion_rows(kin.S, kin.points[i : i + 1], F, kin.support[i : i + 1])
    qd = np.linalg.solve(kin.J, v)
    res = {}
    for wo in (1.0, fast.step_params(MatrixFieldConfig(), 6).orientation_weight):
        dq = T.push_correction(
            kin.J, row, np.array([0.6]), np.ones(1), qd, weight=1.0, orientation_weight=wo, damping2=0
        )
        twist = kin.J @ dq
        res[wo] = (np.linalg.norm(twist[:3]), np.linalg.norm(twist[3:]), abs((row @ (qd + dq)).item() - 0.6))
    (p1, o1, f1), (p2, o2, f2) = res[1.0], res[0.1]
    assert o2 > 5 * o1 and p2 < p1 and f2 < f1


# --- arms without redundancy ---------------------------------------------------------------
def plan(problem, **settings):
    return planbench.plan(problem, MatrixFieldPlanner, time_limit=10.0, **settings)


def test_on_the_ur5_the_default_lets_the_repulsion_act_and_avoid_a_plate(ur5):
    """As specified (null space) the repulsion cannot move a 6-joint arm: the path does not depend
    on its gain and the hand hits the plate. The default (auto: priority) pushes it around the
    plate to the goal; ``hierarchy="nullspace"`` gives back the method's path."""
    problem = ur5_plate_problem(ur5)
    off = dict(slowdown_gain=0.0)  # the slow-down also reacts to the push, and moves the path by itself
    paths = {}
    for name, settings in {"default": {}, "nullspace": dict(hierarchy="nullspace")}.items():
        strong, weak = plan(problem, **off, **settings), plan(problem, repulsion_gain=1e-6, **off, **settings)
        n = min(len(strong.path), len(weak.path))
        paths[name] = (strong, float(np.abs(strong.path[:n] - weak.path[:n]).max()))
    assert paths["nullspace"][1] < 1e-9 and paths["default"][1] > 1e-2
    assert paths["default"][0].info["hierarchy"] == "priority"
    default, method = plan(problem), plan(problem, hierarchy="nullspace", escape_attempts=0)
    assert planbench.evaluate(problem, default).success
    assert not planbench.evaluate(problem, method).success and method.status.name == "COLLISION"
    paper = planbench.plan(problem, "matrix-field:paper", time_limit=10.0)
    assert paper.info["hierarchy"] == "nullspace" and not planbench.evaluate(problem, paper).success


@pytest.mark.skipif(not fast.have_numba(), reason="numba not installed")
def test_both_backends_plan_the_same_priority_path(ur5):
    problem = ur5_plate_problem(ur5)
    a, b = plan(problem, backend="numba"), plan(problem, backend="numpy")
    assert a.info["hierarchy"] == b.info["hierarchy"] == "priority"
    assert a.status == b.status and len(a.path) == len(b.path)
    assert np.allclose(a.path, b.path, atol=1e-8)


def test_the_nullspace_hierarchy_on_a_six_joint_arm_is_warned_at_every_setup(ur5, panda, caplog):
    problem = ur5_plate_problem(ur5)
    with caplog.at_level(logging.WARNING, logger="planbench_plugins.ik_loop.loop"):
        for _ in range(2):
            result = plan(problem, hierarchy="nullspace", max_steps=3)
            assert len(result.info["warnings"]) == 1 and "no null space" in result.info["warnings"][0]
        assert sum("no null space" in r.getMessage() for r in caplog.records) == 2
        caplog.clear()
        assert "warnings" not in plan(problem, max_steps=3).info  # auto: priority
        assert "warnings" not in plan(problem, hierarchy="priority", max_steps=3).info
        free = ur5_plate_problem(ur5, Scene((), name="empty"))
        assert "warnings" not in plan(free, hierarchy="nullspace", max_steps=3).info  # nothing to repel
        wall = Obstacle("wall", "box", position=(0.6, 0.0, 0.3), size=(0.02, 0.6, 0.6))
        arm7 = Problem.create(panda, Scene((wall,), name="wall"), np.array(panda.home), np.array(panda.home))
        assert "warnings" not in plan(arm7, hierarchy="nullspace", max_steps=3).info
        assert not caplog.records
