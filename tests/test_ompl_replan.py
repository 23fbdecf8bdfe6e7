"""ompl-replan: RRT-Connect on the latest observation, a path follower, a replan when a frame
invalidates the rest of the path."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError, InvalidSettingError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.problem import Goal
from planbench.reactive.conformance import check_controller
from planbench.reactive.controller import ControlTask, Observation
from planbench.registry import make_controller
from planbench.scene import Obstacle, Scene
from planbench_plugins.controllers.evade import ArmSamples, EvadeSettings, Threat, retreat


@pytest.fixture(scope="module")
def free_task() -> ControlTask:
    p = planbench.load_problems("mbm:table_pick/0001")[0]
    return ControlTask(p.robot, p.start, p.goal, p.tolerances, 0.01, "free")


def _seen(scene: Scene, t: float, frame: int) -> Observation:
    """A truth observation: the controller plans on its scene."""
    return Observation(t, OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.0), 0.1), frame, None, scene)


def test_ompl_replan_conforms_and_refuses_bad_settings():
    """Its sliced plans end by CPU time by default (``known_cpu_share`` 0.9), so the tick at which
    a plan lands moves with the machine's speed and load, and two runs may part there: the check
    that three runs take the same trajectory is met with slices ended by their count alone, the
    rest of the defaults kept."""
    assert check_controller("ompl-replan", {"known_cpu_share": 0.0}) == []
    found = check_controller("ompl-replan")
    assert all(f.check == "non-deterministic" for f in found), found  # at most the clock's doing
    with pytest.raises(InvalidSettingError, match="speed_scale"):
        make_controller("ompl-replan", speed_scale=2.0)


def test_its_plans_count_the_cpu_time_that_is_charged(free_task):
    c = make_controller("ompl-replan")
    c.setup(free_task)
    assert c.config.plan_clock == "cpu" and c.planner.config.clock == "cpu"
    wall = make_controller("ompl-replan", plan_clock="wall")
    wall.setup(free_task)
    assert wall.planner.config.clock == "wall"
    with pytest.raises(InvalidSettingError, match="plan_clock"):
        make_controller("ompl-replan", plan_clock="thread")
    timeless = make_controller("ompl-replan", planner="straight-line")  # a planner with no clock setting
    with pytest.raises(InvalidConfigError, match="plan_clock='wall'"):
        timeless.setup(free_task)


def test_it_follows_its_path_and_replans_around_an_obstacle_that_appears_on_it(free_task):
    c = make_controller("ompl-replan")
    c.setup(free_task)
    c.reset(np.array(free_task.start), np.random.default_rng(0))
    q = np.array(free_task.start)
    assert np.allclose(c.step(0.0, q, None, free_task.goal), 0.0)  # nothing observed yet: no motion
    c.update(_seen(Scene(), 0.0, 0))
    for k in range(20):  # follow the first plan for 0.2 s
        q = q + 0.01 * c.step(0.01 * k, q, None, free_task.goal)
    assert c.info()["plans"] == 1 and not np.allclose(q, free_task.start)
    first = c.path.copy()
    # a box appears on the rest of that path, where the hand will be half way along it
    mid = first[len(first) // 2] if len(first) > 2 else 0.5 * (q + first[-1])
    hand = free_task.robot.frame_pose(mid).translation
    box = Scene((Obstacle("box", "box", tuple(hand), size=(0.12, 0.12, 0.12)),))
    checker = CollisionChecker(free_task.robot, box)
    assert not checker.in_collision(np.asarray(free_task.goal.q)) and not checker.in_collision(q)
    c.update(_seen(box, 0.2, 1))
    # the path is invalid: first a stop (the command held while it plans), then the plan
    assert np.allclose(c.step(0.2, q, None, free_task.goal), 0.0) and c.info()["plans"] == 1
    c.step(0.21, q, None, free_task.goal)
    info = c.info()
    assert info["invalidated"] == 1 and info["plans"] == 2 and info["failed_plans"] == 0
    new = np.vstack([q, c.path])
    dense = [a + u * (b - a) for a, b in zip(new[:-1], new[1:], strict=True) for u in np.linspace(0, 1, 20)]
    assert not any(checker.in_collision(x) for x in dense)  # the new path goes around the box


def _depth(grid: OccupancyGrid, t: float, frame: int) -> Observation:
    """A depth observation of ``grid``, every cell seen."""
    known = np.ones(grid.shape, dtype=bool)
    return Observation(t, OccupancyGrid(grid.data, grid.origin, grid.resolution, known=known), frame)


def test_an_obstacle_standing_on_the_goal_is_waited_out_not_driven_into(free_task):
    """Depth, ``goal_obstacles = "wait"``: cells next to the arm's body at the goal are left out of
    plans (a surface the goal touches), but a box filling the hand's cells at the goal is an
    obstacle on it: no plan goes there, the arm does not move into it, and once frames show it gone
    the arm reaches the goal."""
    robot, goal_q = free_task.robot, np.asarray(free_task.goal.q)
    empty = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    hand = robot.frame_pose(goal_q, free_task.goal.pose.frame).translation
    box = Scene((Obstacle("box", "box", tuple(hand), size=(0.1, 0.1, 0.1)),))
    blocked = OccupancyGrid.from_scene(box, 0.02, bounds=(empty.origin, empty.origin + 2.2), rule="any")
    assert blocked.shape == empty.shape and (blocked.data >= 0.5).sum() > 100
    checker = CollisionChecker(robot, box)
    with pytest.raises(InvalidSettingError, match="goal_obstacles"):
        make_controller("ompl-replan", goal_obstacles="avoid")
    c = make_controller("ompl-replan", goal_obstacles="wait")
    c.setup(free_task)
    q = np.array(free_task.start, dtype=float)
    c.reset(q.copy(), np.random.default_rng(0))
    vmax = np.asarray(robot.velocity_limit)
    for k in range(300):  # 3 s with the box on the goal, a frame every 3 ticks
        if k % 3 == 0:
            c.update(_depth(blocked, 0.01 * k, k // 3))
        q = q + 0.01 * np.clip(c.step(0.01 * k, q, None, free_task.goal), -vmax, vmax)
        assert not checker.in_collision(q), k  # never into the box
    info = c.info()
    assert info["goal_blocked"] > 0 and info["plans"] > 1 and info["plans"] == info["failed_plans"]
    for k in range(300, 900):  # the box has left
        if k % 3 == 0:
            c.update(_depth(empty, 0.01 * k, k // 3))
        q = q + 0.01 * np.clip(c.step(0.01 * k, q, None, free_task.goal), -vmax, vmax)
    assert np.allclose(q, goal_q, atol=1e-3), c.info()


def test_an_obstacle_that_appears_on_the_goal_blocks_it_and_one_seen_from_the_start_does_not(free_task):
    """Depth, ``goal_obstacles = "appeared"``: a box that arrives on the goal after frames saw it
    free is waited out (no plan goes there, the arm never moves into it, the failed plans do not
    relax the surface margin) and the arm reaches the goal once it leaves; a box that stands there
    from the first frame is the static scene the goal touches, left out of plans, so the arm drives
    to the goal."""
    robot, goal_q = free_task.robot, np.asarray(free_task.goal.q)
    empty = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    hand = robot.frame_pose(goal_q, free_task.goal.pose.frame).translation
    box = Scene((Obstacle("box", "box", tuple(hand), size=(0.1, 0.1, 0.1)),))
    blocked = OccupancyGrid.from_scene(box, 0.02, bounds=(empty.origin, empty.origin + 2.2), rule="any")
    checker = CollisionChecker(robot, box)
    vmax = np.asarray(robot.velocity_limit)

    def run(frames, ticks, c, q):
        """The configurations of ``ticks`` ticks from ``q``, a frame of ``frames(k)`` every 3."""
        qs = []
        for k in ticks:
            if k % 3 == 0:
                c.update(_depth(frames(k), 0.01 * k, k // 3))
            q = q + 0.01 * np.clip(c.step(0.01 * k, q, None, free_task.goal), -vmax, vmax)
            qs.append(q)
        return qs

    c = make_controller("ompl-replan", goal_obstacles="appeared")
    c.setup(free_task)
    c.reset(np.array(free_task.start, dtype=float), np.random.default_rng(0))
    qs = run(lambda k: empty if k < 3 else blocked, range(300), c, np.array(free_task.start, dtype=float))
    assert not any(checker.in_collision(x) for x in qs)  # the box arrived at 30 ms: never driven into
    info = c.info()
    assert info["goal_blocked"] > 0 and info["plans"] > 1 and info["relaxed"] == 0
    q = run(lambda k: empty, range(300, 900), c, qs[-1])[-1]  # the box has left
    assert np.allclose(q, goal_q, atol=1e-3), c.info()

    static = make_controller("ompl-replan", goal_obstacles="appeared")
    static.setup(free_task)
    static.reset(np.array(free_task.start, dtype=float), np.random.default_rng(0))
    q = run(lambda k: blocked, range(600), static, np.array(free_task.start, dtype=float))[-1]
    assert np.allclose(q, goal_q, atol=1e-3) and static.info()["goal_blocked"] == 0


def _box_frame(grid: OccupancyGrid, points: np.ndarray, t: float, frame: int) -> Observation:
    """A depth observation of ``points`` (a box's surface): their cells occupied, every cell known."""
    data = np.zeros(grid.shape)
    idx = grid.index_of(points)
    inside = np.all((idx >= 0) & (idx < np.array(grid.shape)), axis=1)
    data[tuple(idx[inside].T)] = 1.0
    seen = OccupancyGrid(data, grid.origin, grid.resolution, known=np.ones(grid.shape, dtype=bool))
    return Observation(t, seen, frame, points.astype(np.float32))


def _cube(centre: np.ndarray, half: float = 0.05, spacing: float = 0.005) -> np.ndarray:
    """Points [m] on the surface of the cube of half side ``half`` around ``centre``."""
    u = np.arange(-half, half + 1e-9, spacing)
    a, b = (x.ravel() for x in np.meshgrid(u, u, indexing="ij"))
    faces = []
    for axis in range(3):
        for side in (-half, half):
            f = np.zeros((len(a), 3))
            f[:, axis], f[:, (axis + 1) % 3], f[:, (axis + 2) % 3] = side, a, b
            faces.append(f)
    return np.vstack(faces) + centre


def _crossing(task: ControlTask, prediction: str) -> tuple[int | None, float, dict]:
    """Depth: the arm stands at its start with its first plan; a box flies at 1 m/s (30 frames a
    second) at the hand's place half way along that path. The frame at which the path is dropped
    (None: never), the box's distance [m] from that place then, and the controller's ``info``."""
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    c = make_controller(
        "ompl-replan", prediction=prediction, evade="none", known_sliced_when="always", plan_sliced_when="never"
    )  # the path check alone
    c.setup(task)
    q = np.array(task.start, dtype=float)
    c.reset(q.copy(), np.random.default_rng(0))
    c.update(_box_frame(grid, np.zeros((0, 3)), 0.0, 0))
    c.step(0.0, q, None, task.goal)
    path = c.path
    assert path is not None
    mid = path[len(path) // 2] if len(path) > 2 else 0.5 * (path[0] + path[-1])
    target = task.robot.frame_pose(mid, task.goal.pose.frame).translation
    v = np.array([0.0, -1.0, 0.0])
    for k in range(1, 30):
        centre = target - v * (0.8 - k / 30.0)
        c.update(_box_frame(grid, _cube(centre), k / 30.0, k))
        command = c.step(k / 30.0, q, None, task.goal)
        if c.info()["invalidated"]:
            assert np.allclose(command, 0.0)  # the path dropped: a stop first
            return k, float(np.linalg.norm(centre - target)), c.info()
    return None, 0.0, c.info()


def test_with_prediction_the_path_is_dropped_before_a_crossing_box_reaches_it(free_task):
    """``prediction = "swept"``: the cells a tracked box sweeps over the next 0.5 s are obstacles
    of the path's check, so the path is dropped (the arm stopped, a replan next) while the box is
    still more than 0.4 m from it; without prediction only when the box's own cells reach it,
    frames later."""
    late, _, plain = _crossing(free_task, "none")
    early, distance, predicted = _crossing(free_task, "swept")
    assert late is not None and early is not None
    assert plain["predicted_frames"] == 0 and predicted["predicted_frames"] >= 1
    assert early + 3 <= late and distance > 0.4
    with pytest.raises(InvalidSettingError, match="prediction"):
        make_controller("ompl-replan", prediction="ahead")


def test_depth_frames_after_the_first_check_only_new_cells_and_still_see_an_obstacle_arrive(free_task):
    """Depth: the first frame on a path checks it against every occupied cell, later frames only
    against cells no check of it held. A box that fills cells on the rest of the path after
    several frames of the path being clear still invalidates it, and the new plan goes around it."""
    robot = free_task.robot
    c = make_controller("ompl-replan", unknown="free", plan_sliced_when="never")  # plans at once: counted at once
    c.setup(free_task)
    c.reset(np.array(free_task.start), np.random.default_rng(0))
    q = np.array(free_task.start)
    empty = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    post = Scene((Obstacle("post", "box", (0.9, 0.9, 0.1), size=(0.1, 0.1, 0.2)),))  # far from the arm
    static = OccupancyGrid.from_scene(post, 0.02, bounds=(empty.origin, empty.origin + 2.2), rule="any")
    for k in range(12):  # frames every 30 ms while the arm follows its first plan
        if k % 3 == 0:
            c.update(_depth(static, 0.01 * k, k // 3))
        q = q + 0.01 * c.step(0.01 * k, q, None, free_task.goal)
    info = c.info()
    assert info["plans"] == 1 and info["invalidated"] == 0 and c.reach is not None  # the path's boxes: built
    first = c.path.copy()
    mid = first[len(first) // 2] if len(first) > 2 else 0.5 * (q + first[-1])
    hand = robot.frame_pose(mid).translation
    box = Scene((*post.obstacles, Obstacle("box", "box", tuple(hand), size=(0.12, 0.12, 0.12))))
    grid = OccupancyGrid.from_scene(box, 0.02, bounds=(empty.origin, empty.origin + 2.2), rule="any")
    checker = CollisionChecker(robot, box)
    assert not checker.in_collision(q) and not checker.in_collision(np.asarray(free_task.goal.q))
    c.update(_depth(grid, 0.12, 4))
    assert np.allclose(c.step(0.12, q, None, free_task.goal), 0.0)  # a stop: the path is dropped
    c.step(0.13, q, None, free_task.goal)
    info = c.info()
    assert info["invalidated"] == 1 and info["plans"] == 2 and info["failed_plans"] == 0
    new = np.vstack([q, c.path])
    dense = [a + u * (b - a) for a, b in zip(new[:-1], new[1:], strict=True) for u in np.linspace(0, 1, 20)]
    assert not any(checker.in_collision(x) for x in dense)


def test_the_boxes_around_the_links_hold_every_cell_the_arm_touches(free_task):
    """``LinkBoxes``: a cell that coal finds touching the arm at a configuration lies in the mask
    of the path's cells and its (configuration, object) pair is among those ``touching`` gives, so
    ruling cells and configurations out by the boxes never misses a collision; ``touches`` answers
    as a checker of the cells does."""
    from planbench_plugins.controllers.observed import LinkBoxes
    from planbench_plugins.ompl_planners import cells_checker

    robot = free_task.robot
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.04)
    rng = np.random.default_rng(3)
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    qs = lo + rng.random((6, len(lo))) * (hi - lo)
    reach = LinkBoxes(robot).along(qs, grid)
    alone = cells_checker(robot, grid, np.zeros(0, dtype=np.intp))
    found = 0
    for i, q in enumerate(qs):
        if alone.in_collision_all_pairs(q):  # the arm touches itself: not the cell's doing
            continue
        body = robot.collision_model
        for _ in range(40):  # cells near the arm's links: a link origin, moved by up to 8 cm
            frame = rng.integers(len(body.geometryObjects))
            near = reach.placements[i, frame][:3, 3] + rng.uniform(-0.08, 0.08, 3)
            idx = np.floor((near - grid.origin) / grid.resolution).astype(int)
            if np.any(idx < 0) or np.any(idx >= grid.shape):
                continue
            cell = np.array([np.ravel_multi_index(tuple(idx), grid.shape)])
            data = np.zeros(grid.shape)
            data.flat[cell] = 1.0
            touching = cells_checker(robot, grid, cell).in_collision_all_pairs(q)
            assert LinkBoxes(robot).touches(q, OccupancyGrid(data, grid.origin, grid.resolution)) == touching
            if not touching:
                continue
            found += 1
            assert reach.near(cell).size == 1
            rows, objects = reach.touching(cell)
            assert i in rows and reach.collides(cell, rows[rows == i], objects[rows == i])
    assert found >= 20


def test_goal_cells_keep_what_appeared_after_a_free_frame_and_leave_out_the_rest():
    """``GoalCells``: a cell occupied when first known is static (left out); one seen free and then
    occupied blocks the goal until ``block_time`` has passed (then stale, left out); one no frame
    has known is neither left out nor blocking; a blocker seen free again blocks no more."""
    from planbench_plugins.controllers.observed import GoalCells

    near = np.array([0, 1, 2, 3])  # flat indices into a 1x1x4 grid

    def frame(occupied, known):
        return OccupancyGrid(
            np.array(occupied, dtype=float).reshape(1, 1, 4), np.zeros(3), 0.02, known=np.array(known).reshape(1, 1, 4)
        )

    g = GoalCells(block_time=1.0)  # the first sight alone (the default; the fringe: the next test)
    out = g.classify(0.0, frame([1, 0, 0, 0], [True, True, False, True]), near)
    assert out.tolist() == [True, False, False, False] and not g.blocking.any()
    out = g.classify(0.5, frame([1, 1, 1, 0], [True, True, True, True]), near)
    # cell 1 was seen free: it appeared; cell 2 was unknown before: occupied when first known
    assert out.tolist() == [True, False, True, False] and g.blocking.tolist() == [False, True, False, False]
    g.classify(1.4, frame([1, 1, 1, 0], [True] * 4), near)
    assert g.blocking.tolist() == [False, True, False, False]  # 0.9 s: still blocking
    out = g.classify(1.6, frame([1, 1, 1, 0], [True] * 4), near)
    assert out[1] and not g.blocking.any()  # 1.1 s: taken for what the map keeps, left out
    g.classify(1.7, frame([1, 0, 1, 1], [True] * 4), near)
    assert g.blocking.tolist() == [False, False, False, True]  # cell 1 seen free again; cell 3 appeared


def test_goal_cells_take_a_flickering_cell_beside_the_static_scene_for_it():
    """``GoalCells`` with ``fringe = 1``: a cell next to one occupied when first seen (a can's
    surface) that a frame saw free and the next occupied is that surface flickering, left out
    however often it flickers; an occupied cell two cells from the surface blocks the goal as
    before. With ``fringe = 0`` the flickering cell blocks the goal each time it comes back."""
    from planbench_plugins.controllers.observed import GoalCells

    near = np.arange(6)  # flat indices into a 1x1x6 grid

    def frame(occupied):
        data = np.zeros(6)
        data[list(occupied)] = 1.0
        return OccupancyGrid(data.reshape(1, 1, 6), np.zeros(3), 0.02, known=np.ones((1, 1, 6), dtype=bool))

    for fringe, flicker_blocks in ((1, False), (0, True)):
        g = GoalCells(block_time=6.0, fringe=fringe)
        g.classify(0.0, frame([0]), near)  # cell 0: the static scene
        out = g.classify(0.1, frame([0, 1, 3]), near)  # 1 beside it; 3 two cells from it
        assert g.blocking[3] and not out[3]
        assert g.blocking[1] == flicker_blocks and out[1] != flicker_blocks
        g.classify(0.2, frame([0, 3]), near)  # the flickering cell seen free
        out = g.classify(0.3, frame([0, 1, 3]), near)  # and occupied again
        assert g.blocking[1] == flicker_blocks and g.blocking[3]


def _box_at_the_standing_arm(task: ControlTask, evade: str, sensing: str = "depth") -> tuple[bool, dict]:
    """30 frames a second: the arm stands at its goal; a box flies at 0.5 m/s through the place of
    its hand, from 0.6 m away. Whether the box ever touched the arm (the arm moved by the commands,
    clipped to the velocity limits), and the controller's ``info``. ``sensing``: ``"depth"`` (the
    box's surface points) or ``"truth"`` (the box's exact scene and its voxels)."""
    robot, q = task.robot, np.array(task.start, dtype=float)
    at_start = Goal(robot.frame_pose(q, task.goal.pose.frame), q.copy())
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    hand = robot.frame_pose(q, task.goal.pose.frame).translation
    v = np.array([0.0, -0.5, 0.0])
    c = make_controller("ompl-replan", unknown="free", evade=evade)
    c.setup(dataclasses.replace(task, goal=at_start))
    c.reset(q.copy(), np.random.default_rng(0))
    vmax = np.asarray(robot.velocity_limit)
    touched = False
    for k in range(200):  # 2 s: the box reaches the hand at 1.2 s
        t = 0.01 * k
        centre = hand - v * (1.2 - t)
        if k % 3 == 0:
            frame = _box_frame(grid, _cube(centre), t, k // 3)
            if sensing == "truth":
                voxels = OccupancyGrid(frame.grid.data, grid.origin, grid.resolution)  # every cell known
                scene = Scene((Obstacle("box", "box", tuple(centre), size=(0.1, 0.1, 0.1)),))
                frame = Observation(t, voxels, k // 3, None, scene)
            c.update(frame)
        q = q + 0.01 * np.clip(c.step(t, q, None, at_start), -vmax, vmax)
        box = Scene((Obstacle("box", "box", tuple(hand - v * (1.2 - t - 0.01)), size=(0.1, 0.1, 0.1)),))
        touched = touched or CollisionChecker(robot, box).in_collision(q)
    return touched, c.info()


def test_with_evade_the_arm_backs_away_from_a_box_flying_at_it(free_task):
    """``evade = "retreat"``: the cells that came in lately within ``evade_distance`` of the arm
    make it retreat, so a box flying through the standing hand's place misses the arm; without
    it the arm, at its goal, waits where it is and is hit. With depth and with truth sensing."""
    hit, plain = _box_at_the_standing_arm(free_task, "none")
    assert hit and plain["evasions"] == 0
    hit, evaded = _box_at_the_standing_arm(free_task, "retreat")
    assert not hit and evaded["evasions"] >= 1, evaded
    assert check_controller("ompl-replan", {"evade": "retreat", "known_cpu_share": 0.0}) == []
    hit, plain = _box_at_the_standing_arm(free_task, "none", "truth")
    assert hit and plain["evasions"] == 0
    hit, evaded = _box_at_the_standing_arm(free_task, "retreat", "truth")  # the voxels of the exact scene
    assert not hit and evaded["evasions"] >= 1, evaded
    with pytest.raises(InvalidSettingError, match="evade"):
        make_controller("ompl-replan", evade="flee")
    with pytest.raises(InvalidSettingError, match="evade_distance"):
        make_controller("ompl-replan", evade_distance=float("nan"))


def test_a_threat_at_a_moving_arm_stops_it_before_it_retreats(free_task):
    """The runner holds the last command while a retreat is worked out (tens of milliseconds,
    charged): a retreat worked out for a moving arm would start from wherever that command carried
    it, along a motion nothing checked (the UR5's upper arm was driven into a table so). So a
    threat at a moving arm stops it in that tick, and the retreat starts where the arm stands."""
    robot, q = free_task.robot, np.array(free_task.start, dtype=float)
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    c = make_controller("ompl-replan", unknown="free", evade="retreat")
    c.setup(free_task)
    c.reset(q.copy(), np.random.default_rng(0))
    vmax = np.asarray(robot.velocity_limit)
    k, command = 0, np.zeros_like(q)
    while not np.any(command) and k < 30:  # empty frames until the arm follows its first path
        if k % 3 == 0:
            c.update(_box_frame(grid, np.zeros((0, 3)), 0.01 * k, k // 3))
        command = np.clip(c.step(0.01 * k, q, None, free_task.goal), -vmax, vmax)
        q, k = q + 0.01 * command, k + 1
    assert np.any(command), "the arm never set off"
    hand = robot.frame_pose(q, free_task.goal.pose.frame).translation
    c.update(_box_frame(grid, _cube(hand + [0.0, 0.0, 0.12]), 0.01 * k, k))  # a box appears by the hand
    assert not np.any(c.step(0.01 * k, q, None, free_task.goal))  # a stop, no retreat yet
    assert c.info()["evasions"] == 0
    command = c.step(0.01 * (k + 1), q, None, free_task.goal)  # the stop held: the arm stands at q
    assert np.any(command) and c.info()["evasions"] == 1
    assert np.array_equal(c.path[0], q)  # the retreat starts where the arm stands


def test_a_retreat_ends_farther_from_the_threat_or_is_not_made(free_task):
    """:func:`retreat`: the end it picks keeps the arm's body farther from the threat's cells than
    where it stands, by more than a cell, and its motion is free; with steps too small to get a
    cell farther, none."""
    robot, q = free_task.robot, np.array(free_task.start, dtype=float)
    grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
    hand = robot.frame_pose(q, free_task.goal.pose.frame).translation
    cells = np.unique(np.ravel_multi_index(grid.index_of(_cube(hand + [0.2, 0.0, 0.0])).T, grid.shape))
    threat = Threat(grid, cells)
    body = ArmSamples(robot)
    checker = CollisionChecker(robot, Scene())
    limits = (np.asarray(robot.lower), np.asarray(robot.upper))
    here = threat.distance(body, q)
    assert 0.0 < here < 0.15, here
    end = retreat(q, threat, body, checker, limits, EvadeSettings(), 0.02, np.random.default_rng(0))
    assert end is not None and threat.distance(body, end) > here + grid.resolution
    assert np.all(np.abs(end - q) <= 0.5 + 1e-12) and np.all(end >= limits[0]) and np.all(end <= limits[1])
    tiny = EvadeSettings(evade_step=1e-4)
    assert retreat(q, threat, body, checker, limits, tiny, 0.02, np.random.default_rng(0)) is None


def test_a_threat_is_measured_from_the_parts_a_joint_moves():
    """Cells beside the base, which no joint moves, are no threat: a retreat can never take the base
    farther from them, and measured from it they stopped the arm for retreats that all failed
    (``dynamic-test:xarm7_pair_fast_depth/0008``). Cells beside a moving link still are."""
    from planbench.reactive.body import body_points

    for name in ("panda", "xarm7"):  # bases taller than the first link's reach (the UR5's shoulder sits on its base)
        robot = planbench.load_robot(name)
        q = np.clip(np.zeros(robot.nq), robot.lower, robot.upper)
        body = ArmSamples(robot)
        objects = robot.collision_model.geometryObjects
        assert 0 not in {objects[int(i)].parentJoint for i in np.unique(body.part)}
        base = next(i for i, o in enumerate(objects) if o.parentJoint == 0)
        M = objects[base].placement  # the base's in the world: it never moves
        points = body_points(robot, 0.02)[base] @ M.rotation.T + M.translation
        grid = OccupancyGrid.empty(np.full(3, -1.0), np.full(3, 1.2), 0.02)
        beside = np.array([points[:, 0].min() - 0.05, points[:, 1].mean(), points[:, 2].min() + 0.02])
        cells = np.unique(np.ravel_multi_index(grid.index_of(_cube(beside, half=0.01)).T, grid.shape))
        threat = Threat(grid, cells)
        to_base = float(np.min(np.linalg.norm(points[:, None, :] - threat.tree.data[None, :, :], axis=-1)))
        assert to_base < 0.08, (name, to_base)
        assert threat.distance(body, q) > to_base + 0.05, name  # farther from every part that moves
        hand = robot.frame_pose(q, robot.settings.ee_frame).translation
        cells = np.unique(np.ravel_multi_index(grid.index_of(_cube(hand + [0.0, 0.0, 0.1], half=0.01)).T, grid.shape))
        assert Threat(grid, cells).distance(body, q) < 0.15, name  # by the hand: a threat


def test_the_benchmark_warms_it_up_through_a_plan():
    """A benchmark run charges the controller's CPU time, so the first plan's one-time costs (the
    imports, OMPL's and coal's first objects, numba's line walk) must be met untimed: on
    ``dynamic-tune``'s ``xarm7_crossing_fast_depth/0007`` in the benchmark's worker they were
    0.5-1.2 s of the first plan's charge, where the plans took 0.6 s. The warm-up's frames take
    ``ompl-replan`` through a plan and into the plan in known space: by default (one frame, so
    no obstacle's motion is known) both in slices; with every plan made at once, both at once."""
    from planbench.reactive.bench import _warm
    from planbench.reactive.sets import load_scenario

    scenario = load_scenario("dynamic-tune:xarm7_crossing_fast_depth/0007")
    controller = make_controller("ompl-replan")
    assert _warm(controller, scenario)
    info = controller.info()
    assert info["plans"] >= 1 and info["sliced_plans"] >= 1 and info["known_slices"] >= 1, info
    controller = make_controller("ompl-replan", known_checks_per_tick=0, plan_sliced_when="never")
    assert _warm(controller, scenario)
    info = controller.info()
    assert info["plans"] >= 2 and info["sliced_plans"] == 0, info  # the optimistic plan and the one in known space


def test_no_built_in_controller_declines_the_warm_up():
    """The closed loop charges a controller's CPU time, so a built-in controller that declined the
    benchmark's warm-up (``warm_up = False``) would be charged its one-time costs in its first plan
    or frame (``ompl-replan`` was, 0.9 s a run with depth sensing, when the warm-up was asked for
    by name and it did not ask)."""
    from planbench.registry import CONTROLLERS

    cold = []
    for name in CONTROLLERS.names():
        spec = CONTROLLERS.spec(name)
        if not spec.entry_point.startswith("planbench_plugins.") or not spec.available:
            continue  # another package's controller, or an extra not installed (vamp-replan)
        if not getattr(spec.load(), "warm_up", True):
            cold.append(name)
    assert not cold, f"built-in controllers not warmed up before their runs: {cold}"
