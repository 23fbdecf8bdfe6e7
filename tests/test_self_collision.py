"""The loop's self-collision push (plugins/ik_loop/self_collision.py)."""

from __future__ import annotations

import numpy as np
import pytest

import planbench
from planbench_plugins.ik_loop import DistanceModel, ZeroRepulsion, tasks
from planbench_plugins.ik_loop.self_collision import SelfCollisionPush
from planbench_plugins.matrix_field import MatrixFieldPlanner


@pytest.fixture(scope="module")
def near_itself():
    """A Panda problem and a configuration whose closest own pair is 5-30 mm apart."""
    problem = planbench.load_problems("mbm:box/0001")[0]
    robot = problem.robot
    model = DistanceModel(robot, problem.scene, 0.05, self_pairs=True, obstacle_pairs=False)
    rng = np.random.default_rng(1)
    for _ in range(5000):
        q = rng.uniform(robot.lower, robot.upper)
        pairs = model.near_at(q)
        if len(pairs) and 0.005 < pairs.distance.min() < 0.03:
            return problem, q
    raise AssertionError("no configuration near self-collision found")


def test_the_push_separates_the_closest_pair(near_itself):
    problem, q = near_itself
    planner = MatrixFieldPlanner()
    planner.setup(problem)
    kin = planner.stepper.kin
    push = SelfCollisionPush(ZeroRepulsion(), problem.robot, problem.scene, influence=0.05, gain=3.0, speed_max=0.25)
    kin.update(q)
    points, F, support, joint = push.forces(kin)
    assert push.pairs_near >= 1 and len(points) == 2 * push.pairs_near + len(kin.points)
    extra = F[len(kin.points) :]
    m = push.pairs_near
    assert np.allclose(extra[:m], -extra[m:])  # equal and opposite on the two bodies
    assert np.all(joint[len(kin.points) :] == -1)  # never the tool's
    assert np.max(np.linalg.norm(extra, axis=1)) <= 3.0 * 0.25 + 1e-12
    # a small step along the push's joint velocity moves the closest pair apart
    qd = tasks.repulsion_joint_velocity(kin.S, points, F, support)
    model = push.distances
    before = model.near_at(q).distance.min()
    after = model.near_at(q + 1e-3 * qd / np.linalg.norm(qd)).distance.min()
    assert after > before


def test_the_setting_adds_the_push_and_the_paper_preset_leaves_it_out(near_itself):
    problem, _ = near_itself
    on = MatrixFieldPlanner()
    on.setup(problem)
    assert isinstance(on.stepper.repulsion, SelfCollisionPush)
    off = planbench.make_planner("matrix-field", self_collision=False)
    off.setup(problem)
    assert not isinstance(off.stepper.repulsion, SelfCollisionPush)
    paper = planbench.make_planner("matrix-field:paper")
    paper.setup(problem)
    assert not isinstance(paper.stepper.repulsion, SelfCollisionPush)
    qp = planbench.make_planner("matrix-field-qp")  # its collision constraints hold the self pairs
    qp.setup(problem)
    assert not isinstance(qp.stepper.repulsion, SelfCollisionPush)


def test_a_query_asks_the_distances_afresh_however_the_last_one_ended(near_itself):
    """While no pair is near, the distances are asked every few steps; a new query must not
    inherit the last one's count, or one planner gives two paths for the same seed."""
    problem, _ = near_itself
    planner = MatrixFieldPlanner(max_steps=1)
    planner.setup(problem)  # then plan() twice on it, as a caller that reuses a prepared planner does
    planner.plan(problem, time_limit=1.0, rng=np.random.default_rng(0))
    push = planner.stepper.repulsion
    assert isinstance(push, SelfCollisionPush)
    asked = []
    near = push.distances.near
    push.distances.near = lambda *a: asked.append(1) or near(*a)
    push._quiet = push.every - 1  # as a query that ended between two asks leaves it
    planner.plan(problem, time_limit=1.0, rng=np.random.default_rng(0))
    assert asked  # its first step asked
