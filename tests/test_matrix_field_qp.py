"""Tests of the QP variant of the matrix-field planner (``matrix-field-qp``, docs/method.md section 5)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

import planbench
from planbench import PlanStatus, Problem, Scene
from planbench.conformance import check_planner, trivial_problem
from planbench.errors import InvalidConfigError
from planbench.robot import load_robot
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field_qp import MatrixFieldQPConfig, MatrixFieldQPPlanner, installed_solvers
from planbench_plugins.matrix_field_qp.formulation import limit_bounds, objective

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
    assert result.info["solver"] == "osqp"
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
    result = planbench.plan(problem, MatrixFieldQPPlanner, solver_options={"max_iter": 1}, time_limit=5.0)
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
    from planbench import Obstacle

    q = np.array(robot.home)
    elbow = robot.frame_pose(q, "panda_link4").translation
    wall = Obstacle("wall", "box", position=(elbow[0], elbow[1] + 0.13, elbow[2]), size=(0.4, 0.02, 0.4))
    goal = q.copy()
    goal[0] += 0.8
    return problem_from(robot, q, goal, Scene((wall,), name="wall"))


def test_velocity_dampers_hold_near_an_obstacle(robot):
    problem = elbow_wall_problem(robot)
    q = problem.start
    planner = prepared(problem, velocity_dampers=True)
    qp, qd, diag = planner.step_at(q)
    assert qp.G is not None and len(qp.h) >= 1
    assert np.all(qp.G @ qd <= qp.h + 1e-6)
    assert diag[2] > 0  # the field acts


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
    ):
        a = prepared(prob, solver=SOLVERS[0], **fast).step_at(q)[1]
        b = prepared(prob, solver=solver, **fast).step_at(q)[1]
        assert np.allclose(a, b, atol=1e-5), (SOLVERS[0], solver, a, b)


def test_limit_bounds_keep_one_step_inside():
    q = np.array([0.0, 0.99, -0.99])
    lb, ub = limit_bounds(q, -np.ones(3), np.ones(3), np.full(3, 2.0), 0.01)
    assert np.allclose(ub, [2.0, 1.0, 2.0]) and np.allclose(lb, [-2.0, -2.0, -1.0])
    assert np.all(ub <= 2.0 * (1 - 1e-9))
