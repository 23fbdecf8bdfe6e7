"""OMPL baselines: each solves small problems (validated by the harness), same seed -> same path,
settings are checked, grid mode agrees with the primitives, OMPL stays quiet."""

import gc
import json
import subprocess
import sys

import numpy as np
import pytest

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.conformance import blocked_problem, check_planner, trivial_problem
from planbench.errors import InvalidConfigError, UnknownNameError
from planbench.planner import PlanStatus
from planbench.problem import Problem
from planbench.scene import Obstacle, Scene

pytest.importorskip("ompl")

from planbench_plugins.ompl_planners import (  # noqa: E402
    BITstarPlanner,
    KPIECEPlanner,
    OMPLAnyConfig,
    OMPLPlanner,
    PRMstarPlanner,
    RRTConnectPlanner,
    RRTstarPlanner,
    geometric_planners,
    planner_parameters,
)
from planbench_plugins.ompl_planners.grid import grid_checker, grid_for_scene  # noqa: E402

NAMED = [RRTConnectPlanner, RRTstarPlanner, BITstarPlanner, PRMstarPlanner, KPIECEPlanner]


@pytest.fixture(scope="module")
def blocked():
    return blocked_problem()


def solved(problem, planner, **kw):
    result = planbench.plan(problem, planner, **{"seed": 3, "time_limit": 5.0, **kw})
    ev = planbench.evaluate(problem, result)
    assert result.status is PlanStatus.SUCCESS, result.message
    assert ev.success, ev.failure
    return result


@pytest.mark.parametrize("cls", NAMED, ids=lambda c: c.name)
def test_each_planner_solves_the_free_problem(cls):
    result = solved(trivial_problem(), cls)
    assert result.target == "configuration"
    assert result.info["ompl_planner"] == cls.ompl_planner


@pytest.mark.parametrize(
    "cls", [RRTConnectPlanner, BITstarPlanner, PRMstarPlanner, KPIECEPlanner], ids=lambda c: c.name
)
def test_planners_go_around_an_obstacle(cls, blocked):
    straight = planbench.plan(blocked, "straight-line")
    assert straight.status is PlanStatus.COLLISION  # the obstacle is really in the way
    result = solved(blocked, cls)
    assert len(result.path) >= 3
    assert result.info["collision_checks"] > 0


def test_any_ompl_planner_by_name(blocked):
    result = solved(blocked, OMPLPlanner(planner="LBKPIECE1", params={"range": 0.5}))
    assert result.info["ompl_planner"] == "LBKPIECE1"
    assert {"RRTConnect", "RRTstar", "BITstar", "PRMstar", "KPIECE1", "AORRTC"} <= set(geometric_planners())


def test_simplification_is_on_by_default_and_timed_apart(blocked):
    on = solved(blocked, RRTConnectPlanner)
    off = solved(blocked, RRTConnectPlanner, simplify=False)
    assert on.info["simplify_time"] > 0 and off.info["simplify_time"] == 0.0
    assert on.info["solve_time"] + on.info["simplify_time"] <= on.planning_time
    # same seed: the same raw path, which simplification shortens
    assert planbench.metrics.joint_path_length(on.path) < planbench.metrics.joint_path_length(off.path)


@pytest.mark.parametrize(
    "cls", [RRTConnectPlanner, RRTstarPlanner, BITstarPlanner, KPIECEPlanner, OMPLPlanner], ids=lambda c: c.name
)
def test_conformance(cls):
    assert check_planner(cls, time_limit=1.0) == []


def test_prmstar_conformance_except_reproducibility():
    # OMPL's PRM searches the roadmap in a second thread while it grows: the path found depends on
    # thread timing, so two runs with one seed may differ (documented). Everything else conforms.
    problems = check_planner(PRMstarPlanner, time_limit=1.0)
    assert all(p.check == "non-deterministic" for p in problems), problems


def path_of(problem, planner, seed):
    return planbench.plan(problem, planner, seed=seed, time_limit=5.0).path


def test_same_seed_same_path_in_one_process(blocked):
    a, b = path_of(blocked, RRTConnectPlanner, 7), path_of(blocked, RRTConnectPlanner, 7)
    c = path_of(blocked, RRTConnectPlanner, 8)
    np.testing.assert_array_equal(a, b)
    assert a.shape != c.shape or not np.allclose(a, c)


SCRIPT = """
import json, sys, planbench
from planbench.conformance import blocked_problem
from planbench_plugins.ompl_planners import RRTConnectPlanner, PRMstarPlanner
r = planbench.plan(blocked_problem(), RRTConnectPlanner, seed=int(sys.argv[1]), time_limit=5.0)
planbench.plan(blocked_problem(), PRMstarPlanner, seed=1, time_limit=0.5)  # a threaded planner too
print(json.dumps(r.path.tolist()))
"""


def run_fresh(seed):
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(seed)], capture_output=True, text=True, check=True)
    return np.array(json.loads(out.stdout)), out.stderr


def test_same_seed_same_path_in_a_fresh_process_and_nothing_on_the_terminal(blocked):
    fresh, stderr = run_fresh(7)
    again, _ = run_fresh(7)
    assert stderr == ""  # no OMPL log lines, no nanobind leak report at exit
    np.testing.assert_array_equal(fresh, again)
    np.testing.assert_array_equal(fresh, path_of(blocked, RRTConnectPlanner, 7))  # and the same as in-process


def test_log_output_when_asked(capfd):
    planbench.plan(trivial_problem(), RRTConnectPlanner(log_level="info"), time_limit=1.0)
    out = capfd.readouterr()
    assert "RRTConnect" in out.out + out.err
    planbench.plan(trivial_problem(), RRTConnectPlanner(), time_limit=1.0)
    out = capfd.readouterr()
    assert out.out + out.err == ""


def test_settings_are_checked():
    with pytest.raises(UnknownNameError, match="range"):
        RRTConnectPlanner(params={"rang": 1.0})
    with pytest.raises(UnknownNameError, match="RRTConnect"):
        OMPLPlanner(planner="RRTConect")
    with pytest.raises(InvalidConfigError):
        RRTConnectPlanner(collision="voxels")
    with pytest.raises(InvalidConfigError):
        RRTConnectPlanner(resolution=0.0)
    assert "range" in planner_parameters("RRTConnect")
    assert "rewire_factor" in planner_parameters("RRTstar")
    assert OMPLAnyConfig().planner == "RRTConnect"


def test_the_time_limit_counts_the_chosen_clock(blocked, monkeypatch):
    # a search that can never connect (every motion blocked) ends when the "cpu" clock passes the
    # deadline, whatever the elapsed time: the clock here is a counter that jumps after 40 reads
    import time

    from planbench_plugins.ompl_planners import base
    from planbench_plugins.ompl_planners.motion import SegmentChecker

    reads = []

    def fake_cpu() -> float:
        reads.append(1)
        return 0.0 if len(reads) <= 40 else 1e9

    monkeypatch.setitem(base.CLOCKS, "cpu", fake_cpu)
    monkeypatch.setattr(SegmentChecker, "motion_free", lambda self, a, b: False)
    t0 = time.perf_counter()
    result = planbench.plan(blocked, RRTConnectPlanner, seed=3, time_limit=60.0, clock="cpu")
    assert result.status is PlanStatus.TIMEOUT and result.info["clock"] == "cpu"
    assert len(reads) > 40  # OMPL's search read the clock until it jumped
    assert time.perf_counter() - t0 < 30.0  # not the 60 s of elapsed time
    with pytest.raises(InvalidConfigError, match="clock"):
        RRTConnectPlanner(clock="thread")
    assert RRTConnectPlanner().config.clock == "wall"


def test_pose_only_goal_uses_ik_samples(panda, blocked):
    problem = Problem.create(panda, blocked.scene, blocked.start, goal_pose=blocked.goal.pose, id="test:pose")
    result = solved(problem, RRTConnectPlanner, time_limit=5.0)
    assert result.target == "pose"
    assert result.info["ik_goals"] >= 1


def test_goal_configuration_in_collision_is_an_invalid_goal(blocked):
    obstacle = Obstacle("on-goal", "sphere", position=tuple(blocked.goal.pose.position), radius=0.05)
    scene = Scene((*blocked.scene.obstacles, obstacle), name="goal-blocked")
    problem = Problem.create(blocked.robot, scene, blocked.start, blocked.goal.q, id="test:goal-blocked")
    result = planbench.plan(problem, RRTConnectPlanner, time_limit=1.0)
    assert result.status is PlanStatus.INVALID_GOAL
    assert "in collision" in result.message


def test_start_in_collision_is_refused_before_the_ik_sampler_runs(blocked):
    # planbench.plan refuses it earlier (exact geometry); a planner called directly must too
    hand = tuple(blocked.robot.frame_pose(blocked.start).translation)
    scene = Scene((*blocked.scene.obstacles, Obstacle("on-start", "sphere", position=hand, radius=0.05)))
    problem = Problem.create(blocked.robot, scene, blocked.start, goal_pose=blocked.goal.pose, id="test:start-blocked")
    planner = RRTConnectPlanner()
    planner.setup(problem)
    result = planner.plan(problem, time_limit=1.0, rng=np.random.default_rng(0))
    assert result.status is PlanStatus.INVALID_START and "start in collision" in result.message
    assert "ik_time" not in result.info


@pytest.mark.slow
def test_a_reused_planner_checks_each_new_problem_against_its_own_scene(blocked):
    # CPython often gives a new problem the address (id) of one just freed: a checker cached by id
    # would plan the goal-blocked problem against the free scene of the one before it
    planner = RRTConnectPlanner()
    blocker = Obstacle("on-goal", "sphere", position=tuple(blocked.goal.pose.position), radius=0.05)
    empty, goal_scene = Scene(name="empty"), Scene((blocker,), name="goal-blocked")
    reused = 0
    for _ in range(30):
        free = Problem.create(blocked.robot, empty, blocked.start, blocked.goal.q, id="test:free")
        planner.setup(free)
        freed = id(free)
        del free
        gc.collect()
        goal_blocked = Problem.create(blocked.robot, goal_scene, blocked.start, blocked.goal.q, id="test:g")
        reused += id(goal_blocked) == freed
        result = planner.plan(goal_blocked, time_limit=1.0, rng=np.random.default_rng(0))
        assert result.status is PlanStatus.INVALID_GOAL, (result.status, reused)


def test_ompl_rejecting_a_valid_goal_says_the_goal_was_checked():
    # OMPL 2.0.1's AORRTC errors on the zero-cost direct connection of a free straight line
    result = planbench.plan(trivial_problem(), "ompl:AORRTC", seed=0, time_limit=1.0)
    if result.status is PlanStatus.SUCCESS:
        pytest.skip("this OMPL's AORRTC solves a free straight line")
    assert result.status is PlanStatus.INVALID_GOAL
    assert "collision-free and within the limits" in result.message and "log_level" in result.message


def test_goal_configuration_outside_the_limits_plans_to_its_pose():
    # MotionBenchMaker's goal configuration has joint 4 just outside the Panda's limits; its pose is
    # reachable within them: the IK sampler (seeded with the clipped configuration) gives the goal.
    (problem,) = planbench.load_problems("mbm:table_under_pick/0097")
    assert problem.check().goal_configuration  # really outside the limits
    result = solved(problem, RRTConnectPlanner, time_limit=2.0)
    assert result.target == "pose"
    assert "panda_joint4" in result.info["goal_outside_limits"]
    assert result.info["ik_goals"] >= 1


def test_ik_from_a_goal_just_outside_the_limits_stays_next_to_it():
    from planbench.problem import pose_error
    from planbench_plugins.ompl_planners.ik import sample_goal_configurations

    (problem,) = planbench.load_problems("mbm:table_under_pick/0097")
    robot, checker = problem.robot, CollisionChecker(problem.robot, problem.scene)
    seed = np.clip(problem.goal.q, robot.lower, robot.upper)
    rng = np.random.default_rng(0)
    (q,) = sample_goal_configurations(problem, checker.in_collision, rng, 1, 1.0, seeds=[seed], iterations=200)
    assert robot.limit_violations(q) == [] and not checker.in_collision(q)
    assert np.abs(q - problem.goal.q).max() < 0.1  # the seeded attempt, not a random restart
    position, orientation = pose_error(robot, q, problem.goal.pose)
    assert position <= 0.5 * problem.tolerances.position and orientation <= 0.5 * problem.tolerances.orientation


# --- motion validation and the path that is returned ----------------------------------------------


def test_a_search_that_uses_the_whole_time_limit_returns_the_raw_path_unsimplified(blocked):
    # improves until the limit, then certifies its path: it may answer past the limit (0.11 s on the
    # 2-core VM), which is a timeout now (issue 27, part 4); the path it returns is still the raw one
    result = planbench.plan(blocked, BITstarPlanner, seed=3, time_limit=1.0, optimize=True)
    assert result.status in (PlanStatus.SUCCESS, PlanStatus.TIMEOUT), result.message
    assert result.path is not None and result.info["path_source"] == "raw"
    assert result.info["simplify_time"] == 0.0 and "no time left" in result.info["simplify_skipped"]


def test_a_simplified_path_that_grazes_falls_back_to_the_reduced_path_without_repair(blocked, monkeypatch):
    from planbench.checking.certified import CertifiedChecker, PathVerdict

    calls = []
    original = CertifiedChecker.check_path

    def check_path_rejecting_the_first_path(self, path):
        calls.append(len(path))
        return PathVerdict(False, segment=0) if len(calls) == 1 else original(self, path)

    monkeypatch.setattr(CertifiedChecker, "check_path", check_path_rejecting_the_first_path)
    result = solved(blocked, RRTConnectPlanner, repair_attempts=0)
    assert result.info["path_source"] == "reduced" and len(calls) == 3  # simplified, reduced, the harness
    assert result.info["repaired_segments"] == 0


def test_a_path_that_fails_every_check_is_a_collision(blocked, monkeypatch):
    from planbench.checking.certified import CertifiedChecker, PathVerdict

    monkeypatch.setattr(CertifiedChecker, "check_path", lambda self, path: PathVerdict(False, segment=0))
    result = planbench.plan(blocked, RRTConnectPlanner, seed=3, time_limit=5.0, repair_attempts=1)
    assert result.status is PlanStatus.COLLISION
    assert result.info["path_source"] == "none"
    assert result.info["repaired_segments"] == 0  # the one attempt found no certified detour
    assert result.path is not None
    assert result.planning_time < 5.0  # a repair's sub-query is bounded (SUBSOLVE_TIME), not the time limit


@pytest.fixture(scope="module")
def grazing():
    """MBM bookshelf_small/0004, seed 0: OMPL's simplified path grazes the shelf (its sampled motion
    checks pass, the certified check does not)."""
    from planbench.problems.datasets import load_problems

    (problem,) = load_problems("mbm:bookshelf_small/0004")
    return problem


def test_a_grazing_simplified_path_is_repaired_and_certifies(grazing):
    from planbench.checking.certified import CertifiedChecker
    from planbench.metrics import densify
    from planbench.validate import ValidationSettings

    certified = CertifiedChecker(grazing.robot, grazing.scene, ValidationSettings().certification())
    # without certification OMPL returns its simplified path: every sampled check passes, yet it collides
    unchecked = planbench.plan(grazing, RRTConnectPlanner, seed=0, time_limit=5.0, verify=False)
    dense, _ = densify(unchecked.path, 0.01)
    checker = CollisionChecker(grazing.robot, grazing.scene)
    assert not any(checker.in_collision(q) for q in dense)
    verdict = certified.check_path(unchecked.path)
    assert not verdict.free
    # the same query, certified: the failing segment is re-planned, the rest of the path is kept
    result = solved(grazing, RRTConnectPlanner, seed=0)
    assert result.info["path_source"] == "simplified" and result.info["repaired_segments"] >= 1
    assert certified.check_path(result.path).free
    s = verdict.segment
    np.testing.assert_array_equal(result.path[: s + 1], unchecked.path[: s + 1])  # the certified prefix
    np.testing.assert_array_equal(result.path[-(len(unchecked.path) - s - 1) :], unchecked.path[s + 1 :])
    assert len(result.path) > len(unchecked.path)
    # without repair, the simplified path is given up for the (longer) reduced one
    plain = solved(grazing, RRTConnectPlanner, seed=0, repair_attempts=0)
    assert plain.info["path_source"] in ("reduced", "raw") and plain.info["repaired_segments"] == 0


def test_certified_motion_checks_return_certified_checks_only(grazing):
    from planbench.checking.certified import CertifiedChecker
    from planbench.validate import ValidationSettings

    result = solved(grazing, RRTConnectPlanner, seed=0, motion_check="certified")
    assert result.info["repaired_segments"] == 0  # nothing to repair: every edge was certified when added
    assert result.info["certified_checks"] > 0
    certified = CertifiedChecker(grazing.robot, grazing.scene, ValidationSettings().certification())
    assert certified.check_path(result.path).free
    simplified = solved(grazing, RRTConnectPlanner, seed=0, simplify_check="certified")
    assert simplified.info["path_source"] == "simplified" and simplified.info["repaired_segments"] == 0


def test_motion_check_settings_are_validated():
    for bad in ({"motion_check": "exact"}, {"simplify_check": None}, {"repair_attempts": -1}, {"repair_attempts": 1.5}):
        with pytest.raises(InvalidConfigError, match=next(iter(bad))):
            RRTConnectPlanner(**bad)
    assert RRTConnectPlanner().config.motion_check == "sampled"


# --- occupancy-grid collision mode ---------------------------------------------------------------


def aligned_scene(res):
    """Boxes whose faces lie on multiples of the grid resolution."""
    return Scene(
        (
            Obstacle("table", "box", position=(0.5, 0.0, 0.1), size=(0.4, 0.8, 0.2)),
            Obstacle("post", "box", position=(0.3, 0.3, 0.5), size=(0.1, 0.1, 0.6)),
        ),
        name="aligned",
    )


@pytest.mark.parametrize("geometry", ["octree", "boxes"])
def test_grid_mode_agrees_with_primitives_on_an_aligned_scene(panda, geometry):
    res = 0.05
    scene = aligned_scene(res)
    grid = grid_for_scene(scene, res)
    assert grid.data.sum() == 8 * 16 * 4 + 2 * 2 * 12  # exactly the boxes' cells
    exact = CollisionChecker(panda, scene)
    voxels = grid_checker(panda, grid, geometry)
    Q = np.random.default_rng(0).uniform(panda.lower, panda.upper, size=(400, 7))
    a = np.array([exact.in_collision(q) for q in Q])
    b = np.array([voxels.in_collision(q) for q in Q])
    # configurations touching a box face exactly are measure-zero; away from them both agree
    np.testing.assert_array_equal(a, b)
    assert a.any() and not a.all()


def test_grid_mode_plans_a_valid_path(blocked):
    # the grid inflates obstacles by at most a cell: a path free in the grid is free in the scene
    solved(blocked, RRTConnectPlanner, collision="grid", grid_resolution=0.02)


def test_merged_boxes_cover_exactly_the_occupied_cells():
    from planbench.geometry.occupancy import merge_cells

    rng = np.random.default_rng(0)
    for density in (0.1, 0.5, 0.9):
        occupied = rng.random((7, 6, 9)) < density
        cover = np.zeros(occupied.shape, dtype=int)
        for lo, hi in merge_cells(occupied):
            cover[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] += 1
        np.testing.assert_array_equal(cover, occupied)  # every cell once, nothing else
    solid = np.zeros((10, 10, 10), dtype=bool)
    solid[2:7, 1:9, 3:5] = True
    assert merge_cells(solid) == [((2, 1, 3), (7, 9, 5))]  # a voxelized box is one box
