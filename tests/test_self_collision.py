"""The loop's self-collision push (plugins/ik_loop/self_collision.py)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import planbench
from planbench_plugins.ik_loop import DistanceModel, ZeroRepulsion, fast, tasks
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
    cull = push.candidates
    push.candidates = lambda *a: asked.append(1) or cull(*a)
    push._quiet = push.every - 1  # as a query that ended between two asks leaves it
    planner.plan(problem, time_limit=1.0, rng=np.random.default_rng(0))
    assert asked  # its first step asked


def reference_forces(push, kin):
    """The push as first written (before the compiled culling): every pair culled and measured
    by ``DistanceModel.near``, the pushes appended by concatenation."""
    points, F, support, joint = push.inner.forces(kin)
    pairs = push.distances.near(kin.model, kin.data)
    u = np.clip((push.influence - pairs.distance) / push.influence, 0.0, None)
    f = (push.push_gain * push.speed_max * u * u)[:, None] * pairs.normal
    m = len(pairs)
    return (
        np.concatenate((points, pairs.point, pairs.other_point)),
        np.concatenate((F, -f, f)),
        np.concatenate((support, pairs.support, pairs.other_support)),
        np.concatenate((joint, np.full(2 * m, -1, dtype=joint.dtype))),
    )


@pytest.mark.parametrize(
    "compiled", [False, pytest.param(True, marks=pytest.mark.skipif(not fast.have_numba(), reason="numba"))]
)
def test_the_culled_push_equals_the_reference_on_random_configurations(near_itself, compiled):
    problem, q_near = near_itself
    planner = MatrixFieldPlanner()
    planner.setup(problem)
    kin = planner.stepper.kin
    push = SelfCollisionPush(
        ZeroRepulsion(), problem.robot, problem.scene, influence=0.05, gain=3.0, speed_max=0.25, compiled=compiled
    )
    robot = problem.robot
    rng = np.random.default_rng(7)
    near = 0
    for q in [q_near] + [rng.uniform(robot.lower, robot.upper) for _ in range(150)]:
        kin.update(q)
        push.restart()
        got = push.forces(kin)
        want = reference_forces(push, kin)
        near += push.pairs_near > 0
        for a, b in zip(got, want, strict=True):
            assert a.shape == b.shape
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert near >= 10  # the comparison covered configurations with pushes, not only empty ones


def test_the_spheres_bound_every_pair_coal_reports(near_itself):
    """Culling loses nothing: every pair that coal puts within the influence distance is among
    the candidates the spheres leave."""
    problem, _ = near_itself
    robot = problem.robot
    model = DistanceModel(robot, problem.scene, 0.05, self_pairs=True, obstacle_pairs=False)
    everything = DistanceModel(robot, problem.scene, 0.05, self_pairs=True, obstacle_pairs=False)
    everything.influence = np.inf  # culls nothing: coal measures every pair
    rng = np.random.default_rng(3)
    data = robot.model.createData()
    for _ in range(100):
        q = rng.uniform(robot.lower, robot.upper)
        pin.forwardKinematics(robot.model, data, q)
        candidates = model.self_candidates(
            np.array([M.rotation for M in data.oMi]), np.array([M.translation for M in data.oMi])
        )
        pairs = everything.near(robot.model, data)
        close = pairs.pair[pairs.distance < 0.05]
        assert set(close.tolist()) <= set(candidates.tolist())
