"""The certified checker: segments are proven free, never sampled (planbench.checking.certified)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import planbench
from conftest import box, midpoint_wall
from planbench import PlanResult, PlanStatus, Problem, Scene, evaluate
from planbench.checking.certified import CertificationSettings, CertifiedChecker
from planbench.checking.collision import CollisionChecker
from planbench.metrics import densify


def _dense_hit(checker: CollisionChecker, a, b, resolution: float) -> bool:
    dense, _ = densify(np.stack([a, b]), resolution)
    return any(checker.in_collision(q) for q in dense)


def test_thin_plate_between_samples_is_a_collision_with_its_place_and_pair(panda, free_problem):
    wall = midpoint_wall(panda, free_problem.start, free_problem.goal.q, thickness=0.002)
    p = Problem.create(panda, Scene((wall,)), free_problem.start, free_problem.goal.q)
    verdict = CertifiedChecker.for_problem(p).check_path(np.stack([p.start, p.goal.q]))
    assert not verdict.free
    assert verdict.segment == 0 and 0.0 < verdict.fraction < 1.0
    assert verdict.pair[1] == "obstacle:plate" and verdict.depth >= 0
    # the reported place is really in contact (within the certification resolution)
    q = p.start + verdict.fraction * (p.goal.q - p.start)
    assert CertifiedChecker.for_problem(p).clearance(q) < 1e-4


def _ceiling_segment(panda):
    """A joint-2 swing whose highest point lies midway between two 0.01 rad samples, under a
    ceiling 3 um below that point: free at every 0.01 rad sample, colliding in between."""
    far = 1.0
    ceiling = box("ceiling", (0.0, 0.0, far + 0.5), (4.0, 4.0, 1.0))
    probe = CollisionChecker(panda, Scene((ceiling,)))
    a0 = panda.home.copy()
    a0[1] -= 0.9  # the arm tips forward past its highest point
    swing = np.zeros(panda.nq)
    swing[1] = 0.6
    ts = np.linspace(0.0, 1.0, 6001)
    top = np.array([far - probe.clearance(a0 + t * swing) for t in ts])  # highest robot point [m]
    t_star = ts[int(np.argmax(top))]
    assert 0.05 < t_star < 0.95, "the swing's highest point must be inside it"
    q_star = a0 + t_star * swing
    a = q_star.copy()
    a[1] -= 0.045
    b = a.copy()
    b[1] += 0.1  # samples at 0.01 rad: the top at 0.045, midway between two of them
    lowered = box("ceiling", (0.0, 0.0, float(top.max()) - 3e-6 + 0.5), (4.0, 4.0, 1.0))
    return Problem.create(panda, Scene((lowered,)), a, b), a, b


def test_grazing_segment_free_at_coarse_samples_but_colliding_between_is_rejected(panda):
    p, a, b = _ceiling_segment(panda)
    dense = CollisionChecker.for_problem(p)
    assert not _dense_hit(dense, a, b, 0.01), "precondition: the old sampled check accepts it"
    assert _dense_hit(dense, a, b, 0.0002), "precondition: a fine check sees the contact"
    verdict = CertifiedChecker.for_problem(p).check_segment(a, b)
    assert not verdict.free and verdict.pair[1] == "obstacle:ceiling"
    assert 0.3 < verdict.fraction < 0.6
    ev = evaluate(p, PlanResult(PlanStatus.SUCCESS, np.stack([a, b]), target="configuration"))
    assert not ev.success and not ev.checks["collision_free"]
    assert ev.collision_segment == 0 and "ceiling" in ev.collision_pair


def test_self_collision_along_a_long_jump_is_rejected(panda):
    # two free configurations far apart whose straight line passes through the arm itself
    checker = CollisionChecker(panda, Scene())
    rng = np.random.default_rng(7)
    for _ in range(500):
        a, b = rng.uniform(panda.lower, panda.upper), rng.uniform(panda.lower, panda.upper)
        if not checker.in_collision(a) and not checker.in_collision(b) and _dense_hit(checker, a, b, 0.05):
            break
    else:
        pytest.fail("no self-colliding jump between free configurations found")
    p = Problem.create(panda, Scene(), a, b)
    verdict = CertifiedChecker.for_problem(p).check_segment(a, b)
    assert not verdict.free and verdict.depth > 0  # the deepest point the search met
    assert not verdict.pair[1].startswith("obstacle:")


def test_free_path_is_certified_with_its_clearance_bracketed(panda):
    p = planbench.load_problems("mbm:box/0001")[0]
    checker = CertifiedChecker.for_problem(p)
    q = p.start
    # a short motion of the wrist, well away from the box
    b = q.copy()
    b[6] += 0.3
    verdict = checker.check_segment(q, b)
    assert verdict.free
    ts = np.linspace(0, 1, 61)
    sampled = min(checker.clearance(q + t * (b - q)) for t in ts)
    assert verdict.clearance_lower <= verdict.clearance_found + 1e-12
    assert verdict.clearance_lower <= sampled + 1e-9  # a true lower bound
    assert verdict.clearance_found - verdict.clearance_lower <= 1e-3 + 1e-9
    assert sampled <= verdict.clearance_found + 1e-3


def test_verdicts_do_not_depend_on_earlier_queries():
    p = planbench.load_problems("mbm:bookshelf_small/0001")[0]
    rng = np.random.default_rng(3)
    path = p.start + np.cumsum(rng.normal(scale=0.05, size=(8, p.robot.nq)), axis=0)
    fresh = CertifiedChecker(p.robot, p.scene).check_path(path)
    used = CertifiedChecker(p.robot, p.scene)
    for _ in range(5):
        used.check_path(np.clip(p.start + rng.normal(scale=0.8, size=(4, p.robot.nq)), p.robot.lower, p.robot.upper))
    again = used.check_path(path)
    assert (fresh.free, fresh.segment, fresh.fraction, fresh.clearance_found) == (
        again.free,
        again.segment,
        again.fraction,
        again.clearance_found,
    )


def test_every_distance_is_bit_identical_whatever_was_queried_before():
    # pinocchio's requests came with coal's cached GJK guess on: a hull distance moved by 1.4 um
    # and an exact one by 0.1 um with the queries made before, so a row's clearance depended on
    # the runs its validator had checked earlier
    p = planbench.load_problems("mbm:bookshelf_small/0003")[0]
    rng = np.random.default_rng(0)
    path = np.linspace(p.start, p.goal.q, 30)
    fresh, used = CertifiedChecker(p.robot, p.scene), CertifiedChecker(p.robot, p.scene)
    for _ in range(50):
        q = np.clip(p.start + rng.normal(0, 0.5, p.robot.nq), p.robot.lower, p.robot.upper)
        used.clearance(q)
        s = used._new_sample(-1.0, q)
        for k in range(used.n_pairs):
            used._query("exact", s, k)

    def distances(checker: CertifiedChecker, q: np.ndarray) -> list[float]:
        s = checker._new_sample(-1.0, np.ascontiguousarray(q))
        checker._all_bounds(s)
        return [s.bound[k] for k in range(checker.n_pairs)] + [
            checker._query("exact", s, k) for k in range(checker.n_pairs)
        ]

    for q in path:
        assert distances(fresh, q) == distances(used, q)
        assert fresh.clearance(q) == used.clearance(q)


def test_required_clearance_rejects_a_path_that_only_touches_less_than_asked(panda):
    p = planbench.load_problems("mbm:box/0001")[0]
    q = p.start
    b = q.copy()
    b[6] += 0.3
    free = CertifiedChecker(p.robot, p.scene).check_segment(q, b)
    assert free.free
    strict = CertifiedChecker(p.robot, p.scene, CertificationSettings(required_clearance=free.clearance_found + 0.01))
    assert not strict.check_segment(q, b).free


def test_query_budget_refuses_instead_of_guessing():
    p = planbench.load_problems("mbm:box/0001")[0]
    b = p.start.copy()
    b[0] += 1.0
    verdict = CertifiedChecker(p.robot, p.scene, CertificationSettings(max_queries=10)).check_segment(p.start, b)
    assert not verdict.free and "distance queries" in verdict.reason


def test_motion_bound_covers_the_real_motion_of_every_pair(panda):
    """W @ |dq| must bound how far any pair's distance moves: compare with finite differences."""
    p = planbench.load_problems("mbm:cage/0001")[0]
    checker = CertifiedChecker(p.robot, p.scene)
    rng = np.random.default_rng(0)
    for _ in range(5):
        a = rng.uniform(panda.lower, panda.upper)
        b = np.clip(a + rng.normal(scale=0.02, size=panda.nq), panda.lower, panda.upper)
        bound = checker.motion_weights @ np.abs(b - a)
        sa, sb = checker._new_sample(0.0, a), checker._new_sample(1.0, b)
        for k in range(checker.n_pairs):
            da, db = checker._exact(sa, k), checker._exact(sb, k)
            if da > 0 and db > 0:
                assert abs(db - da) <= bound[k] + 2e-6, checker._pair_names[k]


_MBM_BOX = None


def _box_problem():
    global _MBM_BOX
    if _MBM_BOX is None:
        _MBM_BOX = planbench.load_problems("mbm:bookshelf_small/0001")[0]
    return _MBM_BOX


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start=st.lists(st.floats(-0.25, 0.25), min_size=7, max_size=7),
    step=st.lists(st.floats(-0.06, 0.06), min_size=7, max_size=7),
)
def test_never_accepts_a_segment_that_a_dense_check_finds_colliding(start, step):
    p = _box_problem()
    dense = CollisionChecker.for_problem(p)
    # near the goal: the hand is among the shelf's objects there
    a = np.clip(p.goal.q + np.array(start), p.robot.lower, p.robot.upper)
    b = np.clip(a + np.array(step), p.robot.lower, p.robot.upper)
    verdict = CertifiedChecker.for_problem(p).check_segment(a, b)
    if verdict.free:
        assert not _dense_hit(dense, a, b, 1e-4)


def test_evaluate_reports_clearance_at_a_single_configuration_exactly():
    p = planbench.load_problems("mbm:box/0001")[0]
    ev = evaluate(p, PlanResult(PlanStatus.SUCCESS, p.start[None, :]))
    assert ev.min_clearance == pytest.approx(CollisionChecker.for_problem(p).clearance(p.start), abs=1e-6)
    assert ev.min_clearance_bound <= ev.min_clearance
    assert math.isfinite(ev.mean_clearance)


def test_a_waypoint_within_the_distance_accuracy_is_refused_also_at_the_end_of_a_segment():
    """Coal's distances are accurate to about 1 um, so two ends of one interval can disagree by that
    much: a waypoint closer than the accuracy must be refused on its own, not certified from the
    other end (a planner checking segment by segment would otherwise accept what the harness,
    checking the whole path, refuses)."""

    class EndTouching(CertifiedChecker):  # the path's last configuration reads 0.5 um from everything
        def _all_bounds(self, s):
            super()._all_bounds(s)
            if s.u == len(self._path) - 1:
                for k in range(self.n_pairs):
                    s.bound[k] = min(s.bound[k], 5e-7)
                    s.exact[k] = min(s.exact.get(k, s.bound[k]), 5e-7)

    p = planbench.load_problems("mbm:box/0001")[0]
    b = p.start.copy()
    b[6] += 1e-4  # a tiny motion: the far end alone would certify the segment
    verdict = EndTouching(p.robot, p.scene).check_segment(p.start, b)
    assert not verdict.free and verdict.segment == 0 and verdict.fraction == 1.0
    assert CertifiedChecker(p.robot, p.scene).check_segment(p.start, b).free  # the real distances
