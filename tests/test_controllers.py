"""The closed-loop controllers: the registry of controllers, the conformance checker, and the four
field planners' steps run as controllers (planbench_plugins.controllers)."""

from __future__ import annotations

import dataclasses
import re
import sys
import textwrap
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from planbench.conformance import ConformanceReport
from planbench.errors import InvalidSettingError, PlannerUnavailableError, UnknownNameError
from planbench.field.full import full_field
from planbench.field.scene_field import FieldRepulsion
from planbench.field.surface import surface_grid
from planbench.geometry.occupancy import OccupancyGrid
from planbench.planner import PlanStatus
from planbench.problem import Goal, Pose, pose_error
from planbench.reactive import Controller, Observation
from planbench.reactive.conformance import CHECKS, check_controller, conformance_task, controller_report
from planbench.registry import CONTROLLERS, REGISTRY, Registry, make_controller, make_planner, register_controller
from planbench.scene import Scene
from planbench_plugins.controllers import IKLoopController
from planbench_plugins.ik_loop import ArmKinematics, DistanceModel, IKLoopPlanner, StepFailure, ZeroRepulsion

FIELD_CONTROLLERS = ["matrix-field", "matrix-field-qp", "edt-field", "distance-field"]
GUIDE = Path(__file__).resolve().parents[1] / "docs" / "writing-a-controller.md"


@pytest.fixture(scope="module")
def box():
    """MotionBenchMaker box/0001 as a control task, with its scene's grid and an empty one."""
    return conformance_task()


def drive(controller, task, observation, ticks):
    """Integrate the controller's velocities as the runner does (clipped to the limits); the
    configurations (ticks + 1, nq), stopping at the goal."""
    robot = task.robot
    vmax = np.asarray(robot.velocity_limit)
    q = np.array(task.start, dtype=float)
    controller.setup(task)
    controller.reset(q.copy(), np.random.default_rng(0))
    controller.update(observation)
    path = [q]
    for k in range(ticks):
        qd = controller.step(k * task.period, q.copy(), observation, task.goal)
        q = np.clip(q + task.period * np.clip(qd, -vmax, vmax), robot.lower, robot.upper)
        path.append(q)
        err_p, err_r = pose_error(robot, q, task.goal.pose)
        if err_p <= task.tolerances.position and err_r <= task.tolerances.orientation:
            break
    return np.array(path)


# --- the registry of controllers -------------------------------------------------------------------


def test_the_registry_lists_the_controllers_and_names_their_kind():
    assert set(FIELD_CONTROLLERS) <= set(CONTROLLERS.names())
    assert CONTROLLERS.kind == "controller" and CONTROLLERS.group == "planbench.controllers"
    with pytest.raises(UnknownNameError, match=r"unknown controller 'matrix-feild'.*Did you mean 'matrix-field'"):
        CONTROLLERS.get("matrix-feild")
    speed = r"^controller 'matrix-field': setting speed .*did you mean 'speed_max'"
    with pytest.raises(InvalidSettingError, match=speed):
        make_controller("matrix-field", speed=0.3)
    with pytest.raises(InvalidSettingError, match=r"^controller 'edt-field': setting standoff"):
        make_controller("edt-field", standoff=0.5)  # beyond the influence distance


def test_the_planner_registry_is_unchanged_beside_it():
    assert REGISTRY.kind == "planner" and "straight-line" in REGISTRY.names()
    assert "straight-line" not in CONTROLLERS.names()
    assert make_planner("matrix-field").config.field_mode == "full"  # the planner's default stays
    with pytest.raises(UnknownNameError, match="unknown planner"):
        REGISTRY.get("matrix-feild")
    with pytest.raises(InvalidSettingError, match=r"^planner 'matrix-field'"):
        make_planner("matrix-field", speed=0.3)


def test_controllers_take_their_planners_settings_presets_and_a_lazy_field():
    controller = make_controller("matrix-field", standoff=0.08, hierarchy="nullspace")
    assert (controller.config.standoff, controller.config.hierarchy) == (0.08, "nullspace")
    assert controller.config.field_mode == "lazy"
    assert make_controller("matrix-field-qp").config.field_mode == "lazy"
    paper = make_controller("matrix-field:paper")
    assert paper.config.hierarchy == "nullspace" and paper.config.self_collision is False


def test_the_matrix_field_controller_keeps_its_rows_on_a_redundant_arm(box):
    """The planner took the null space on a redundant arm (issue 32, measured on planning sets);
    the controller of the same name keeps the priority rows for the matrix field."""
    assert make_planner("matrix-field").hierarchy_for(7) == "nullspace"
    for name, hierarchy in (("matrix-field", "priority"), ("matrix-field:calibrated", "nullspace")):
        controller = make_controller(name)
        controller.setup(box.task)
        assert controller.stepper is not None and controller.stepper.hierarchy == hierarchy, name


def test_a_controller_registers_into_an_isolated_registry():
    registry = Registry(discover=False, group="planbench.controllers", kind="controller")

    @register_controller(registry=registry)
    class Still(Controller):
        name = "still"

        def step(self, t, q, observation, goal):
            return np.zeros_like(q)

    assert registry.names() == ["still"] and registry.make("still").name == "still"
    assert "still" not in CONTROLLERS.names()
    with pytest.raises(ValueError, match="controller name 'Not_Kebab'"):
        registry.register(Still, name="Not_Kebab")
    with pytest.raises(UnknownNameError, match="unknown controller"):
        registry.get("moving")


def test_a_controller_that_cannot_be_imported_says_it_is_a_controller():
    registry = Registry(discover=False, group="planbench.controllers", kind="controller")
    registry.register("pb_not_a_module_xyz:Controller", name="missing")
    with pytest.raises(PlannerUnavailableError, match=r"^controller 'missing' is registered but cannot be loaded"):
        registry.get("missing")
    assert not registry.spec("missing").available


# --- the conformance checker -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n == "edt-field" else n for n in FIELD_CONTROLLERS],
)  # edt-field: a distance transform per frame, ~9 s for the checker's 400 frames
def test_every_field_controller_conforms(name):
    assert check_controller(name) == []


class Toward(Controller):
    """Joint-space proportional control to the goal configuration (conformant)."""

    name = "toward"

    def step(self, t, q, observation, goal):
        return 2.0 * (goal.q - q)


class RaisesInStep(Toward):
    name = "raises-in-step"

    def step(self, t, q, observation, goal):
        if t > 0.05:
            raise RuntimeError("lost track")
        return super().step(t, q, observation, goal)


class WrongShape(Toward):
    name = "wrong-shape"

    def step(self, t, q, observation, goal):
        return np.zeros(3)


class ReturnsNaN(Toward):
    name = "returns-nan"

    def step(self, t, q, observation, goal):
        return np.full_like(q, np.nan) if observation is not None else np.zeros_like(q)


class Unseeded(Toward):
    name = "unseeded"

    def step(self, t, q, observation, goal):
        return super().step(t, q, observation, goal) + np.random.default_rng().normal(size=len(q)) * 1e-3


class Stays(Toward):
    name = "stays"

    def step(self, t, q, observation, goal):
        return np.zeros_like(q)


class ForgetsNoReset(Toward):
    """Remembers the frames of an earlier run: a second run after reset differs."""

    name = "forgets-no-reset"

    def __init__(self, config=None, **settings):
        super().__init__(config, **settings)
        self.frames = 0

    def update(self, observation):
        self.frames += 1

    def step(self, t, q, observation, goal):
        return super().step(t, q, observation, goal) * (1.0 + 0.01 * self.frames)


def test_a_conformant_toy_passes(box):
    assert box.task.goal.q is not None
    assert check_controller(Toward) == []


@pytest.mark.parametrize(
    ("cls", "check", "words"),
    [
        (RaisesInStep, "raises", "step at tick 6 (t = 0.06 s) raised RuntimeError: lost track"),
        (WrongShape, "wrong-shape", "returned shape (3,), expected (7,)"),
        (ReturnsNaN, "nan", "step at tick 1 returned NaN"),
        (Unseeded, "non-deterministic", "after reset with the same seed"),
        (ForgetsNoReset, "non-deterministic", "after reset with the same seed"),
        (Stays, "ignores-goal", "at least 25% of it must go"),
    ],
)
def test_the_checker_names_what_a_bad_controller_does(cls, check, words):
    found = check_controller(cls)
    assert [f.check for f in found] == [check], found
    assert words in found[0].message
    assert check in CHECKS and str(found[0]).startswith(f"{check}: ")


def test_the_checker_names_a_bad_interface_and_bad_info():
    class Bad(Toward):
        name = "Bad_Name"

    class BadInfo(Toward):
        name = "bad-info"

        def info(self):
            return {"when": object()}

    assert [f.check for f in check_controller(Bad)] == ["interface"]
    found = check_controller(BadInfo)
    assert [f.check for f in found] == ["info"] and "JSON-friendly" in found[0].message


def test_the_report_has_the_planners_shape_and_says_which_checks_did_not_run():
    good = controller_report(Toward)
    assert isinstance(good, ConformanceReport) and good.conformant
    assert good.checks == tuple(CHECKS) and good.lines() == [f"passed: {', '.join(CHECKS)}"]
    stays = controller_report(Stays)  # every run ends; only the goal check fails
    assert stays.with_status("failed") == ["ignores-goal"] and stays.with_status("not run") == []
    raises = controller_report(RaisesInStep)  # the first run stops at tick 6: nothing after it runs
    assert raises.with_status("failed") == ["raises"]
    assert raises.with_status("passed") == ["interface", "settings"]
    assert raises.lines()[:2] == ["failed: raises", "  - raises: " + raises.findings[0].message]
    unseeded = controller_report(Unseeded)  # the free-space run still happens after non-determinism
    assert unseeded.with_status("failed") == ["non-deterministic"] and unseeded.with_status("not run") == []


# --- the field controllers ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", FIELD_CONTROLLERS)
def test_in_free_space_the_controller_reaches_the_goal(box, name):
    path = drive(make_controller(name), box.task, box.free, ticks=800)
    err_p, err_r = pose_error(box.task.robot, path[-1], box.task.goal.pose)
    assert err_p <= box.task.tolerances.position and err_r <= box.task.tolerances.orientation
    assert len(path) < 700  # about 4.5 s at the default speed


def elbow_setting(box):
    """The Panda at its start with the goal where its hand already is (only the null space moves),
    the control point on the elbow (``panda_joint4``), and the direction [unit] in which the
    arm's self-motion moves that point."""
    robot, q = box.task.robot, np.array(box.task.start, dtype=float)
    hand = robot.frame_pose(q, box.task.goal.pose.frame)
    goal = Goal(Pose(hand.translation.copy(), hand.rotation.copy(), box.task.goal.pose.frame))
    task = dataclasses.replace(box.task, goal=goal)
    frame = robot.frame_id(goal.pose.frame)
    J = pin.computeFrameJacobian(robot.model, robot.model.createData(), q, frame, pin.LOCAL_WORLD_ALIGNED)
    null = np.linalg.svd(J)[2][-1]  # the 7-joint arm's self-motion
    return task, q, null


def point_on_elbow(controller, robot, q):
    kin = ArmKinematics(robot, robot.frame_id(controller.task.goal.pose.frame), controller.planner.control_points)
    i = int(np.flatnonzero(kin.cp_joint == robot.model.getJointId("panda_joint4"))[0])

    def at(qq):
        kin.update(np.asarray(qq, dtype=float))
        return kin.points[i].copy()

    return at


def block_grid(centre, resolution=0.02):
    """A free grid around ``centre`` [m] and the same grid with a block of 3 x 3 x 3 cells there."""
    free = OccupancyGrid.empty(centre - 0.5, centre + 0.5, resolution)
    data = free.data.copy()
    i, j, k = free.index_of(centre[None])[0]
    data[i - 1 : i + 2, j - 1 : j + 2, k - 1 : k + 2] = 1.0
    return free, OccupancyGrid(data, free.origin, resolution)


@pytest.mark.parametrize("name", FIELD_CONTROLLERS)
def test_an_obstacle_near_a_control_point_pushes_it_away(box, name):
    task, q, null = elbow_setting(box)
    robot = task.robot
    controller = make_controller(name)
    controller.setup(task)
    controller.reset(q.copy(), np.random.default_rng(0))
    point = point_on_elbow(controller, robot, q)
    p = point(q)
    towards = point(q + 1e-5 * null) - p
    towards /= np.linalg.norm(towards)
    centre = p + 0.10 * towards  # the block's face 7 cm from the point, where the elbow can move
    free, blocked = block_grid(centre)

    def away_speed(grid):
        controller.update(Observation(0.0, grid))
        qd = controller.step(0.0, q.copy(), None, task.goal)
        h = 1e-3
        return (np.linalg.norm(point(q + h * qd) - centre) - np.linalg.norm(p - centre)) / h  # [m/s]

    without, with_block = away_speed(free), away_speed(blocked)
    assert with_block > without + 0.001, (without, with_block)
    assert controller.info()["largest_push"] > 0


@pytest.mark.parametrize("name", FIELD_CONTROLLERS)
def test_a_new_frame_replaces_the_last_ones_push(box, name):
    controller = make_controller(name)
    controller.setup(box.task)
    q = np.array(box.task.start, dtype=float)
    controller.reset(q, np.random.default_rng(0))
    goal = box.task.goal
    before = controller.step(0.0, q, None, goal)  # no frame yet: no obstacle known
    answers = []
    for observation in (box.free, box.obstacles, box.free, box.obstacles):
        controller.update(observation)
        answers.append(controller.step(0.0, q, observation, goal))
    np.testing.assert_allclose(answers[0], before, atol=1e-12)
    assert not np.allclose(answers[1], answers[0], atol=1e-6)  # the obstacles' frame changes the step
    np.testing.assert_allclose(answers[2], answers[0], atol=1e-12)  # and the next frame forgets them
    np.testing.assert_allclose(answers[3], answers[1], atol=1e-12)
    assert controller.info()["frames"] == 4
    controller.reset(q, np.random.default_rng(0))  # a new run starts knowing no obstacle
    np.testing.assert_allclose(controller.step(0.0, q, None, goal), before, atol=1e-12)


@pytest.mark.parametrize("mode", ["lazy", "full"])
def test_the_field_of_the_observed_grid_is_the_field_of_its_surface(box, mode):
    """Full: computed on the occupied cells' block of the observed grid (cheaper, same numbers);
    lazy: the whole grid read through the surface pass cell by cell (nothing per frame)."""
    grid = OccupancyGrid.from_scene(box.obstacles.scene, 0.02, padding=0.4)  # much free space around
    controller = make_controller("matrix-field", field_mode=mode)
    cropped = controller.field.repulsion(grid)
    if mode == "full":
        assert cropped.grid.data.size < grid.data.size / 2
    else:
        assert cropped.grid is grid and cropped.surface and cropped.field is None
    kernels, gain = controller.field.kernels(grid.resolution)
    whole = surface_grid(grid)
    reference = FieldRepulsion(whole, kernels, full_field(whole, kernels, dtype=np.float64), gain)
    points = np.random.default_rng(1).uniform(grid.origin, grid.upper, size=(300, 3))
    np.testing.assert_allclose(cropped.field_at(points), reference.field_at(points), rtol=1e-9, atol=1e-9)
    assert np.abs(reference.field_at(points)).max() > 1  # the points feel the obstacles


def test_the_loops_dt_does_not_change_the_velocity(box):
    q = np.array(box.task.start, dtype=float)
    answers = []
    for dt in (0.01, 0.002):
        controller = make_controller("matrix-field", dt=dt)
        controller.setup(box.task)
        controller.reset(q, np.random.default_rng(0))
        controller.update(box.obstacles)
        answers.append(controller.step(0.0, q, box.obstacles, box.task.goal))
        assert controller.planner.config.dt == box.task.period  # the runner's tick, whatever the setting
        assert controller.planner.config.escape_attempts == 0  # escapes are planning, not control
    np.testing.assert_array_equal(answers[0], answers[1])


@pytest.mark.parametrize("name", ["matrix-field-qp", "distance-field"])
def test_distances_are_to_the_scene_when_observed_else_to_the_grids_cells(box, name):
    controller = make_controller(name)
    controller.setup(box.task)
    controller.reset(np.array(box.task.start), np.random.default_rng(0))
    key = "collision_geometry" if name == "matrix-field-qp" else "geometry"
    controller.update(box.obstacles)
    assert controller.info()[key] == "scene"
    controller.update(dataclasses.replace(box.obstacles, scene=None))
    assert controller.info()[key] == "near cells"  # the default: the cells near the arm, one octree
    q = np.array(box.task.start, dtype=float)
    assert np.isfinite(controller.step(0.0, q, None, box.task.goal)).all()
    boxes = make_controller(name, observed_geometry="boxes")
    boxes.setup(box.task)
    boxes.reset(q.copy(), np.random.default_rng(0))
    boxes.update(dataclasses.replace(box.obstacles, scene=None))
    assert boxes.info()[key] == "grid cells"


def test_near_cells_are_those_within_reach_as_one_octree_measured_exactly():
    import coal

    from planbench_plugins.controllers.cells import near_cells_scene

    res, origin = 0.02, np.array([0.31, -0.2, 0.1])  # a corner off the multiples of the resolution
    data = np.zeros((30, 30, 30))
    near_cell, far_cell = (10, 10, 10), (10, 10, 25)  # 0 and 0.30 m from the point below
    data[near_cell] = data[far_cell] = 1.0
    data[12, 10, 10] = 0.3  # below the threshold: free
    grid = OccupancyGrid(data, origin, res)
    p = origin + (np.array(near_cell) + 0.5) * res + np.array([0.0, 0.0, 0.05])
    scene = near_cells_scene(grid, p[None], reach=0.1)
    (octree,) = scene.obstacles
    lo, hi = octree.aabb()
    np.testing.assert_allclose(lo, origin + np.array(near_cell) * res, atol=1e-12)  # the near cell alone
    np.testing.assert_allclose(hi, origin + (np.array(near_cell) + 1) * res, atol=1e-12)
    for query in (p, origin + (np.array(far_cell) + 0.5) * res + np.array([0.0, 0.0, 0.05])):
        sphere, placed = coal.Sphere(0.01), coal.Transform3s(np.eye(3), query)
        result = coal.DistanceResult()
        M = octree.placement()
        d = coal.distance(
            octree.collision_geometry(),
            coal.Transform3s(M.rotation, M.translation),
            sphere,
            placed,
            coal.DistanceRequest(),
            result,
        )
        gap = np.maximum(lo - query, 0) + np.maximum(query - hi, 0)  # to the near cell's cube
        assert d == pytest.approx(np.linalg.norm(gap) - 0.01, abs=1e-6)
    assert len(near_cells_scene(grid, p[None] + 1.0, reach=0.1)) == 0  # nothing within reach


def test_the_controller_steers_to_the_goal_it_is_given_each_tick(box):
    controller = make_controller("matrix-field")
    controller.setup(box.task)
    q = np.array(box.task.start, dtype=float)
    controller.reset(q, np.random.default_rng(0))
    pose = box.task.goal.pose
    position = pose.position.copy()
    towards_task_goal = controller.step(0.0, q, None, box.task.goal)
    elsewhere = Goal(Pose(pose.position + np.array([0.0, 0.0, 0.1]), pose.rotation, pose.frame))
    assert not np.allclose(controller.step(0.0, q, None, elsewhere), towards_task_goal, atol=1e-6)
    np.testing.assert_allclose(controller.step(0.0, q, None, box.task.goal), towards_task_goal, atol=1e-12)
    np.testing.assert_array_equal(pose.position, position)  # the task's goal is never written
    with pytest.raises(ValueError, match="goal's frame changed"):
        controller.step(0.0, q, None, Goal(Pose(pose.position, pose.rotation, "panda_link4")))


FOLDED = np.array([0.0, -0.785, 0.0, -2.9, 0.0, 0.5, 0.785])
"""The Panda folded so that two of its links' hulls overlap (by 16 mm)."""


@pytest.mark.parametrize("name", FIELD_CONTROLLERS)
def test_the_arm_still_pushes_off_itself(box, name):
    """The loop's self-collision push (on by default) needs the robot only, so it works in a
    controller; ``matrix-field-qp`` keeps the robot's own pairs apart with its constraints."""
    own = DistanceModel(box.task.robot, Scene(), 0.05, obstacle_pairs=False)
    before = own.near_at(FOLDED).distance.min()
    assert before < 0

    def separation_speed(**settings):  # how fast the overlap shrinks [m/s]
        controller = make_controller(name, **settings)
        controller.setup(box.task)
        controller.reset(FOLDED, np.random.default_rng(0))
        qd = controller.step(0.0, FOLDED.copy(), None, box.task.goal)
        return (own.near_at(FOLDED + 1e-3 * qd).distance.min() - before) / 1e-3

    pushed = separation_speed()
    if name == "matrix-field-qp":
        assert pushed > 0.05
    else:
        assert pushed > separation_speed(self_collision=False) + 0.05


class FailingPlanner(IKLoopPlanner):
    """A loop planner whose step can be told to have no answer."""

    name = "failing"
    fail = False

    def make_repulsion(self, problem, points):
        return ZeroRepulsion()

    def solve_step(self, kin, q, inputs, points, F, support, tool, qd_out, diag):
        if self.fail:
            raise StepFailure(PlanStatus.INFEASIBLE, "no step keeps the joints within their limits")
        super().solve_step(kin, q, inputs, points, F, support, tool, qd_out, diag)


class FailingController(IKLoopController):
    name = "failing"
    planner_class = FailingPlanner

    def make_source(self, observation):
        return None


def test_a_step_without_answer_gives_zero_velocity_and_is_counted(box):
    controller = FailingController()
    controller.setup(box.task)
    q = np.array(box.task.start, dtype=float)
    controller.reset(q, np.random.default_rng(0))
    assert np.abs(controller.step(0.0, q, None, box.task.goal)).max() > 0
    controller.planner.fail = True
    np.testing.assert_array_equal(controller.step(0.01, q, None, box.task.goal), np.zeros(7))
    info = controller.info()
    assert (info["steps"], info["step_failures"]) == (1, 1)
    assert "t = 0.010 s: no step keeps the joints" in info["last_step_failure"]


# --- the guide's example -------------------------------------------------------------------------------


def guide_module(tmp_path, monkeypatch):
    text = GUIDE.read_text()
    code = re.search(r"```python\n(# my_controller\.py\n.*?)```", text, re.S)
    assert code, "the guide's complete controller (a block starting with '# my_controller.py') is missing"
    (tmp_path / "my_controller.py").write_text(textwrap.dedent(code.group(1)))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "my_controller", raising=False)
    import my_controller

    return my_controller


def test_the_guides_controller_conforms_and_reaches_a_goal(tmp_path, monkeypatch, box):
    module = guide_module(tmp_path, monkeypatch)
    assert '[project.entry-points."planbench.controllers"]' in GUIDE.read_text()
    registry = Registry(discover=False, group="planbench.controllers", kind="controller")
    registry.register(module.ResolvedRateController)
    assert check_controller("resolved-rate", registry=registry) == []
    path = drive(registry.make("resolved-rate"), box.task, box.obstacles, ticks=600)
    err_p, err_r = pose_error(box.task.robot, path[-1], box.task.goal.pose)
    assert err_p <= box.task.tolerances.position and err_r <= box.task.tolerances.orientation


@pytest.mark.parametrize("shape", ["box", "sphere"])
def test_witnesses_of_a_distance_to_an_octree_point_from_the_first_body(shape):
    """coal reports a shape's distance to an OcTree given second as if the octree came first
    (3.0.3); ``witnesses`` gives the first body's point and the normal towards the second."""
    import coal

    from planbench.checking.collision import witnesses

    octree = coal.makeOctree(np.array([[0.51, 0.01, 0.01]]), 0.02)  # the cell [0.5, 0.52] x ...
    geometry = coal.Box(0.1, 0.1, 0.1) if shape == "box" else coal.Sphere(0.05)
    result = coal.DistanceResult()
    beside = coal.Transform3s(np.eye(3), np.array([0.3, 0.0, 0.0]))
    d = coal.distance(geometry, beside, octree, coal.Transform3s(), coal.DistanceRequest(), result)
    p1, p2, n = witnesses(result, octree_second=True)
    assert d == pytest.approx(0.15, abs=1e-9)
    assert p1[0] == pytest.approx(0.35, abs=1e-9) and p2[0] == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(n, [1.0, 0.0, 0.0], atol=1e-9)  # from the shape towards the cell
