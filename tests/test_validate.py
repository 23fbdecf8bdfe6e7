import json
import math
from importlib import resources

import numpy as np
import pytest

import planbench
from conftest import midpoint_wall
from planbench import PlanResult, PlanStatus, Problem, Scene, evaluate
from planbench.checking.collision import CollisionChecker
from planbench.problem import Goal, Pose


def straight(problem, **kw):
    return PlanResult(PlanStatus.SUCCESS, np.stack([problem.start, problem.goal.q]), target="configuration", **kw)


def test_free_straight_line_is_valid(free_problem):
    ev = evaluate(free_problem, straight(free_problem))
    assert ev.success, ev.failure
    assert all(ev.checks.values())
    assert ev.min_clearance == math.inf  # empty scene


def test_segment_through_thin_obstacle_is_rejected_although_both_waypoints_are_free(panda, free_problem):
    wall = midpoint_wall(panda, free_problem.start, free_problem.goal.q, thickness=0.004)
    p = Problem.create(panda, Scene((wall,)), free_problem.start, free_problem.goal.q)
    checker = CollisionChecker.for_problem(p)
    assert not checker.in_collision(p.start) and not checker.in_collision(p.goal.q)
    ev = evaluate(p, straight(p))
    assert not ev.success
    assert not ev.checks["collision_free"]
    assert "collision on segment 0" in ev.failure and "obstacle:plate" in ev.failure
    assert ev.collision_segment == 0 and 0 < ev.collision_fraction < 1 and "plate" in ev.collision_pair


def test_planner_check_count_is_kept_apart_from_the_validation_count(free_problem):
    reported = evaluate(free_problem, straight(free_problem, info={"collision_checks": 7}))
    silent = evaluate(free_problem, straight(free_problem))
    assert reported.collision_checks == 7 and silent.collision_checks is None
    assert reported.validation_checks == silent.validation_checks > 0  # the certifier's distance queries
    failed = evaluate(free_problem, PlanResult(PlanStatus.TIMEOUT, None, info={"collision_checks": 3}))
    assert failed.collision_checks == 3 and failed.validation_checks == 0


def test_joint_limit_violation_is_rejected(panda, free_problem):
    over = free_problem.start.copy()
    over[3] = panda.upper[3] + 0.01
    path = np.stack([free_problem.start, over, free_problem.goal.q])
    ev = evaluate(free_problem, PlanResult(PlanStatus.SUCCESS, path, target="configuration"))
    assert not ev.success and not ev.checks["joint_limits"]
    assert "waypoint 1 outside joint limits" in ev.failure and "panda_joint4" in ev.failure
    assert ev.max_limit_violation == pytest.approx(0.01)


def test_too_fast_trajectory_is_rejected(panda, free_problem):
    start, goal = free_problem.start, free_problem.goal.q
    fastest = float((np.abs(goal - start) / panda.velocity_limit).max())
    ok = evaluate(free_problem, straight(free_problem, times=[0.0, fastest]))
    assert ok.success and ok.max_velocity_ratio == pytest.approx(1.0)
    ev = evaluate(free_problem, straight(free_problem, times=[0.0, 0.5 * fastest]))
    assert not ev.success and not ev.checks["velocity_limits"]
    assert ev.max_velocity_ratio == pytest.approx(2.0)
    assert "too fast" in ev.failure
    back = evaluate(
        free_problem,
        PlanResult(PlanStatus.SUCCESS, np.stack([start, goal, goal]), times=[0.0, 1.0, 1.0], target="configuration"),
    )
    assert not back.success and "increase strictly" in back.failure


def test_planner_claims_are_not_trusted(free_problem):
    short = PlanResult(PlanStatus.SUCCESS, np.stack([free_problem.start, free_problem.start + 0.1]))
    ev = evaluate(free_problem, short)
    assert not ev.success and "goal not reached" in ev.failure
    moved = PlanResult(PlanStatus.SUCCESS, np.stack([free_problem.start + 0.01, free_problem.goal.q]))
    assert "does not start at the start" in evaluate(free_problem, moved).failure
    nan = PlanResult(PlanStatus.SUCCESS, np.stack([free_problem.start, np.full(7, np.nan)]))
    assert "NaN" in evaluate(free_problem, nan).failure
    none = evaluate(free_problem, PlanResult(PlanStatus.LOCAL_MINIMUM, message="stalled"))
    assert not none.success and none.failure == "local_minimum: stalled"


@pytest.mark.parametrize("status", [s for s in PlanStatus if s is not PlanStatus.SUCCESS])
def test_a_valid_path_counts_only_with_a_claim_of_success(free_problem, status):
    """Success and status never contradict: a valid path the planner calls a failure is kept and
    measured, not counted (a caller acts on the status)."""
    ev = evaluate(free_problem, straight(free_problem, message="gave up").replace(status=status))
    assert not ev.success and ev.status == status.value
    assert ev.checks["claimed_success"] is False and ev.checks["collision_free"] and ev.checks["goal_pose"]
    assert ev.failure.startswith(f"{status.value}: gave up") and "not counted" in ev.failure
    assert ev.joint_path_length > 0  # the metrics are kept for inspection
    ok = evaluate(free_problem, straight(free_problem))
    assert ok.success and ok.status == "success" and ok.checks["claimed_success"]


def test_joint_goal_checked_only_when_planner_claims_the_configuration(panda, free_problem):
    # same final pose, different joint vector is impossible to craft simply; instead move the goal
    # configuration slightly and keep the pose goal of the original: pose within tolerance.
    q_end = free_problem.goal.q + np.array([0, 0, 0, 0, 0, 0, 0.02])  # last joint: orientation only
    path = np.stack([free_problem.start, q_end])
    pose_ev = evaluate(free_problem, PlanResult(PlanStatus.SUCCESS, path, target="pose"))
    conf_ev = evaluate(free_problem, PlanResult(PlanStatus.SUCCESS, path, target="configuration"))
    assert pose_ev.success
    assert not conf_ev.success and "goal configuration not reached" in conf_ev.failure
    assert conf_ev.final_joint_error == pytest.approx(0.02)


def test_metrics_of_a_hand_made_path_have_their_exact_values(panda):
    home = panda.home.copy()
    a = home.copy()
    a[0] += 0.5  # joint 1 turns 0.5 rad
    b = a.copy()
    b[1] += 0.3  # then joint 2 turns 0.3 rad
    path = np.stack([home, a, b])
    M = panda.frame_pose(b)
    problem = Problem(panda, Scene(), home, Goal(Pose(M.translation, M.rotation, "panda_link8")))
    ev = evaluate(problem, PlanResult(PlanStatus.SUCCESS, path))
    assert ev.success, ev.failure
    assert ev.n_waypoints == 3
    assert ev.joint_path_length == pytest.approx(0.8, abs=1e-12)
    assert ev.smoothness == pytest.approx(math.pi / 2, abs=1e-12)
    assert ev.duration == pytest.approx(0.5 / 2.175 + 0.3 / 2.175, abs=1e-12)
    assert ev.final_position_error == pytest.approx(0.0, abs=1e-12)
    # End effector: a circle about each moving joint's axis, checked every 0.01 rad, so the
    # measured length is a sum of chords 2 r sin(0.005) with r the distance to that axis.
    data = panda.model.createData()

    def radius_about_joint(q, joint_index):
        import pinocchio as pin

        pin.forwardKinematics(panda.model, data, q)
        axis_placement = data.oMi[joint_index]
        axis = axis_placement.rotation[:, 2]
        v = panda.frame_pose(q).translation - axis_placement.translation
        return float(np.linalg.norm(v - v.dot(axis) * axis))

    chord = 2 * math.sin(0.005)
    expected = 50 * chord * radius_about_joint(home, 1) + 30 * chord * radius_about_joint(a, 2)
    assert ev.ee_path_length == pytest.approx(expected, rel=1e-9)


def test_clearance_matches_the_mbm_reference_values():
    ref = json.loads((resources.files("planbench") / "data" / "mbm" / "validation.json").read_text())["problems"]
    for pid in ("box/0001", "cage/0050", "bookshelf_thin/0007"):
        p = planbench.load_problems(f"mbm:{pid}")[0]
        ev = evaluate(p, PlanResult(PlanStatus.SUCCESS, p.start[None, :]))
        assert ev.min_clearance == pytest.approx(ref[pid]["start"]["erd_f065"]["clearance"], abs=2e-6)


def test_unusable_paths_are_rejected_by_name(free_problem):
    start = free_problem.start
    inf = PlanResult(PlanStatus.SUCCESS, np.stack([start, np.full(7, np.inf)]))
    assert "NaN or infinite" in evaluate(free_problem, inf).failure
    narrow = PlanResult(PlanStatus.SUCCESS, np.zeros((3, 6)))
    assert "6 columns" in evaluate(free_problem, narrow).failure
    empty = evaluate(free_problem, PlanResult(PlanStatus.SUCCESS, np.zeros((0, 7))))
    assert not empty.success and "no path" in empty.failure
    with pytest.raises(ValueError, match="shape"):
        PlanResult(PlanStatus.SUCCESS, np.zeros(7))  # one row given flat: not an (N, nq) path
