"""Tests of the QP variant of the matrix-field planner (``matrix-field-qp``, docs/method.md section 5)."""

from __future__ import annotations

import weakref

import numpy as np
import pinocchio as pin
import pytest
from scipy.optimize import lsq_linear

import planbench
from planbench import Obstacle, PlanStatus, Problem, Scene
from planbench.checking.collision import CollisionChecker
from planbench.conformance import check_planner, trivial_problem
from planbench.errors import InvalidConfigError
from planbench.robot import load_robot
from planbench_plugins.ik_loop import DistanceModel
from planbench_plugins.ik_loop import distances as ik_distances
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field_qp import MatrixFieldQPConfig, MatrixFieldQPPlanner, installed_solvers
from planbench_plugins.matrix_field_qp import planner as qp_planner
from planbench_plugins.matrix_field_qp.formulation import collision_constraints, limit_bounds, objective

EXACT_SOLVERS = ("osqp", "daqp", "quadprog", "proxqp", "clarabel", "piqp", "highs", "qpalm", "cvxopt")
"""Backends expected to agree to 1e-5 rad/s on a step (others, e.g. scs, are first-order and looser)."""


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


def problem_from(robot, start, goal_q, scene=None, pid="test:qp"):
    return Problem.create(
        robot, scene or Scene(name="empty"), np.asarray(start, float), np.asarray(goal_q, float), id=pid
    )


def prepared(problem, **settings):
    planner = MatrixFieldQPPlanner(**settings)
    planner.setup(problem)
    return planner


def box_lsq(qp):
    """The box-constrained minimiser of ``1/2 x^T P x + c^T x`` by an independent method (scipy)."""
    L = np.linalg.cholesky(qp.P)
    return lsq_linear(L.T, -np.linalg.solve(L, qp.c), bounds=(qp.lb, qp.ub), tol=1e-14, method="bvls").x


def test_conformance():
    assert check_planner(MatrixFieldQPPlanner) == []


def test_free_space_plan_is_validated_and_times_the_solver_apart():
    problem = trivial_problem()
    result = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0)
    ev = planbench.evaluate(problem, result)
    assert result.status is PlanStatus.SUCCESS and ev.success, ev.failure
    n = len(result.path)
    for key in ("qp_build_time", "qp_solve_time", "qp_active", "qp_residual", "position_error", "damping"):
        assert result.info[key].shape == (n,)
    assert 0 < result.info["solver_time"] < result.planning_time
    assert 0 < result.info["build_time"] < result.planning_time
    assert result.info["solver"] == "daqp"
    assert ev.max_limit_violation == 0.0 and ev.max_velocity_ratio <= 1.0


def test_no_active_constraint_gives_the_unconstrained_least_squares_step(robot):
    q = np.array(robot.home) + 0.1
    goal = np.array(robot.home) + 0.3
    planner = prepared(problem_from(robot, robot.home, goal))
    qp, qd, diag = planner.step_at(q)
    assert np.all(qp.lb < qd) and np.all(qd < qp.ub) and qp.G is None and diag[8] == 0
    assert np.allclose(qd, qp.unconstrained(), atol=1e-6)


def test_objective_minimiser_is_the_matrix_field_merge_with_damped_least_squares():
    """Unconstrained, the QP's minimiser is s J_dls^+ v + w_sec/(w_sec+mu) N x_sec (docs/method.md 4, step 8)."""
    rng = np.random.default_rng(3)
    J, v, x_sec = rng.normal(size=(6, 7)), rng.normal(size=6), rng.normal(size=7)
    w_task, w_sec, mu = 2.0, 1e-3, 1e-4
    P, c = objective(J, v, x_sec, task_weight=w_task, orientation_weight=1.0, secondary_weight=w_sec, damping=mu)
    qd1, nx = T.dls_with_nullspace(J, v, x_sec, np.sqrt((w_sec + mu) / w_task), floor=0.0)
    assert np.allclose(np.linalg.solve(P, -c), qd1 + w_sec / (w_sec + mu) * nx, atol=1e-10)


def test_start_at_a_joint_limit_with_the_goal_pulling_outward_never_crosses_it(robot):
    j = 3  # panda_joint4, upper limit -0.0698 rad
    start = np.array(robot.home)
    start[j] = robot.upper[j]
    goal = start.copy()
    goal[j] += 0.4  # outside the limits: its pose pulls joint 4 further out
    goal[1] += 0.3
    problem = problem_from(robot, start, goal)
    planner = prepared(problem)
    qp, qd, _ = planner.step_at(start)
    assert qp.unconstrained()[j] > 0.1  # the pull is outward ...
    assert qp.ub[j] == 0.0 and qd[j] <= 0.0  # ... and the step does not follow it
    result = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0)
    path = result.path
    assert np.all(path <= robot.upper) and np.all(path >= robot.lower)
    assert np.max(path[:, j]) == robot.upper[j]
    assert np.nanmax(result.info["qp_active"]) >= 1
    ev = planbench.evaluate(problem, result)
    assert ev.max_limit_violation == 0.0 and ev.max_velocity_ratio <= 1.0


def test_goal_faster_than_the_velocity_limits_is_followed_at_exactly_the_limit(robot):
    start = np.array(robot.home)
    goal = start.copy()
    goal[0] -= 1.5
    goal[1] += 0.5
    problem = problem_from(robot, start, goal)
    fast = dict(speed_max=5.0, angular_speed_max=10.0, orientation_gain=20.0)
    planner = prepared(problem, **fast)
    qp, qd, _ = planner.step_at(start)
    qd_max = np.asarray(robot.velocity_limit)
    assert np.max(np.abs(qp.unconstrained()) / qd_max) > 1.5  # the task asks for too much
    assert np.max(np.abs(qd) / qd_max) == pytest.approx(1.0, abs=2e-9)  # saturated (1e-9 margin)
    assert np.all(np.abs(qd) <= qd_max)
    assert np.allclose(qd, box_lsq(qp), atol=1e-5)  # and the best step within the limits
    result = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0, **fast)
    ev = planbench.evaluate(problem, result)
    assert ev.success, ev.failure
    assert ev.max_velocity_ratio == pytest.approx(1.0, abs=2e-9) and ev.max_velocity_ratio <= 1.0
    speed = np.abs(np.diff(result.path, axis=0)) / np.diff(result.times)[:, None]
    assert np.all(speed <= qd_max)


def test_infeasible_start_gives_the_named_failure(robot):
    start = np.array(robot.home)
    start[3] = robot.upper[3] + 0.3  # beyond what one step at full speed can undo
    problem = problem_from(robot, start, robot.home)
    planner = MatrixFieldQPPlanner()
    result = planner.plan(problem, time_limit=5.0, rng=np.random.default_rng(0))  # the harness would refuse it
    assert result.status is PlanStatus.INFEASIBLE
    assert "panda_joint4" in result.message and "start inside the limits" in result.message
    assert "infeasible" in result.info["qp_failure"]["solver_status"]
    assert planbench.plan(problem, MatrixFieldQPPlanner).status is PlanStatus.INVALID_START


@pytest.mark.filterwarnings("ignore:OSQP exited")
def test_solver_failure_is_a_named_status_and_options_pass_through(robot):
    problem = trivial_problem()
    result = planbench.plan(
        problem, MatrixFieldQPPlanner, solver="osqp", solver_options={"max_iter": 1}, time_limit=5.0
    )
    assert result.status is PlanStatus.INFEASIBLE, result.message
    assert "osqp" in result.message and "maximum iterations" in result.message
    assert result.info["qp_failure"]["solver"] == "osqp"


def test_settings_are_validated():
    with pytest.raises(InvalidConfigError, match="installed"):
        MatrixFieldQPConfig(solver="no-such-solver")
    with pytest.raises(InvalidConfigError, match="secondary_weight"):
        MatrixFieldQPConfig(secondary_weight=-1.0)
    with pytest.raises(InvalidConfigError, match="solver_options"):
        MatrixFieldQPConfig(solver_options=3)
    assert MatrixFieldQPConfig(solver_options={"eps_abs": 1e-9}).options == {"eps_abs": 1e-9}


def elbow_wall_problem(robot):
    """A wall 13 cm beside the elbow at the ready pose; the goal swings the elbow towards it."""
    q = np.array(robot.home)
    elbow = robot.frame_pose(q, "panda_link4").translation
    wall = Obstacle("wall", "box", position=(elbow[0], elbow[1] + 0.13, elbow[2]), size=(0.4, 0.02, 0.4))
    goal = q.copy()
    goal[0] += 0.8
    return problem_from(robot, q, goal, Scene((wall,), name="wall"))


def test_velocity_dampers_hold_near_an_obstacle(robot):
    problem = elbow_wall_problem(robot)
    q = problem.start
    planner = prepared(problem, velocity_dampers=True, collision_constraints=False)
    qp, qd, diag = planner.step_at(q)
    assert qp.G is not None and len(qp.h) >= 1
    assert np.all(qp.G @ qd <= qp.h + 1e-6)
    assert diag[2] > 0  # the field acts


# --- collision constraints (exact distances) ---------------------------------------------------


def plate_problem(robot):
    """A plate across the hand's way: the goal turns joint 1 by 1 rad, and the plate stands
    half-way between the hand's start and goal positions."""
    q = np.array(robot.home)
    goal = q.copy()
    goal[0] += 1.0
    a, b = robot.frame_pose(q, "panda_hand").translation, robot.frame_pose(goal, "panda_hand").translation
    yaw = np.arctan2(b[1] - a[1], b[0] - a[0])
    plate = Obstacle(
        "plate",
        "box",
        position=tuple(0.5 * (a + b) + [0.0, 0.0, -0.05]),
        orientation_xyzw=(0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)),
        size=(0.02, 0.4, 0.2),
    )
    return problem_from(robot, q, goal, Scene((plate,), name="plate"))


def test_collision_constraint_rows_are_the_rate_of_the_exact_distance(robot):
    """-G qd is the time derivative of coal's distance for any qd (normal and witness Jacobians),
    for robot-obstacle and robot-robot pairs."""
    problem = elbow_wall_problem(robot)
    distances = DistanceModel(robot, problem.scene, 0.2)
    model, data = robot.model, robot.model.createData()

    def near(q):
        pin.computeJointJacobians(model, data, q)
        return distances.near(model, data)

    q = np.array(problem.start)
    pairs = near(q)
    S = data.J.copy()
    assert len(pairs) >= 3 and pairs.distance.min() < 0.05
    assert np.any(pairs.second < distances.n_robot)  # self pairs too: both bodies move
    G, h = collision_constraints(
        S,
        pairs.point,
        pairs.normal,
        pairs.support,
        pairs.distance,
        gain=5.0,
        safety=0.003,
        other_point=pairs.other_point,
        other_support=pairs.other_support,
    )
    assert np.allclose(h, 5.0 * (pairs.distance - 0.003))
    rng = np.random.default_rng(1)
    eps = 1e-3  # central differences: GJK's distances are accurate to ~1e-6 m
    for _ in range(3):
        qd = 5.0 * rng.normal(size=7)
        rate = (near(q + eps * qd).by_pair()[pairs.pair] - near(q - eps * qd).by_pair()[pairs.pair]) / (2 * eps)
        assert np.allclose(rate, -G @ qd, rtol=0.02, atol=1e-3), np.abs(rate + G @ qd).max()
        assert np.abs(rate[pairs.second < distances.n_robot]).max() > 5e-3  # a self pair moves


def test_hull_distances_never_exceed_the_true_clearance(robot):
    problem = elbow_wall_problem(robot)
    distances = DistanceModel(robot, problem.scene, 1.0)
    checker = CollisionChecker(robot, problem.scene)
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(robot.lower, robot.upper)
        pairs = distances.near_at(q)
        obstacle = pairs.second >= distances.n_robot
        assert pairs.distance[obstacle].min() <= checker.clearance(q) + 1e-5  # GJK's tolerance


def test_models_of_one_robot_share_its_hulls_and_measure_as_one_made_afresh(robot, monkeypatch):
    """A controller builds a distance model every frame: the robot's hulls and bounds are made once
    per robot and shared, and a model on them gives the distances of one whose hulls are new."""
    problem = elbow_wall_problem(robot)
    first = DistanceModel(robot, problem.scene, 1.0)
    shared = DistanceModel(robot, problem.scene, 1.0)
    n = first.n_robot
    kept = [first.geometry_model.geometryObjects[i].geometry for i in range(n)]
    again = [shared.geometry_model.geometryObjects[i].geometry for i in range(n)]
    assert all(a is b for a, b in zip(kept, again, strict=True))  # the same coal objects
    monkeypatch.setattr(ik_distances, "_BODIES", weakref.WeakKeyDictionary())
    fresh = DistanceModel(robot, problem.scene, 1.0)
    made = [fresh.geometry_model.geometryObjects[i].geometry for i in range(n)]
    assert not any(a is b for a, b in zip(kept, made, strict=True))  # hulls made again
    assert np.array_equal(shared.body_segment, fresh.body_segment) and np.array_equal(shared.radius, fresh.radius)
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(robot.lower, robot.upper)
        a, b = shared.near_at(q), fresh.near_at(q)
        assert np.array_equal(a.pair, b.pair)
        assert np.array_equal(a.distance, b.distance) and np.array_equal(a.normal, b.normal)
        assert np.array_equal(a.point, b.point) and np.array_equal(a.other_point, b.other_point)


def test_collision_constraints_turn_a_collision_into_a_named_stall(robot):
    """On the plate scene the field alone lets the hand hit the plate; with the constraints the
    arm stops at the safety distance (a local minimum), the harness finds no collision."""
    problem = plate_problem(robot)
    off = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0, collision_constraints=False, escape_attempts=0)
    ev_off = planbench.evaluate(problem, off)
    assert off.status is PlanStatus.COLLISION and "plate" in ev_off.failure
    on = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0, escape_attempts=0)
    ev_on = planbench.evaluate(problem, on)
    assert on.status is PlanStatus.LOCAL_MINIMUM, on.message
    assert "collision" not in ev_on.failure
    safety = MatrixFieldQPConfig().collision_safety
    assert safety - 1e-4 <= ev_on.min_clearance < safety + 1e-3  # held at the safety distance
    assert np.nanmin(on.info["qp_clearance"]) >= safety - 1e-4
    assert np.nanmax(on.info["qp_collision_rows"]) >= 1


def test_collision_constraints_off_leave_the_qp_without_rows(robot):
    problem = plate_problem(robot)
    q = problem.start
    qp_on = prepared(problem).step_at(q)[0]
    qp_off = prepared(problem, collision_constraints=False).step_at(q)[0]
    assert qp_on.G is not None and len(qp_on.h) >= 1
    assert qp_off.G is None
    assert prepared(problem, collision_constraints=False).distances is None


def sandwich_problem(robot):
    """Two plates 1 cm from either side of the arm (links 1 and 2) at the ready pose."""
    q = np.array(robot.home)
    c = robot.frame_pose(q, "panda_link4").translation
    size = (0.6, 0.02, 0.6)
    plates = []
    for name, side in (("left", 1.0), ("right", -1.0)):
        far = c[1] + side * 0.3  # a probe 30 cm away, then moved to leave 1 cm
        probe = Obstacle("probe", "box", position=(c[0], far, c[2]), size=size)
        d = DistanceModel(robot, Scene((probe,)), 1.0, self_pairs=False).near_at(q).distance.min()
        plates.append(Obstacle(name, "box", position=(c[0], far - side * (d - 0.01), c[2]), size=size))
    goal = q.copy()
    goal[0] += 0.5
    return problem_from(robot, q, goal, Scene(tuple(plates), name="sandwich"))


@pytest.mark.filterwarnings("ignore:OSQP exited")
def test_a_retreat_the_limits_cannot_give_is_a_named_infeasible_step(robot):
    """Closer than the safety distance on both sides, the constraints ask the arm to move away
    from both plates at once: no step does, and the plan ends INFEASIBLE naming the pair."""
    problem = sandwich_problem(robot)
    result = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0, collision_safety=0.02)
    assert result.status is PlanStatus.INFEASIBLE
    assert "move away from obstacle" in result.message and "safety distance of 20 mm" in result.message
    assert result.info["qp_failure"]["collision_pair"][1] in ("obstacle:left", "obstacle:right")
    assert len(result.path) == 1  # no step taken
    # with room to spare the same scene plans on (and never touches a plate)
    free = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=5.0)
    assert free.status is not PlanStatus.INFEASIBLE
    assert "collision" not in (planbench.evaluate(problem, free).failure or "")


def test_the_check_ahead_keeps_a_face_turning_onto_a_shelf_at_the_safety_distance(monkeypatch):
    """mbm:bookshelf_thin/0005: a finger's face lies flat on a shelf board while the arm turns;
    the witness point's linearisation misses the corner that comes down. The check ahead adds
    its rows; without it the finger sinks below the safety distance."""
    problem = planbench.load_problems("mbm:bookshelf_thin/0005")[0]
    safety = MatrixFieldQPConfig().collision_safety
    result = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=10.0)
    assert np.nansum(result.info["qp_corrections"]) > 0
    assert np.nanmin(result.info["qp_clearance"]) >= safety - 1e-4
    monkeypatch.setattr(qp_planner, "MAX_CORRECTIONS", 0)
    unchecked = planbench.plan(problem, MatrixFieldQPPlanner, time_limit=10.0)
    assert np.nansum(unchecked.info["qp_corrections"]) == 0
    assert np.nanmin(unchecked.info["qp_clearance"]) < safety - 5e-4


def test_collision_settings_are_validated():
    with pytest.raises(InvalidConfigError, match="collision_gain"):
        MatrixFieldQPConfig(collision_gain=200.0)  # times dt = 2 > 1
    with pytest.raises(InvalidConfigError, match="collision_gain"):
        MatrixFieldQPConfig(collision_gain=0.0)
    with pytest.raises(InvalidConfigError, match="collision_safety"):
        MatrixFieldQPConfig(collision_safety=0.2, collision_influence=0.1)
    with pytest.raises(InvalidConfigError, match="collision_safety"):
        MatrixFieldQPConfig(collision_safety=-0.001)
    with pytest.raises(InvalidConfigError, match="collision_influence"):
        MatrixFieldQPConfig(collision_influence=float("inf"))
    with pytest.raises(InvalidConfigError, match="collision_constraints"):
        MatrixFieldQPConfig(collision_constraints="yes")
    assert MatrixFieldQPConfig(collision_gain=100.0).collision_gain == 100.0  # gain dt = 1 is allowed


SOLVERS = [s for s in EXACT_SOLVERS if s in installed_solvers()]


@pytest.mark.skipif(len(SOLVERS) < 2, reason=f"needs two qpsolvers backends, installed: {installed_solvers()}")
@pytest.mark.parametrize("solver", SOLVERS[1:])
def test_backends_give_the_same_step(robot, solver):
    start = np.array(robot.home)
    goal = start.copy()
    goal[0] -= 1.5
    goal[1] += 0.5
    problem = problem_from(robot, start, goal)
    wall = elbow_wall_problem(robot)
    # velocity limits active; no constraint active; velocity dampers in the QP
    for prob, q, fast in (
        (problem, start, {"speed_max": 5.0}),
        (problem, start + 0.05, {}),
        (wall, wall.start, {"velocity_dampers": True}),
        (wall, wall.start, {}),  # collision constraints
    ):
        a = prepared(prob, solver=SOLVERS[0], **fast).step_at(q)[1]
        b = prepared(prob, solver=solver, **fast).step_at(q)[1]
        assert np.allclose(a, b, atol=1e-5), (SOLVERS[0], solver, a, b)


def test_limit_bounds_keep_one_step_inside():
    q = np.array([0.0, 0.99, -0.99])
    lb, ub = limit_bounds(q, -np.ones(3), np.ones(3), np.full(3, 2.0), 0.01)
    assert np.allclose(ub, [2.0, 1.0, 2.0]) and np.allclose(lb, [-2.0, -2.0, -1.0])
    assert np.all(ub <= 2.0 * (1 - 1e-9))
