"""The potential-field baselines (``distance-field``, ``edt-field``): Khatib profile and gain,
direction and reach of both repulsions at a wall, a wall avoided, conformance."""

from __future__ import annotations

import numpy as np
import pytest

import planbench
from planbench import Obstacle, PlanStatus, Problem, Scene
from planbench.conformance import check_planner
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.robot import load_robot
from planbench_plugins.ik_loop import ArmKinematics
from planbench_plugins.potential_fields import (
    DistanceFieldConfig,
    DistanceFieldPlanner,
    DistanceFieldRepulsion,
    EDTFieldConfig,
    EDTFieldPlanner,
    EDTFieldRepulsion,
    khatib_gain,
    khatib_magnitude,
)

D0, STANDOFF, SPEED = 0.15, 0.10, 0.5


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


def wall_problem(robot, top: float = 0.5) -> Problem:
    """As in test_matrix_field_planner: the hand swings from joint 1 = +0.7 to -0.7 rad at the
    ready pose; a 2 cm wall in front of the robot rises to ``top`` [m], above the hand's straight way."""
    start, goal = np.array(robot.home), np.array(robot.home)
    start[0], goal[0] = 0.7, -0.7
    h = top - 0.2
    wall = Obstacle("wall", "box", position=(0.4, 0.0, 0.2 + h / 2), size=(0.3, 0.02, h))
    return Problem.create(robot, Scene((wall,), name="wall"), start, goal, id="test:wall")


def test_khatib_gain_gives_speed_max_at_the_standoff():
    k = khatib_gain(SPEED, STANDOFF, D0)
    d = np.array([-0.05, 0.0, 0.005, STANDOFF, 0.149, D0, 0.3])
    f = khatib_magnitude(d, k, D0, floor=0.01)
    assert f[3] == pytest.approx(SPEED)
    assert np.all(np.isfinite(f)) and f[0] == f[1] == f[2] == f.max()  # floored: finite at contact
    assert np.all(np.diff(f[2:]) <= 0) and f[4] > 0 and f[5] == f[6] == 0.0


def test_settings_are_validated():
    with pytest.raises(InvalidConfigError, match="influence_distance"):
        DistanceFieldConfig(standoff=0.2)
    with pytest.raises(InvalidConfigError, match="distance_floor"):
        EDTFieldConfig(distance_floor=0.1)
    with pytest.raises(InvalidConfigError, match="grid_resolution"):
        EDTFieldConfig(grid_resolution=0.0)


def test_edt_repulsion_points_away_from_a_wall_and_vanishes_beyond_d0():
    r = 0.02
    data = np.zeros((40, 40, 40))
    data[20:22] = 1.0  # a wall 2 cells thick, faces at x = 0.40 and 0.44 m, grid-aligned
    rep = EDTFieldRepulsion(OccupancyGrid(data, np.zeros(3), r), khatib_gain(SPEED, STANDOFF, D0), D0, 0.01)
    yz = (20.5 * r, 20.5 * r)
    front = np.array([[0.40 - d, *yz] for d in (0.03, STANDOFF, 0.14, D0 + 0.01, 0.25)])
    F = rep.at(front)
    assert np.all(F[:3, 0] < 0) and np.allclose(F[:3, 1:], 0.0, atol=1e-9)  # pushed in -x, away
    assert np.linalg.norm(F[1]) == pytest.approx(SPEED, rel=1e-6)  # the half-cell offset is exact here
    assert np.all(F[3:] == 0.0)  # beyond the influence distance
    behind = rep.at(np.array([[0.44 + STANDOFF, *yz]]))
    assert behind[0, 0] == pytest.approx(SPEED, rel=1e-6)
    inside = rep.at(np.array([[0.405, *yz], [0.435, *yz]]))  # in the wall: out through the nearer face
    assert inside[0, 0] < 0 < inside[1, 0] and np.all(np.isfinite(inside))


@pytest.mark.parametrize("fill", [0.0, 1.0])
def test_edt_repulsion_of_a_grid_without_free_or_occupied_cells_is_zero(fill):
    data = np.full((6, 6, 6), fill)  # e.g. the reach cube of a scene whose obstacles lie outside it
    rep = EDTFieldRepulsion(OccupancyGrid(data, np.zeros(3), 0.02), khatib_gain(SPEED, STANDOFF, D0), D0, 0.01)
    F = rep.at(np.array([[0.05, 0.05, 0.05], [0.5, 0.5, 0.5]]))
    assert np.all(F == 0.0)  # not NaN: inf - inf in the gradient of a constant distance


def _distance_repulsion(robot, q, wall_x: float, d0: float = D0):
    """A wide wall facing -x with its front face at ``wall_x`` [m]; the repulsion at ``q``."""
    wall = Obstacle("wall", "box", position=(wall_x + 0.01, 0.0, 0.5), size=(0.02, 2.0, 1.0))
    rep = DistanceFieldRepulsion(robot, Scene((wall,), name="wall"), khatib_gain(SPEED, STANDOFF, d0), d0, 0.01)
    kin = ArmKinematics(robot, robot.ee_frame_id, _no_points())
    kin.update(q)
    points, F, support, joint = rep.forces(kin)
    return rep, points.copy(), F.copy(), support, joint


def _no_points():
    from planbench_plugins.ik_loop.control_points import ControlPoints

    return ControlPoints(np.zeros(0, dtype=int), np.zeros((0, 3)), np.zeros(0), ())


def test_distance_repulsion_points_away_from_a_wall_and_vanishes_beyond_d0(robot):
    import coal
    import pinocchio as pin

    q = np.array(robot.home)
    probe = _distance_repulsion(robot, q, 1.0, d0=2.0)[0]
    x_front = 1.0 - float(probe.distance.min())  # the arm's hulls reach this far along x
    rep, points, F, support, joint = _distance_repulsion(robot, q, x_front + 0.08)
    near = np.isfinite(rep.distance) & (rep.distance < D0)
    assert near.any() and support.shape == (len(rep.link_names), robot.nq)
    assert np.all(F[near, 0] < 0) and np.allclose(F[near, 1:], 0.0, atol=1e-9)  # -x: away from the wall
    assert np.allclose(np.linalg.norm(F, axis=1), khatib_magnitude(rep.distance, rep.gain, D0, 0.01))
    assert np.all(F[~near] == 0.0)
    # the hull distance never exceeds the mesh's (coal on the robot's own geometry)
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q)
    wall_geom, wall_pose = coal.Box(0.02, 2.0, 1.0), coal.Transform3s(np.eye(3), np.array([x_front + 0.09, 0, 0.5]))
    for g in robot.collision_model.geometryObjects:
        if g.parentJoint == 0:
            continue
        M = data.oMi[g.parentJoint] * g.placement
        d = coal.distance(
            g.geometry,
            coal.Transform3s(M.rotation, M.translation),
            wall_geom,
            wall_pose,
            coal.DistanceRequest(),
            coal.DistanceResult(),
        )
        link = rep.link_names.index(g.name.rpartition("_")[0])
        assert rep.distance[link] <= d + 1e-6 or (d >= D0 and rep.distance[link] == np.inf)
    # the nearest link exactly at the stand-off is pushed at speed_max (the gain's derivation)
    i = int(np.argmin(rep.distance))
    rep2, _, F2, _, _ = _distance_repulsion(robot, q, x_front + 0.08 + STANDOFF - rep.distance[i])
    assert rep2.distance[i] == pytest.approx(STANDOFF, abs=1e-6)
    assert np.linalg.norm(F2[i]) == pytest.approx(SPEED, rel=1e-4)
    # farther than the influence distance: nothing
    rep3, _, F3, _, _ = _distance_repulsion(robot, q, x_front + D0 + 0.01)
    assert np.all(F3 == 0.0) and np.all(rep3.distance >= D0)


@pytest.mark.parametrize("planner", [DistanceFieldPlanner, EDTFieldPlanner])
def test_wall_is_avoided(robot, planner):
    problem = wall_problem(robot)
    blind = planbench.plan(problem, planner, repulsion_gain=0.0, collision_check_every=0, escape_attempts=0)
    assert not planbench.evaluate(problem, blind).success
    result = planbench.plan(problem, planner, tool_repulsion_gain=1.0)
    ev = planbench.evaluate(problem, result)
    assert result.status is PlanStatus.SUCCESS and ev.success, ev.failure
    assert ev.min_clearance > 0.02
    assert np.nanmax(result.info["repulsion"]) > 0


@pytest.mark.parametrize("planner", [DistanceFieldPlanner, EDTFieldPlanner])
def test_conformance(planner):
    assert check_planner(planner) == []
