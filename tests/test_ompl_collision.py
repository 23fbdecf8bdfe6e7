"""The broadphase behind CollisionChecker.in_collision gives the same answers as checking every pair.

Configurations are taken on the collision boundary (bisection between a free and a colliding
configuration), where a wrong filter would show first. Each is checked with a fresh checker: coal's
GJK warm start makes answers within about a micrometre of contact depend on earlier queries, with or
without broadphase, so both methods must start from the same (empty) history.
"""

import numpy as np
import pytest

from planbench.checking.collision import CollisionChecker
from planbench.problems.datasets import load_problems


def boundary_configurations(checker, robot, n, seed=0):
    rng = np.random.default_rng(seed)
    Q = rng.uniform(robot.lower, robot.upper, size=(200, robot.nq))
    hit = np.array([checker.in_collision_all_pairs(q) for q in Q])
    out = []
    for a, b in zip(Q[~hit][:n], Q[hit][:n], strict=False):
        lo, hi = 0.0, 1.0
        for _ in range(25):
            mid = 0.5 * (lo + hi)
            if checker.in_collision_all_pairs(a + mid * (b - a)):
                hi = mid
            else:
                lo = mid
        out += [a + lo * (b - a), a + hi * (b - a)]
    return out


@pytest.mark.parametrize("selector", ["mbm:bookshelf_thin/0003", "mbm:cage/0001"])
def test_broadphase_agrees_with_all_pairs_on_the_boundary(selector):
    (problem,) = load_problems(selector)
    checker = CollisionChecker(problem.robot, problem.scene)
    configurations = boundary_configurations(checker, problem.robot, 15)
    assert len(configurations) == 30
    answers = []
    for q in configurations:
        fresh = CollisionChecker(problem.robot, problem.scene)
        reference = fresh.in_collision_all_pairs(q)
        assert fresh.in_collision(q) == reference, q
        answers.append(reference)
    assert any(answers) and not all(answers)  # both sides of the boundary were tested


def test_broadphase_agrees_on_random_configurations():
    (problem,) = load_problems("mbm:table_pick/0001")
    checker = CollisionChecker(problem.robot, problem.scene)
    Q = np.random.default_rng(1).uniform(problem.robot.lower, problem.robot.upper, size=(300, 7))
    fast = [checker.in_collision(q) for q in Q]
    assert fast == [checker.in_collision_all_pairs(q) for q in Q]
    assert 0 < sum(fast) < len(fast)
    assert checker.n_checks == 600


def test_a_checker_built_in_steps_answers_as_one_built_at_once():
    """CollisionChecker.in_steps (a control loop's, a yield between its three steps) builds the
    same checker; collisions() and clearance(), whose data are built when first asked, agree."""
    (problem,) = load_problems("mbm:table_pick/0001")
    whole = CollisionChecker(problem.robot, problem.scene)
    steps = CollisionChecker.in_steps(problem.robot, problem.scene)
    yields = 0
    while True:
        try:
            next(steps)
            yields += 1
        except StopIteration as done:
            stepped = done.value
            break
    assert yields == 2 and isinstance(stepped, CollisionChecker)
    Q = np.random.default_rng(2).uniform(problem.robot.lower, problem.robot.upper, size=(100, 7))
    verdicts = [whole.in_collision(q) for q in Q]
    assert verdicts == [stepped.in_collision(q) for q in Q] and 0 < sum(verdicts) < len(verdicts)
    q = Q[int(np.argmax(verdicts))]
    assert stepped.collisions(q) == whole.collisions(q) != []
    assert stepped.clearance(Q[0]) == whole.clearance(Q[0])


# --- OMPL motion validation: the harness's check points, in one batch -----------------------------

pytest.importorskip("ompl")


def test_bisection_order_is_a_permutation_with_the_end_state_first():
    from planbench_plugins.ompl_planners.motion import bisection_order

    for n in (1, 2, 3, 7, 64, 101):
        order = bisection_order(n)
        assert order[0] == n - 1
        assert sorted(order.tolist()) == list(range(n))
    assert bisection_order(9).tolist()[:3] == [8, 3, 1]


def test_motion_checks_agree_with_the_harness_on_every_segment():
    # SegmentChecker.motion_free must answer exactly what planbench.evaluate's dense check answers:
    # the same configurations (densify's), the same broadphase and geometry.
    from planbench.metrics import densify
    from planbench_plugins.ompl_planners.motion import SegmentChecker

    (problem,) = load_problems("mbm:bookshelf_small/0002")
    robot = problem.robot
    checker = CollisionChecker(robot, problem.scene)
    segments = SegmentChecker(checker, 0.01)
    one_by_one = SegmentChecker(checker, 0.01, pooled=False)  # the control loops' kind: no batch pool
    rng = np.random.default_rng(2)
    free = [q for q in rng.uniform(robot.lower, robot.upper, size=(200, 7)) if not checker.in_collision(q)]
    answers, early_stops = [], 0
    for a in free[:40]:
        b = np.clip(a + rng.normal(0.0, 0.4, size=7), robot.lower, robot.upper)
        dense, _ = densify(np.array([a, b]), 0.01)
        reference = not any(checker.in_collision(q) for q in dense[1:])
        before, before_one = segments.n_checks, one_by_one.n_checks
        assert segments.motion_free(a, b) == reference
        assert one_by_one.motion_free(a, b) == reference
        checked = segments.n_checks - before
        assert one_by_one.n_checks - before_one == checked  # stops at the same configuration
        assert checked == len(dense) - 1 if reference else 1 <= checked <= len(dense) - 1
        early_stops += checked < len(dense) - 1
        answers.append(reference)
    assert any(answers) and not all(answers)
    assert early_stops > 0  # a blocked motion stops at its first collision


# --- certified motion checks --------------------------------------------------------------------


def test_verdict_checker_agrees_with_the_harness_and_skips_the_clearance_refinement():
    from planbench.checking.certified import CertifiedChecker
    from planbench.validate import ValidationSettings, verdict_checker

    (problem,) = load_problems("mbm:bookshelf_small/0002")
    robot = problem.robot
    settings = ValidationSettings().certification()
    harness = CertifiedChecker(robot, problem.scene, settings)
    verdicts = verdict_checker(problem)
    checker = CollisionChecker(robot, problem.scene)
    rng = np.random.default_rng(4)
    free = [q for q in rng.uniform(robot.lower, robot.upper, size=(150, 7)) if not checker.in_collision(q)]
    answers, fewer = [], 0
    for a in free[:25]:
        b = np.clip(a + rng.normal(0.0, 0.3, size=7), robot.lower, robot.upper)
        reference, fast = harness.check_segment(a, b), verdicts.check_segment(a, b)
        assert (fast.free, fast.segment) == (reference.free, reference.segment)
        if fast.free:
            assert np.isnan(fast.clearance_lower) and np.isfinite(reference.clearance_lower)
            fewer += fast.queries < reference.queries
        answers.append(fast.free)
    assert any(answers) and not all(answers)
    assert fewer > 0


def test_certified_segments_samples_first_and_remembers_certified_segments():
    from planbench.validate import verdict_checker
    from planbench_plugins.ompl_planners.motion import CertifiedSegments, SegmentChecker

    (problem,) = load_problems("mbm:cage/0002")
    robot = problem.robot
    checker = CollisionChecker(robot, problem.scene)
    segs = CertifiedSegments(SegmentChecker(checker, 0.01), verdict_checker(problem))
    start, goal = problem.start, problem.goal.q
    assert not segs.free(start, goal)  # through the cage: the sampled check rejects it
    assert segs.n_certified == 0  # ... before any distance query
    mid = start + 0.01 * (goal - start)
    assert segs.free(start, mid) and segs.n_certified == 1
    assert segs.free(start, mid) and segs.n_certified == 1  # remembered, not certified again
    path = np.array([start, mid])
    assert segs.known_free(path, 0) and not segs.known_free(path[::-1], 0)
