"""``field_push="khatib"``: the matrix field's push with Khatib's magnitude at the wall distance
(:mod:`planbench_plugins.matrix_field.wall_push`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import planbench
from planbench import Obstacle, Problem, Scene
from planbench.errors import InvalidConfigError
from planbench.field.lazy import lazy_field
from planbench.field.scene_field import standoff_gain
from planbench.geometry.occupancy import OccupancyGrid
from planbench.robot import load_robot
from planbench_plugins.ik_loop import khatib_gain, khatib_magnitude
from planbench_plugins.matrix_field import MatrixFieldPlanner
from planbench_plugins.matrix_field.config import MatrixFieldConfig
from planbench_plugins.matrix_field.wall_push import WallKhatibRepulsion, wall_khatib

R = 0.02


class Plain:
    """The linear push of a grid (``k_rep F``), the inner repulsion's ``gain`` and ``field_at``."""

    def __init__(self, grid: OccupancyGrid, config: MatrixFieldConfig) -> None:
        self.grid, self.kernels = grid, config.kernels()
        self.gain = standoff_gain(self.kernels, config.speed_max, config.standoff)

    def field_at(self, points: np.ndarray) -> np.ndarray:
        return lazy_field(self.grid, self.kernels, points)


def wall_grid(n: int = 41) -> OccupancyGrid:
    """A one-cell-thick wall filling the plane x = 0 (its faces at x = -+R/2)."""
    data = np.zeros((n, n, n))
    data[n // 2] = 1.0
    return OccupancyGrid(data, np.full(3, -(n // 2) * R - R / 2), R)


def test_at_a_flat_wall_the_push_is_khatibs_at_the_distance_along_the_field():
    config = MatrixFieldConfig(field_push="khatib")
    plain: Any = Plain(wall_grid(), config)
    rep = wall_khatib(plain, config)
    k = khatib_gain(config.speed_max, config.standoff, config.kernel_reach)
    previous = np.inf
    for d in (0.02, 0.04, 0.06, 0.08, 0.10, 0.12):
        point = np.array([[-(R / 2 + d), 0.0, 0.0]])
        F = plain.gain * plain.field_at(point)
        push = rep.map(F, np.empty_like(F))[0]
        want = khatib_magnitude(np.array([d]), k, config.kernel_reach, config.distance_floor)[0]
        assert np.linalg.norm(push) == pytest.approx(want, rel=1e-6)  # edt-field's push at a flat wall
        assert push[0] < 0 and np.allclose(push[1:], 0.0)  # the field's own direction
        assert np.linalg.norm(push) < previous
        previous = np.linalg.norm(push)
    at_standoff = np.array([[-(R / 2 + config.standoff), 0.0, 0.0]])
    F = plain.gain * plain.field_at(at_standoff)
    assert np.linalg.norm(rep.map(F, np.empty_like(F))) == pytest.approx(config.speed_max)


def test_the_push_grows_to_the_floor_and_vanishes_with_the_field():
    config = MatrixFieldConfig(field_push="khatib")
    plain: Any = Plain(wall_grid(), config)
    rep = WallKhatibRepulsion(plain, config.kernels(), config.speed_max, config.standoff, 0.15, 0.01)
    u = np.array([0.0, 0.05, 0.25, 0.5, rep.top_push, 2 * rep.top_push])
    d = rep.wall_distance(u)
    assert d[0] >= 0.15 and d[2] == pytest.approx(config.standoff) and d[-1] == 0.01
    assert np.all(np.diff(d) <= 0)
    F = np.zeros((len(u), 3))
    F[:, 2] = u
    out = rep.map(F, np.empty_like(F))
    assert out[0, 2] == 0.0 and np.all(np.diff(out[:, 2]) >= 0)
    top = khatib_magnitude(np.array([0.01]), khatib_gain(0.25, 0.10, 0.15), 0.15, 0.01)[0]
    assert out[-1, 2] == pytest.approx(top)  # the floor's push, ~2800x speed_max


def test_bad_settings_are_refused():
    with pytest.raises(InvalidConfigError, match="field_push"):
        MatrixFieldConfig(field_push="cubic").validate()
    with pytest.raises(InvalidConfigError, match="distance_floor"):
        MatrixFieldConfig(field_push="khatib", distance_floor=0.2).validate()
    MatrixFieldConfig(field_push="khatib").validate()


def test_the_planner_pushes_with_the_mapped_field_in_full_and_lazy_mode():
    robot = load_robot("panda")
    start = np.array(robot.home)
    goal = start.copy()
    goal[0] = 0.3
    wall = Obstacle("wall", "box", position=(0.5, 0.0, 0.4), size=(0.2, 0.6, 0.8))  # face at x = 0.4
    problem = Problem.create(robot, Scene((wall,), name="wall"), start, goal, id="test:khatib-wall")
    forces = []
    for mode in ("full", "lazy"):
        planner = MatrixFieldPlanner(field_push="khatib", field_mode=mode)
        planner.setup(problem)
        rep = getattr(planner.stepper.repulsion, "inner", planner.stepper.repulsion)
        assert isinstance(rep, WallKhatibRepulsion)
        q = np.array(robot.home)
        points, F = planner.repulsion_at(q)
        forces.append(F)
        linear = MatrixFieldPlanner(field_mode=mode)
        linear.setup(problem)
        _, F_lin = linear.repulsion_at(q)
        assert np.allclose(planner.field_at(points), linear.field_at(points))  # the field itself unchanged
        near = np.linalg.norm(F_lin, axis=1) > 0
        cos = np.einsum("ij,ij->i", F[near], F_lin[near])
        assert np.all(cos >= 0) and np.any(cos > 0)  # the same directions (weak fields map to no push)
    assert np.allclose(forces[0], forces[1], rtol=1e-6, atol=1e-9)
    result = planbench.plan(problem, MatrixFieldPlanner, field_push="khatib", time_limit=10.0)
    assert planbench.evaluate(problem, result).success


def test_hand_only_maps_the_last_joints_points_and_contact_keeps_the_larger_push():
    """``"khatib-hand"``: the points of the arm's last joint mapped, the others left linear;
    ``"contact"``: the larger of the linear and the mapped magnitude, in the field's direction."""
    config = MatrixFieldConfig(field_push="khatib")
    plain: Any = Plain(wall_grid(), config)
    args = (config.kernels(), config.speed_max, config.standoff, config.kernel_reach, config.distance_floor)
    full = WallKhatibRepulsion(plain, *args)
    hand = WallKhatibRepulsion(plain, *args, hand_only=True)
    contact = WallKhatibRepulsion(plain, *args, at_least_linear=True)
    F = np.array([[0.0, 0.0, u] for u in (0.1, 0.25, 0.45, 0.12, 0.5)])

    class Kin:
        points = np.zeros((5, 3))
        support = np.ones((5, 7))
        cp_joint = np.array([5, 6, 7, 7, 7])

    class Source:
        gain = plain.gain

        def forces(self, kin: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
            return kin.points, F, kin.support, kin.cp_joint

    hand.inner = Source()
    _, out, _, _ = hand.forces(Kin())
    mapped = full.map(F, np.empty_like(F))
    assert np.allclose(out[:2], F[:2]) and np.allclose(out[2:], mapped[2:])
    both = contact.map(F, np.empty_like(F))
    assert np.allclose(both[:, 2], np.maximum(F[:, 2], mapped[:, 2]))
    assert both[0, 2] == pytest.approx(0.1) and both[2, 2] > 1.0  # linear far out, Khatib's close in


def test_the_controller_refuses_the_planners_push_setting():
    from planbench_plugins.controllers import MatrixFieldController

    with pytest.raises(InvalidConfigError, match="field_push"):
        MatrixFieldController(field_push="khatib")
    assert MatrixFieldController().config.field_push == "linear"
