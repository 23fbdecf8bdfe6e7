"""The broadphase behind CollisionChecker.in_collision gives the same answers as checking every pair.

Configurations are taken on the collision boundary (bisection between a free and a colliding
configuration), where a wrong filter would show first. Each is checked with a fresh checker: coal's
GJK warm start makes answers within about a micrometre of contact depend on earlier queries, with or
without broadphase, so both methods must start from the same (empty) history.
"""

import numpy as np
import pytest

from planbench.collision import CollisionChecker
from planbench.datasets import load_problems


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
