"""Unit tests of the matrix-field planner's task terms, control points, kinematics and settings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planbench.errors import InvalidConfigError
from planbench.field.scene_field import wall_field
from planbench.robot import load_robot
from planbench_plugins.ik_loop import ArmKinematics, stalled
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field import MatrixFieldConfig, place_control_points


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


@pytest.fixture(scope="module")
def kin(robot):
    k = ArmKinematics(robot, robot.ee_frame_id, place_control_points(robot, 0.12))
    k.update(np.asarray(robot.home) + 0.1)
    return k


# --- attraction ----------------------------------------------------------------------------
def test_attraction_is_v_max_far_away_and_points_to_goal():
    p, goal = np.zeros(3), np.array([30.0, 40.0, 0.0])  # 50 m away
    v = T.attraction_velocity(p, goal, speed_max=0.5, sigmoid_gain=20.0)
    assert np.linalg.norm(v) == pytest.approx(0.5, rel=1e-3)
    assert np.allclose(v / np.linalg.norm(v), goal / 50.0)


def test_attraction_falls_to_zero_at_goal_without_overshoot():
    goal = np.array([0.3, -0.2, 0.5])
    assert np.array_equal(T.attraction_velocity(goal.copy(), goal, 0.5, 20.0), np.zeros(3))
    p, dt = np.array([0.0, 0.0, 0.0]), 0.01
    dists = []
    for _ in range(2000):
        v = T.attraction_velocity(p, goal, 0.5, 20.0)
        before = goal - p
        p = p + v * dt
        after = goal - p
        assert before @ after >= 0.0  # never passes the goal
        dists.append(np.linalg.norm(after))
    assert np.all(np.diff(dists) <= 0)
    assert dists[-1] < 1e-9


def test_attraction_magnitude_is_monotone_in_distance():
    d = np.linspace(1e-4, 2.0, 200)
    mags = [np.linalg.norm(T.attraction_velocity(np.zeros(3), np.array([x, 0, 0]), 0.5, 20.0)) for x in d]
    assert np.all(np.diff(mags) > 0) and max(mags) < 0.5


def test_orientation_error_of_known_rotation_is_its_axis_angle():
    rng = np.random.default_rng(1)
    for _ in range(50):
        R = Rotation.random(random_state=rng).as_matrix()
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(0.0, math.pi - 1e-3)
        R_goal = Rotation.from_rotvec(axis * angle).as_matrix() @ R  # world-frame rotation of R
        assert np.allclose(T.orientation_error(R, R_goal), axis * angle, atol=1e-9)


def test_orientation_error_takes_the_short_arc_and_zero_at_goal():
    R = np.eye(3)
    big = Rotation.from_rotvec([0, 0, 1.5 * math.pi]).as_matrix()  # = -0.5 pi about z
    assert np.allclose(T.orientation_error(R, big), [0, 0, -0.5 * math.pi], atol=1e-9)
    assert np.allclose(T.orientation_error(big, big), 0.0, atol=1e-12)
    tiny = Rotation.from_rotvec([1e-9, 0, 0]).as_matrix()
    assert np.allclose(T.orientation_error(R, tiny), [1e-9, 0, 0], atol=1e-15)


def test_attraction_caps_angular_speed():
    R_goal = Rotation.from_rotvec([0, 3.0, 0]).as_matrix()
    v = T.attraction(
        np.zeros(3),
        np.eye(3),
        np.zeros(3),
        R_goal,
        speed_max=0.5,
        sigmoid_gain=20,
        position_gain=1,
        orientation_gain=4,
        angular_speed_max=1.5,
    )
    assert np.allclose(v[:3], 0) and np.allclose(v[3:], [0, 1.5, 0])


# --- least squares, null space, manipulability ---------------------------------------------
def test_dls_is_exact_inverse_without_damping(kin):
    v = np.array([0.1, -0.2, 0.05, 0.3, 0.0, -0.1])
    assert np.allclose(kin.J @ T.dls(kin.J, v, 0.0), v, atol=1e-10)
    damped = T.dls(kin.J, v, 0.5)
    assert np.linalg.norm(damped) < np.linalg.norm(T.dls(kin.J, v, 0.0))


def test_nullspace_projection_leaves_ee_velocity_unchanged(kin, robot):
    rng = np.random.default_rng(0)
    assert np.linalg.matrix_rank(kin.J) == 6
    v = rng.normal(size=6)
    for _ in range(20):
        x = rng.normal(size=7) * 3.0  # e.g. a repulsion velocity
        qd1, nx = T.dls_with_nullspace(kin.J, v, x, damping=0.0, floor=0.0)
        for s in (1.0, 0.3):
            qd = T.merge(qd1, s, nx)
            assert np.allclose(kin.J @ qd, s * kin.J @ qd1, atol=1e-9, rtol=0)
    N = T.nullspace_projector(kin.J)
    assert np.allclose(kin.J @ N, 0.0, atol=1e-9) and np.allclose(N @ N, N, atol=1e-9)


def test_adaptive_damping():
    assert T.adaptive_damping(0.05, 0.1, 0.02) == 0.0
    assert T.adaptive_damping(0.0, 0.1, 0.02) == pytest.approx(0.1)
    assert 0 < T.adaptive_damping(0.01, 0.1, 0.02) < 0.1


def test_manipulability_gradient_matches_finite_differences(robot):
    import pinocchio as pin

    data = robot.model.createData()

    def spatial(q):
        pin.computeJointJacobians(robot.model, data, q)
        return data.J.copy()

    kin = ArmKinematics(robot, robot.ee_frame_id, place_control_points(robot))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(robot.lower + 0.3, robot.upper - 0.3)
        m, grad = T.manipulability_gradient(spatial(q), kin.descendants)
        kin.update(q)
        assert m == pytest.approx(T.manipulability(kin.J), rel=1e-9)  # same for EE and spatial J
        h = 1e-6
        num = [
            (T.manipulability(spatial(q + h * e)) - T.manipulability(spatial(q - h * e))) / (2 * h) for e in np.eye(7)
        ]
        assert np.allclose(grad, num, atol=1e-7)


# --- repulsion mapping, control points, kinematics -----------------------------------------
def test_repulsion_joint_velocity_equals_sum_of_point_jacobian_transposes(kin):
    rng = np.random.default_rng(2)
    F = rng.normal(size=(len(kin.points), 3))
    Jp = T.point_jacobians(kin.S, kin.points, kin.support)
    expected = np.einsum("nak,na->k", Jp, F)
    assert np.allclose(T.repulsion_joint_velocity(kin.S, kin.points, F, kin.support), expected, atol=1e-12)


def test_point_jacobians_match_finite_differences(robot, kin):
    q = np.asarray(robot.home) + 0.1
    cp = kin.cp
    Jp = T.point_jacobians(kin.S, kin.points, kin.support)
    h = 1e-6
    for k in range(7):
        e = np.zeros(7)
        e[k] = h
        num = (cp.world(robot, q + e) - cp.world(robot, q - e)) / (2 * h)
        assert np.allclose(Jp[:, :, k], num, atol=1e-7)


def test_kinematics_agree_with_pinocchio(robot, kin):
    q = np.asarray(robot.home) + 0.1
    M = robot.frame_pose(q)
    assert np.allclose(kin.p, M.translation) and np.allclose(kin.R, M.rotation)
    assert np.allclose(kin.points, kin.cp.world(robot, q), atol=1e-12)


@pytest.mark.parametrize("compiled", [False, True])
def test_kinematics_follow_every_update(robot, compiled):
    if compiled and not __import__("planbench_plugins.ik_loop.fast", fromlist=["x"]).have_numba():
        pytest.skip("numba not installed")
    k = ArmKinematics(robot, robot.ee_frame_id, place_control_points(robot), compiled=compiled)
    rng = np.random.default_rng(11)
    for _ in range(5):
        q = rng.uniform(robot.lower, robot.upper)
        k.update(q)
        assert np.allclose(k.points, k.cp.world(robot, q), atol=1e-12)
        assert np.allclose(k.p, robot.frame_pose(q).translation, atol=1e-12)


def test_control_points_cover_every_moving_link(robot):
    cp = place_control_points(robot, 0.12)
    moving = {g.name.rpartition("_")[0] for g in robot.collision_model.geometryObjects if g.parentJoint > 0}
    assert set(cp.link) == moving
    assert 15 <= len(cp) <= 25
    assert np.all(cp.joint > 0) and np.all(cp.radius >= 0)
    assert len(place_control_points(robot, 0.05)) > len(cp)  # finer spacing, more points


def test_control_points_override(robot):
    cp = place_control_points(robot, 0.12, [("panda_hand", [[0.0, 0.0, 0.05]]), ("panda_link1", [])])
    assert "panda_link1" not in cp.link
    assert cp.link.count("panda_hand") == 1
    i = cp.link.index("panda_hand")
    q = np.asarray(robot.home)
    hand = robot.frame_pose(q, "panda_hand")
    assert np.allclose(cp.world(robot, q)[i], hand.act(np.array([0.0, 0.0, 0.05])))


# --- limits, slow-down, mid-joint ----------------------------------------------------------
def test_velocity_scaling_keeps_direction_and_limits():
    rng = np.random.default_rng(4)
    vmax = np.array([2.175] * 4 + [2.61] * 3)
    for _ in range(100):
        qd = rng.normal(size=7) * rng.uniform(0.1, 20)
        out, c = T.scale_to_velocity_limits(qd, vmax)
        assert np.all(np.abs(out) <= vmax * (1 + 1e-12))
        assert 0 < c <= 1 and np.allclose(out, c * qd)


def test_position_clamp_never_leaves_limits(robot):
    rng = np.random.default_rng(5)
    lo, hi, dt = np.asarray(robot.lower), np.asarray(robot.upper), 0.01
    for _ in range(200):
        q = rng.uniform(lo, hi)
        j = rng.integers(7)
        q[j] = lo[j] if rng.random() < 0.5 else hi[j]  # some joints at a limit
        qd = rng.normal(size=7) * 50
        out = T.clamp_to_position_limits(q, qd, lo, hi, dt)
        nxt = q + out * dt
        assert np.all(nxt >= lo - 1e-12) and np.all(nxt <= hi + 1e-12)
        assert np.all(np.abs(out) <= np.abs(qd))
    at_limit = lo.copy()
    out = T.clamp_to_position_limits(at_limit, -np.ones(7), lo, hi, dt)
    assert np.allclose(out, 0.0)


def test_slowdown_and_mid_joint():
    assert T.slowdown_factor(0.0, 2.0, 0.2) == 1.0
    assert T.slowdown_factor(1.0, 2.0, 0.2) == pytest.approx(1 / 3)
    assert T.slowdown_factor(100.0, 2.0, 0.2) == 0.2
    lo, hi = np.array([-1.0, 0.0]), np.array([1.0, 4.0])
    assert np.allclose(T.mid_joint_velocity(np.array([0.0, 2.0]), lo, hi, 1.0), 0.0)
    v = T.mid_joint_velocity(np.array([0.5, 1.0]), lo, hi, 1.0)
    assert v[0] == pytest.approx(-0.5 / 4) and v[1] == pytest.approx(1.0 / 16)


# --- local minimum, stand-off, settings ----------------------------------------------------
def test_stalled_definition():
    window = 10
    flat = np.full(30, 0.2)
    assert not stalled(flat, 9, window, 0.02)  # never before a full window
    assert stalled(flat, 10, window, 0.02)
    decaying = 0.2 * np.exp(-0.1 * np.arange(30))  # ~63 % per window: progress
    assert not stalled(decaying, 25, window, 0.02)


def test_wall_field_follows_kernel_profile():
    from planbench.field import KernelSpec

    k = KernelSpec(reach=0.16, profile="linear").build(0.02)  # c = 8 cells, taper sum 9
    for cells in (1, 3, 5):
        d = cells * 0.02 - 0.01  # a cell centre
        expected = (9 - cells) / 9 * 81
        assert wall_field(k, d) == pytest.approx(expected, rel=1e-9)
    assert wall_field(k, 0.2) == 0.0  # beyond the reach


@pytest.mark.parametrize(
    "bad",
    [
        dict(dt=0),
        dict(speed_max=-1),
        dict(field_mode="dense"),
        dict(max_steps=0),
        dict(standoff=0.3),
        dict(damping="auto"),
        dict(slowdown_min=2.0),
        dict(control_points={"panda_hand": [[1, 2]]}),
        dict(repulsion_gain=float("nan")),
    ],
)
def test_config_validation(bad):
    with pytest.raises(InvalidConfigError):
        MatrixFieldConfig(**bad)


def test_config_defaults_and_overrides_freeze():
    c = MatrixFieldConfig(control_points={"panda_hand": [[0, 0, 0.1]]})
    assert c.control_points == (("panda_hand", ((0.0, 0.0, 0.1),)),)
    assert MatrixFieldConfig().stall_steps == 100


@pytest.mark.parametrize("damping", ["adaptive", "fixed"])
def test_step_params_are_the_config_settings_by_name(damping):
    from planbench_plugins.ik_loop import fast

    cfg = MatrixFieldConfig(damping=damping, speed_max=0.3, dt=0.02, tool_repulsion_gain=0.5, orientation_priority=0.2)
    prm = fast.step_params(cfg, 7)
    assert prm.adaptive == (1.0 if damping == "adaptive" else 0.0)
    for name in prm._fields:
        if name not in ("adaptive", "priority", "orientation_weight"):
            assert getattr(prm, name) == getattr(cfg, name)
    assert (prm.speed_max, prm.dt, prm.tool_repulsion_gain) == (0.3, 0.02, 0.5)
    # the hierarchy's fields are resolved for the arm (tests/test_hierarchy.py)
    assert (prm.priority, prm.orientation_weight) == (0.0, 1.0)
    assert fast.step_params(cfg, 7, "priority").priority == 1.0
    assert (fast.step_params(cfg, 6).priority, fast.step_params(cfg, 6).orientation_weight) == (1.0, 0.2)
    assert fast.step_params(MatrixFieldConfig(hierarchy="nullspace"), 7).priority == 0.0


# --- the compiled step equals the composition of the task functions ------------------------
@pytest.mark.skipif(
    not __import__("planbench_plugins.ik_loop.fast", fromlist=["x"]).have_numba(), reason="numba not installed"
)
@pytest.mark.parametrize(
    "robot_name, damping, hierarchy",
    [
        ("panda", "adaptive", "nullspace"),
        ("panda", "fixed", "nullspace"),
        ("panda", "adaptive", "priority"),
        ("panda", "fixed", "priority"),
        ("ur5", "adaptive", "priority"),
        ("ur5", "fixed", "auto"),
        ("ur5", "adaptive", "nullspace"),
    ],
)
def test_compiled_step_matches_numpy_reference(robot_name, damping, hierarchy):
    """Both backends, both hierarchies, a redundant arm and one without redundancy (orientation
    rows weighted), random configurations, goals and pushes (some steps without repulsion, some
    points without push, pushes from below the priority onset to far above it)."""
    from planbench_plugins.ik_loop import fast

    robot = load_robot(robot_name)
    n = robot.nq
    cfg = MatrixFieldConfig(damping=damping, tool_repulsion_gain=1.0, hierarchy=hierarchy)
    prm = fast.step_params(cfg, n, "priority")
    assert prm.priority == (0.0 if hierarchy == "nullspace" else 1.0)
    kin = ArmKinematics(robot, robot.ee_frame_id, place_control_points(robot), compiled=True)
    ref_kin = ArmKinematics(robot, robot.ee_frame_id, place_control_points(robot), compiled=False)
    rng = np.random.default_rng(7)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    vmax = np.asarray(robot.velocity_limit)
    tool = np.flatnonzero(kin.cp.joint == kin.cp.joint.max()).astype(np.intp)
    rows_seen = 0
    for trial in range(12):
        q = rng.uniform(lo, hi)
        if trial == 0:
            q[3] = hi[3]  # at a limit
        kin.update(q)
        ref_kin.update(q)
        assert np.allclose(kin.points, ref_kin.points, atol=1e-14)
        assert np.allclose(kin.J, ref_kin.J, atol=1e-14)  # compiled from S, as pinocchio.getFrameJacobian
        F = rng.normal(size=kin.points.shape) * (trial % 3) * 0.4
        F[rng.random(len(F)) < 0.3] = 0.0  # points without push
        mag = np.linalg.norm(F, axis=1)
        rows_seen += int(np.sum(mag / prm.speed_max > prm.priority_onset))
        p_goal = rng.uniform(-0.5, 0.5, 3)
        R_goal = Rotation.random(random_state=rng).as_matrix()
        out = []
        for fn, k in ((fast.step_compiled, kin), (fast.step_numpy, ref_kin)):
            qd, dg = np.zeros(n), np.zeros(6)
            fn(
                k.S,
                k.J,
                k.p,
                k.R,
                p_goal,
                R_goal,
                q,
                lo,
                hi,
                vmax,
                k.points,
                F,
                k.support,
                k.descendants,
                tool,
                prm,
                qd,
                dg,
            )
            out.append((qd, dg))
        assert np.allclose(out[0][0], out[1][0], atol=1e-10, rtol=1e-8)
        assert np.allclose(out[0][1], out[1][1], atol=1e-10, rtol=1e-8)
        assert np.all(np.abs(out[0][0]) <= vmax * (1 + 1e-12))
    assert rows_seen > 20  # the priority rows were exercised
