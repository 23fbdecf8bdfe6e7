"""``matrix-field-guided`` as a controller: a global RRT-Connect path on the latest observation,
planned a slice per tick, tracked with the matrix field pushing the arm clear.

**The plan.** RRT-Connect (OMPL, :class:`~planbench_plugins.ompl_planners.SlicedRRTConnect`) plans
from the configuration the arm holds to the goal configuration against the observed geometry, as
``ompl-replan`` builds it (:mod:`.observed`): the observation's scene less the obstacles the arm
touches (truth sensing), or the occupied cells as coal octrees, less the cells within a cell of the
arm's body when it touches them (depth sensing). At the goal, the cells near the arm's body there
are left out only when they were occupied the first time a frame knew them (the static scene a
grasp touches, as ``ompl-replan`` leaves them out); a cell seen free there and occupied later is
an obstacle on the goal, kept, and the goal is blocked while it is there, for ``goal_block_time``
at most (then it is taken for what a map keeps where no ray passes any more, and left out).

**Time-sliced, not threaded.** The benchmark charges the controller's process all its CPU time,
every thread, as if it had one core (docs/reactive.md, "Compute is charged from outside"): a
planning thread's work is charged to the next call anyway. So the work is cut into slices, and
each ``step`` does the control law plus at most one slice: a plan's preparation (truth: the
scene's checker; depth: the occupied cells found in two slices, the cells the arm touches, then
octrees of at most ``octree_cells`` cells, one per tick, then their checker), then RRT-Connect
search and shortening slices of ``plan_checks_per_tick`` collision checks (the search may end up
to two motions of ``plan_range / motion_resolution`` checks beyond:
:mod:`planbench_plugins.ompl_planners.sliced`), or, while a path is tracked, the check of the
latest frame (below). A slice's end is set by check counts and frames, and a search or
shortening slice also ends once the tick's CPU time has run out (``slice_cpu_share``, counted
from the turn's ``update`` when it took in a frame; 0 turns that off).
While it plans, the arm holds the reference it had (after a lag replan: where it is) with the field
on; a plan starts there, and the tracker takes the path from where the arm is (its feedback closes
the small gap). A query that finds nothing in ``plan_check_budget`` checks starts again from the
held configuration on the latest frame.

**Tracking** (the planner's law, :func:`~planbench_plugins.matrix_field_guided.tracking_velocity`,
once per tick at the task's period): ``qd = (r_next - r) / T + K (r - q) + w sum J^T f``, the push
``f`` the lazy matrix field of the latest grid at the control points (:class:`.matrix_field.GridField`:
the same kernels and stand-off gain as ``matrix-field``), ``w`` faded by the lag ``max |q - r|`` over
``max_lag`` and over the last ``goal_fade`` of the path (not while holding), then the velocity limits
(one factor) and the joint limits.

**Replanning**, counted in ``info()["replans"]`` by why: ``invalidated``, a new frame shows the rest
of the path in collision (checked from the reference every ``check_resolution`` rad, in slices;
truth: against the frame's scene less what the arm touches; depth: against the cells occupied now
that the plan did not know, which is the same verdict since the plan's own cells were checked by
the planner, and costs one pass over the grid instead of an octree of every cell); ``lag``, the arm
is more than ``replan_lag`` from its reference (the field pushed it far off; it then holds where it
is); ``blocked``, a plan refused because the goal configuration is in collision with what is
observed: the arm holds, field on, and tries again on the next frame.

**Unknown space** (``unknown``, :class:`.unknown.UnknownSettings`): ``"occupied"`` reads the unknown
cells near the arm (where the last step left it) as occupied, for the field and for the plan and its
checks, as ``matrix-field`` does for its field; ``"free"`` (default) reads them free. With truth
sensing every cell is known.

**Prediction** (``prediction``, :class:`.prediction.PredictionSettings`): ``"swept"`` adds the cells
the moving clusters of the frames sweep over ``prediction_horizon`` to the push (their own field)
and to the occupied cells of its plans and path checks, so a sweep across the rest of the path
invalidates it and one over the goal blocks it. ``"none"`` (default: on ``dynamic-tune`` it held
while sweeps blocked its goal and solved one of two scenarios where ``"none"`` solved both,
docs/reactive.md, "Prediction").
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.field.scene_field import FieldSettings
from planbench.geometry.occupancy import OccupancyGrid, grid_shape
from planbench.problem import Goal
from planbench.reactive.body import body_points
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.reactive.sensing import default_bounds
from planbench_plugins.controllers.live import LiveRepulsion
from planbench_plugins.controllers.matrix_field import GridField
from planbench_plugins.controllers.observed import ArmCells, GoalCells, finished, scene_without_touched_in_steps
from planbench_plugins.controllers.prediction import (
    MotionPredictor,
    PredictionSettings,
    SummedRepulsion,
    predicted_grid,
    warm_up,
)
from planbench_plugins.controllers.unknown import UnknownSettings, near_unknown, unknown_as_occupied
from planbench_plugins.ik_loop import ArmKinematics, ArmRepulsion, Repulsion, check_number, place_control_points
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field_guided import Reference, push_weight, tracking_velocity
from planbench_plugins.ompl_planners import SlicedRRTConnect, cells_octree, pieces_checker, pieces_checker_in_steps

__all__ = ["MatrixFieldGuidedController", "MatrixFieldGuidedControllerConfig"]

Work = Generator[None, None, None]
"""A job cut into slices: each ``next`` runs one slice."""

R = TypeVar("R")

SCAN_PARTS = 2
"""Slices in which a depth grid's occupied cells are found (each a part of the grid's cells), at
:data:`SLICE_PERIOD`."""

MIN_SLICE_CELLS = 1000
"""The fewest cells in one octree of a plan's geometry with ``scale_slices``: building 1,000 costs
about 0.25 ms, and each octree adds about 0.08 ms to building the checker (18 pieces of 400 cells:
2.0 ms, 7 of 1,000: 1.0 ms, on a Panda frame of 7,000 occupied cells)."""

TICK_COST = 0.0005
"""[s] What a tick costs besides its slice (the tracking law, the call and a frame's share), charged
every tick: about 0.2-0.3 ms in process and 0.5 ms across processes on the Panda at 1 kHz. A
search slice gets ``plan_checks_per_tick`` times the period left beyond it over that of a 10 ms
tick (``scale_slices``): 11 checks at 1 kHz with the default 200 (3 with 50; 5 checks, before slices
ended by CPU time, made ticks of 1.3 ms at p99)."""

SLICE_PERIOD = 0.01
"""[s] The control period for which the slice sizes are given (``plan_checks_per_tick``,
``octree_cells``, :data:`SCAN_PARTS`); with ``scale_slices`` they scale with the task's period."""


@dataclass(frozen=True)
class MatrixFieldGuidedControllerConfig(FieldSettings, UnknownSettings, PredictionSettings):
    """Settings of the ``matrix-field-guided`` controller (module docstring). The field's are
    ``matrix-field-guided``'s (:class:`~planbench.field.scene_field.FieldSettings`; ``grid_resolution``
    is not used: the kernels are built at the observed grid's resolution)."""

    # --- planning, a slice per tick --------------------------------------------------------------
    plan_checks_per_tick: int = 200
    """Collision checks of one planning or path-check slice; one slice per tick. With
    ``slice_cpu_share`` (the default) a slice also ends once the tick has used that share of the
    period, which at 100 Hz usually comes first (checks cost 20-50 us with depth sensing). 200 since
    2026-12-05 (was 50, chosen before that bound, when 100 cost deadlines): on ``dynamic-tune`` the
    same 58 of 72 with fewer missed deadlines (docs/reactive.md, "Checks a slice under a CPU bound")."""
    scale_slices: bool = True
    """Size the slices for the task's control period: ``plan_checks_per_tick`` and ``octree_cells``
    are a 10 ms tick's, the checks multiplied by the share of the period left beyond
    :data:`TICK_COST` (at least 1), the cells by ``period / 10 ms`` (at least :data:`MIN_SLICE_CELLS`),
    and a grid's scan takes ``2 * 10 ms / period`` slices: at 1 kHz, 11 checks, 1,000 cells, 20
    parts, so a tick
    stays near a tenth of the work; at 100 Hz nothing changes. False: the numbers as given."""
    slice_cpu_share: float = 0.6
    """> 0 (0.6, the default): a search, shortening or path-check slice also ends at the first check after the
    tick has used this share of the control period in CPU time (after at least one check), so that
    a slice of slow checks does not pass the period; a turn that takes in a frame counts from its
    ``update``, and runs no slice when the update and the goal cells' classification used the
    share (any other turn runs one); the search's checks and path stay the same,
    only when it finds them moves with the clock (:mod:`planbench_plugins.ompl_planners.sliced`,
    "A slice's CPU time"). 0: a slice ends by its check count alone. Chosen on ``dynamic-tune``
    (the same 57 of 72 solved, a quarter of the missed deadlines) in docs/reactive.md ("A slice's
    CPU time")."""
    plan_check_budget: int = 20000
    """Checks one RRT-Connect query may spend without a path before it starts again from the held
    configuration on the latest frame."""
    plan_range: float = 0.5
    """RRT-Connect's longest extension [rad] (``ompl-rrtconnect``'s default)."""
    motion_resolution: float = 0.01
    """Largest joint motion between configurations the planner checks [rad] (``ompl-rrtconnect``'s)."""
    shorten: bool = True
    """Shorten the path found (greedy, in slices; :mod:`planbench_plugins.ompl_planners.sliced`)."""
    octree_cells: int = 4000
    """Depth sensing: most occupied cells put in one octree per tick while a plan's geometry is
    built (one octree of 15,000 cells costs 7-17 ms)."""
    check_resolution: float = 0.02
    """Spacing of the configurations at which the rest of the path is checked on a new frame [rad]."""
    goal_block_time: float = 6.0
    """[s] Depth: a cell near the arm's body at the goal that a frame saw free and that is occupied
    blocks the goal for at most this long, then it is left out as those occupied from the start
    are: a map keeps an obstacle that left where no ray passes any more (the arm's own shadow, say;
    seen on ``dynamic:panda_reaching_fast_depth/0001``). The ``dynamic`` set parks obstacles on
    the goal for 2-5 s."""
    goal_fringe: int = 0
    """[cells] Depth: an occupied cell near the goal within this many cells of one that was
    occupied when first seen is taken for that static surface and left out, however it flickered
    (:class:`~.observed.GoalCells`); 0 (the default): only the first sight decides. 1 ended a
    flickering can's blocks of the goal in a traced run, and was not better in benchmark runs
    (docs/reactive.md, "A flickering shelf blocked the goal")."""
    replan_lag: float = 0.3
    """[rad] The arm farther than this from its reference (largest joint error) plans again from
    where it is."""
    hold_gives_way: bool = True
    """While there is no path (planning, or the goal blocked), the held configuration follows the
    arm wherever the field pushes it, so that an obstacle coming at the waiting arm drives it back;
    False: the hold pulls the arm back against the push (which fades with the distance from it)."""

    # --- tracking ---------------------------------------------------------------------------------
    velocity_scale: float = 0.5
    """The reference moves along the path at this fraction of the joint velocity limits (0, 1]."""
    tracking_gain: float = 10.0
    """``K`` [1/s] of the feedback ``K (r - q)``; ``K`` times the control period must be at most 1."""
    max_lag: float = 0.1
    """[rad] The push fades out (a smoothstep) as the arm's largest joint error from the reference
    nears this."""
    goal_fade: float = 0.3
    """[rad] The push fades to 0 over this much joint path length before the goal."""

    # --- the push (the matrix field, as matrix-field-guided's) -----------------------------------
    field_mode: str = "lazy"
    """``"lazy"``: window sums of the grid at the control points every tick (nothing per frame);
    ``"full"``: the whole field every frame."""
    speed_max: float = 0.25
    """Speed [m/s] of the push on a point ``standoff`` from a flat wall (``repulsion_gain`` 1)."""
    standoff: float = 0.10
    """Distance [m] from a flat wall at which a point on the arm is pushed at ``speed_max``."""
    repulsion_gain: float = 2.0
    """Multiplier [-] of the gain derived from ``standoff``; 0 tracks the path alone."""
    control_point_spacing: float = 0.12
    """Largest distance between control points along a link [m] (automatic placement)."""
    control_points: Any = None
    """Per-link override of the automatic placement, as in ``matrix-field``."""

    def __post_init__(self) -> None:
        for name in ("plan_checks_per_tick", "plan_check_budget", "octree_cells"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidConfigError(f"{name} must be an integer >= 1, got {v!r}")
        v = self.goal_fringe
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise InvalidConfigError(f"goal_fringe must be an integer >= 0, got {v!r}")
        for name in (
            "plan_range",
            "motion_resolution",
            "check_resolution",
            "goal_block_time",
            "replan_lag",
            "velocity_scale",
            "tracking_gain",
            "max_lag",
            "speed_max",
            "standoff",
            "control_point_spacing",
        ):
            check_number(self, name, lambda v: v > 0, "finite and > 0")
        check_number(self, "velocity_scale", lambda v: v <= 1, "in (0, 1]")
        check_number(self, "slice_cpu_share", lambda v: 0 <= v < 1, "in [0, 1)")
        check_number(self, "goal_fade", lambda v: v >= 0, "finite and >= 0")
        check_number(self, "repulsion_gain", lambda v: v >= 0, "finite and >= 0")
        for name in ("shorten", "scale_slices", "hold_gives_way"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        self.validate_field()
        self.validate_unknown()
        self.validate_prediction()


class MatrixFieldGuidedController(Controller):
    """``matrix-field-guided`` (module docstring). Settings: :class:`MatrixFieldGuidedControllerConfig`."""

    name = "matrix-field-guided"
    Config = MatrixFieldGuidedControllerConfig

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self.field = GridField(self.config)
        self.repulsion = LiveRepulsion()
        self.predictor = MotionPredictor(self.config) if self.config.prediction != "none" else None

    # --- the controller interface -------------------------------------------------------------------
    def setup(self, task: ControlTask) -> None:
        """Kinematics, control points and limits for ``task`` (untimed)."""
        c = self.config
        if c.tracking_gain * task.period > 1:
            raise InvalidConfigError(
                f"tracking_gain ({c.tracking_gain:g} 1/s) times the control period ({task.period:g} s) must be "
                "at most 1: a larger gain overshoots the reference in one tick"
            )
        if task.goal.q is None:
            raise InvalidConfigError(
                f"{self.name} plans to a goal configuration, and task {task.id!r} gives a goal pose only"
            )
        robot = task.robot
        self.task = task
        overrides = dict(robot.settings.control_points)
        overrides.update(dict(c.control_points or {}))
        points = place_control_points(robot, c.control_point_spacing, list(overrides.items()))
        kin = ArmKinematics(robot, robot.frame_id(task.goal.pose.frame), points)
        self.arm = ArmRepulsion(robot, kin, self.repulsion)
        self.radii = np.asarray(points.radius, dtype=float)
        self.goal_q = np.array(task.goal.q, dtype=float)
        self.lower = np.asarray(robot.lower, dtype=float)
        self.upper = np.asarray(robot.upper, dtype=float)
        self.qd_max = np.asarray(robot.velocity_limit, dtype=float)
        self.arm.at(np.asarray(task.start, dtype=float))  # first-call costs out of the timed ticks
        body_points(robot, 0.02)  # the arm's body at the sensors' default resolution (depth: cells near it)
        self.field.kernels(0.02)  # and the kernels and gain there (the first frame's otherwise: 5-9 ms)
        # the arm's cells at the goal on the sensor's default grid (the first frame's otherwise: 3-6 ms)
        self.arm_cells = ArmCells(robot, self.goal_q)
        lower, upper = default_bounds(robot, 0.02)
        self.arm_cells.fit_geometry(lower, grid_shape(lower, upper, 0.02), 0.02)
        if self.predictor is not None:
            warm_up(c, self._warm_push)
        # the slices' sizes: a 10 ms tick's, scaled with the period (``scale_slices``)
        self.slice_checks, self.slice_cells, self.scan_parts = c.plan_checks_per_tick, c.octree_cells, SCAN_PARTS
        self.fine = c.scale_slices and task.period < SLICE_PERIOD  # slices cut finer than a 10 ms tick's
        if c.scale_slices:
            scale = task.period / SLICE_PERIOD
            left = max(0.0, task.period - TICK_COST) / (SLICE_PERIOD - TICK_COST)  # of the time a slice may take
            self.slice_checks = max(1, round(c.plan_checks_per_tick * left))
            self.slice_cells = max(MIN_SLICE_CELLS, round(c.octree_cells * scale))
            self.scan_parts = max(SCAN_PARTS, math.ceil(SCAN_PARTS / scale - 1e-9))

    def _warm_push(self, block: OccupancyGrid) -> None:
        source = self.field.repulsion(block, surfaces=False)
        if source is not None:
            source.forces(self.arm.kin)

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        """A new run from ``q``: nothing observed, nothing planned, the arm holding ``q``."""
        self.rng = rng
        self.repulsion.replace(None)
        self.cells = ArmCells(self.task.robot, self.goal_q)  # fitted by the first classification
        self.observation: Observation | None = None
        self.grid: OccupancyGrid | None = None  # the latest grid as ``unknown`` reads it
        self.frame = 0  # frames taken in
        self.fresh = False  # a frame not yet checked against the path
        self.counted: np.ndarray | None = None  # unknown cells read as occupied last frame
        self.goal_cells = GoalCells(
            self.config.goal_block_time, self.config.goal_fringe
        )  # depth: near-goal cells left out or blocking
        self.goal_out: np.ndarray | None = None  # depth: near-goal cells left out (static, or blocking too long)
        self.hold = np.array(q, dtype=float)  # the reference held while there is no path
        self.reference: Reference | None = None
        self.t_ref = 0.0  # [s] along the reference
        self.t_last: float | None = None  # the last step's time [s]
        self.plan_cells: np.ndarray | None = None  # depth: cells the path was planned with (bool, grid)
        self.predicted = np.zeros(0, dtype=np.intp)  # the cells moving clusters sweep (flat, the latest frame's)
        if self.predictor is not None:
            self.predictor.reset()
        self.job: Work | None = None
        self.job_kind = ""
        self.wait_frame = -1  # no plan before a frame newer than this (a plan refused on this one)
        self.frame_turn = False  # fine slices: the step of a turn that took in a frame (no slice then)
        # fine slices: a frame's goal cells, classified on the step after the frame's turn (frame, grid)
        self.goal_cells_due: tuple[Observation, OccupancyGrid] | None = None
        self.blocked_from: np.ndarray | None = None  # depth: the start of the last plan refused for its goal
        self.start_near: tuple[np.ndarray, np.ndarray] | None = None  # depth: a plan's start, cells near the arm there
        self.stats: dict[str, Any] = {
            "plans": 0,
            "paths": 0,
            "restarts": 0,
            "blocked": 0,
            "blocked_near_goal": 0,
            "start_in_collision": 0,
            "replans": {"invalidated": 0, "blocked": 0, "lag": 0},
            "slices": 0,
            "plan_slices": 0,
            "check_slices": 0,
            "max_checks_per_slice": 0,
            "frames": 0,
            "dropped": 0,
            "plan_ticks": [],
            "path_waypoints": [],
            "unknown_cells": 0,
            "predicted_frames": 0,
            "predicted_cells_max": 0,
        }
        self._plan_started = 0
        self._ticks = 0
        self._cpu_until: float | None = None  # with slice_cpu_share: the process CPU time [s] a slice ends at
        self._turn_began: float | None = None  # the process CPU time [s] at this turn's update (None: no frame)

    def update(self, observation: Observation) -> None:
        """Take in a frame: the field's grid (its unknown cells near the arm occupied first, with
        ``unknown = "occupied"``); its checks run in the next steps' slices."""
        self._turn_began = time.process_time()  # this turn's CPU share counts from here
        if self.goal_cells_due is not None:  # two frames without a step between: none goes unclassified
            self._classify_goal_cells(*self.goal_cells_due)
            self.goal_cells_due = None
        self.observation = observation
        self.grid = self._unknown_read(observation)
        surfaces = observation.points is not None and self.grid is observation.grid
        source: Repulsion | None = self.field.repulsion(self.grid, surfaces=surfaces)
        if self.predictor is not None:
            self.predicted = self.predictor.observe(observation).cells
            block = predicted_grid(observation.grid, self.predicted)
            extra = None if block is None else self.field.repulsion(block, surfaces=False)
            if extra is not None:
                source = SummedRepulsion(source, extra)
                self.stats["predicted_frames"] += 1
                self.stats["predicted_cells_max"] = max(self.stats["predicted_cells_max"], len(self.predicted))
        self.repulsion.replace(source)
        self.frame += 1
        self.stats["frames"] += 1
        self.fresh = True
        self.frame_turn = self.fine  # fine slices: this turn carries the update, its step no slice
        if observation.scene is None:
            # the goal's cells are a plan's bookkeeping, not the field's: classified by a step (the
            # next one with fine slices, this turn's otherwise), charged there
            self.goal_cells_due = (observation, self.grid)

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        """The tracking law from ``q`` [rad] (module docstring) after at most one slice of work."""
        q = np.asarray(q, dtype=float)
        self._ticks += 1
        began, self._turn_began = self._turn_began, None
        busy = began is not None  # this turn took in a frame
        if self.config.slice_cpu_share > 0:  # the turn's share: from its update, when it took in a frame
            began = time.process_time() if began is None else began
            self._cpu_until = began + self.config.slice_cpu_share * self.task.period
        if self.frame_turn:
            self.frame_turn = False
            return self._command(t, q)  # the frame's update is this turn's work
        if self.goal_cells_due is not None:
            frame, grid = self.goal_cells_due
            self.goal_cells_due = None
            self._classify_goal_cells(frame, grid)
            if self.fine:
                return self._command(t, q)  # no slice of work on this tick
            busy = True
        # a turn that did other work runs a slice only while its share lasts; any other runs one
        # (of one check at least), so the work always goes on
        if self.grid is not None and not (busy and self._cpu_spent()):
            self._work(q)
        return self._command(t, q)

    def info(self) -> dict[str, Any]:
        """Counts of the run: plans started (``plans``), paths found (``paths``), queries restarted,
        plans refused with the goal (``blocked``; ``blocked_near_goal`` of them against the cells near
        the goal only) or the start in collision, replans by why, work
        slices (planning, path checks) and the most checks one made, frames, cells or obstacles
        left out where the arm touched them, ticks from each plan's start to its path, waypoints of
        each path, unknown cells read as occupied in the last frame."""
        out = dict(self.stats)
        out["replans"] = dict(self.stats["replans"])
        out["plan_ticks"] = list(self.stats["plan_ticks"])
        out["path_waypoints"] = list(self.stats["path_waypoints"])
        out["tracking"] = self.reference is not None
        return out

    # --- work: one slice per tick ---------------------------------------------------------------------
    def _work(self, q: np.ndarray) -> None:
        """Start the job due (a plan while holding, a check of the latest frame while tracking,
        when the last check is done) and run one slice of the current job."""
        if self.job is None:
            if self.reference is None and self.frame > self.wait_frame:
                self.job, self.job_kind = self._plan(), "plan"
                self._plan_started = self._ticks
                self.stats["plans"] += 1
            elif self.reference is not None and self.fresh:
                self.fresh = False
                self.job, self.job_kind = self._check(q), "check"
            else:
                return
        self.stats["slices"] += 1
        self.stats[f"{self.job_kind}_slices"] += 1
        try:
            next(self.job)
        except StopIteration:
            self.job = None

    def _count(self, checks: int) -> None:
        self.stats["max_checks_per_slice"] = max(self.stats["max_checks_per_slice"], int(checks))

    def _plan(self) -> Work:
        """A plan from the held configuration (module docstring), a slice per ``yield``."""
        start, frame, c = self.hold.copy(), self.frame, self.config
        if (yield from self._goal_still_blocked(start)):
            self.stats["blocked"] += 1
            self.stats["blocked_near_goal"] += 1
            self.wait_frame = frame
            return
        checker = yield from self._planning_checker(start)
        if checker.in_collision(self.goal_q):
            self.stats["blocked"] += 1
            self.wait_frame = frame
            self.blocked_from = start
            return
        self.blocked_from = None
        yield from self._pause()  # a new checker's first queries cost 0.2 ms each
        if checker.in_collision(start):
            self.stats["start_in_collision"] += 1
            self.wait_frame = frame
            return
        seed = int(self.rng.integers(1, 2**31 - 1))
        query = SlicedRRTConnect(
            checker,
            start,
            self.goal_q,
            seed=seed,
            extension=c.plan_range,
            resolution=c.motion_resolution,
            shorten=c.shorten,
            exact=True,
        )
        yield
        while True:
            before = query.checks
            done = query.advance(self.slice_checks, self._cpu_until)
            self._count(query.checks - before)
            if done:
                break
            if query.path is None and (query.checks >= c.plan_check_budget or query.failed):
                query.close()
                self.stats["restarts"] += 1
                return  # the next job starts again, on the latest frame
            yield
        assert query.path is not None
        self.reference = Reference(query.path, c.velocity_scale * self.qd_max)
        self.t_ref = 0.0
        self.stats["paths"] += 1
        self.stats["plan_ticks"].append(self._ticks - self._plan_started + 1)
        self.stats["path_waypoints"].append(len(query.path))
        self.fresh = self.frame > frame  # frames came while it planned: check the path on the latest

    def _planning_checker(self, start: np.ndarray) -> Generator[None, None, CollisionChecker]:
        """The checker a plan from ``start`` uses, built over slices (module docstring). No frame's
        arrays are held across a slice: a frame's stay as delivered for three more frames only."""
        robot = self.task.robot
        scene = self.observation.scene if self.observation is not None else None
        if scene is not None:  # truth: the scene less what the arm at the start touches
            _, checker, dropped = yield from self._in_steps(scene_without_touched_in_steps(robot, scene, start))
            del scene
            self.stats["dropped"] += dropped
            self.plan_cells = None
            yield
            return checker
        occupied = yield from self._occupied()
        self.plan_cells = np.zeros(self.cells.size, dtype=bool)
        self.plan_cells[occupied] = True
        yield
        kept, close = yield from self._near_cells(occupied, start)
        yield
        if len(close):
            kept = self._without_touched(kept, close, start, None)
            yield
        checker = yield from self._cells_checker(kept, pause_after_last=True)
        yield
        return checker

    def _cells_checker(self, cells: np.ndarray, pause_after_last: bool) -> Generator[None, None, CollisionChecker]:
        """Depth: a checker of ``cells`` (flat indices), built over slices: an octree of at most
        :attr:`slice_cells` cells a slice (one of 4,000 costs 2-4 ms; one of every cell a frame
        added could cost several times that in one tick), then their checker, in the last octree's
        slice unless ``pause_after_last`` (a plan's checker of many octrees gets a slice of its own)."""
        pieces = []
        for k in range(0, len(cells), self.slice_cells):
            if k:
                yield
            assert self.grid is not None  # the latest frame's: every frame has the same cells
            pieces.append(cells_octree(self.grid, cells[k : k + self.slice_cells], f"cells-{k}"))
        if pause_after_last and pieces:
            yield
        return (yield from self._in_steps(pieces_checker_in_steps(self.task.robot, pieces)))

    def _pause(self) -> Generator[None, None, None]:
        """A slice boundary only where slices are finer than a 10 ms tick's (``scale_slices``
        with a shorter period): work that a 10 ms tick takes in one piece is cut there at 1 kHz."""
        if self.fine:
            yield

    def _in_steps(self, steps: Generator[None, None, R]) -> Generator[None, None, R]:
        """``steps`` (a job built in steps) a slice each where slices are fine, else in one."""
        if self.fine:
            return (yield from steps)
        return finished(steps)

    def _goal_still_blocked(self, start: np.ndarray) -> Generator[None, None, bool]:
        """Depth, while the arm holds where the last plan was refused for its goal: whether the goal
        is in collision with the occupied cells near the arm's body there (the cells it can touch),
        left-out cells aside. A goal that stays blocked then costs an octree of those cells and a
        small checker per frame instead of the plan's whole geometry (about 3 ms on the Panda).
        It only says "blocked" where the plan would: its cells are among the plan's, unless the arm
        at the start is within a cell of one of them (the plan leaves out cells the arm touches),
        and then the plan decides."""
        if self.blocked_from is None or not np.array_equal(self.blocked_from, start) or self.grid is None:
            return False
        near = self.cells.near_goal
        blocking = np.asarray(self.grid.data).reshape(-1)[near] >= 0.5
        if self.goal_out is not None and len(self.goal_out) == len(near):
            blocking &= ~self.goal_out
        cells = near[blocking]
        start_near = self.start_near
        if (
            not len(cells)
            or start_near is None
            or not np.array_equal(start_near[0], start)
            or np.isin(cells, start_near[1], kind="table").any()
        ):
            return False
        octree = cells_octree(self.grid, cells, "near-goal")
        yield from self._pause()
        checker = yield from self._in_steps(pieces_checker_in_steps(self.task.robot, [octree]))
        yield from self._pause()
        return checker.in_collision(self.goal_q)

    def _occupied(self) -> Generator[None, None, np.ndarray]:
        """Depth: the flat indices of the occupied cells of the latest grid, found in
        :attr:`scan_parts` slices (a pass over a 142^3 grid costs 2-4 ms; a part is read from the
        grid latest when its slice runs)."""
        assert self.grid is not None
        self.cells.fit(self.grid)
        bounds = np.linspace(0, self.cells.size, self.scan_parts + 1).astype(np.intp)
        found = []
        for k, (a, b) in enumerate(itertools.pairwise(bounds)):
            if k:
                yield
            assert self.grid is not None
            found.append(a + np.flatnonzero(np.asarray(self.grid.data).reshape(-1)[a:b] >= 0.5))
        if len(self.predicted):  # the cells moving clusters sweep are obstacles of plans and checks
            return np.union1d(np.concatenate(found), self.predicted)
        return np.concatenate(found)

    def _near_cells(self, cells: np.ndarray, q: np.ndarray) -> Generator[None, None, tuple[np.ndarray, np.ndarray]]:
        """Depth: ``cells`` (flat indices) less the cells near the goal left out (module docstring),
        and those of them within a cell of the arm's body at ``q``; up to three slices (the arm's
        cells and those around them cost about 0.45 and 0.4 ms on the Panda). Lookups by table
        (``np.isin``'s ``kind="table"``: 0.04 ms where sorting takes 0.7 ms on 7,000 cells)."""
        if self.goal_out is not None and self.goal_out.any():
            cells = cells[~np.isin(cells, self.cells.near_goal[self.goal_out], kind="table")]
            yield from self._pause()
        assert self.cells.body is not None
        arm = self.cells.body.cells(q)
        yield from self._pause()
        near = self.cells.around(arm, 1)
        self.start_near = (np.array(q, dtype=float), near)
        return cells, cells[np.isin(cells, near, kind="table")]

    def _without_touched(
        self, cells: np.ndarray, close: np.ndarray, q: np.ndarray, checker: CollisionChecker | None
    ) -> np.ndarray:
        """Depth: ``cells`` less ``close`` (those within a cell of the arm's body at ``q``) when
        the arm there touches them (``checker``: of ``cells``, else one of ``close`` is built);
        counted in ``dropped``."""
        if checker is None:
            assert self.grid is not None
            checker = pieces_checker(self.task.robot, [cells_octree(self.grid, close)])
        if not checker.in_collision(q):
            return cells
        self.stats["dropped"] += len(close)
        return cells[~np.isin(cells, close, kind="table")]

    def _classify_goal_cells(self, observation: Observation, grid: OccupancyGrid) -> None:
        """Depth: which cells near the arm's body at the goal are left out of plans and checks
        (:attr:`goal_out`, :class:`.observed.GoalCells`)."""
        if self.cells.body is None:  # the run's first: the cells fitted in setup (refitted if on another grid)
            self.cells = self.arm_cells
        self.cells.fit(grid)
        self.goal_out = self.goal_cells.classify(observation.time, grid, self.cells.near_goal)

    def _check(self, q: np.ndarray) -> Work:
        """The rest of the path against the latest frame, a slice per ``yield``; drops the path at
        the first configuration in collision (``blocked`` when that is the goal, else
        ``invalidated``)."""
        robot = self.task.robot
        scene = self.observation.scene if self.observation is not None else None
        if scene is not None:
            _, checker, dropped = yield from self._in_steps(scene_without_touched_in_steps(robot, scene, q))
            del scene
            self.stats["dropped"] += dropped
        else:
            occupied = yield from self._occupied()
            if self.plan_cells is not None:
                occupied = occupied[~self.plan_cells[occupied]]  # the plan's own cells: its path is free of them
            yield
            new, close = yield from self._near_cells(occupied, q)
            if not len(new):
                return
            yield
            checker = yield from self._cells_checker(new, pause_after_last=False)
            if len(close):
                kept = self._without_touched(new, close, q, checker)
                if len(kept) < len(new):
                    if not len(kept):
                        return
                    yield
                    checker = yield from self._cells_checker(kept, pause_after_last=False)
        yield
        rest = self._rest()
        k = 0
        while k < len(rest):
            made = 0  # a slice: up to ``slice_checks`` configurations, ended early by the tick's CPU time
            while k < len(rest) and made < self.slice_checks and (made == 0 or not self._cpu_spent()):
                made += 1
                if checker.in_collision(rest[k]):
                    self._count(made)
                    self._drop_path("blocked" if k == len(rest) - 1 else "invalidated", stop_job=False)
                    return
                k += 1
            self._count(made)
            if k < len(rest):
                yield

    def _cpu_spent(self) -> bool:
        """Whether this tick's share of CPU time (``slice_cpu_share``) has run out."""
        return self._cpu_until is not None and time.process_time() >= self._cpu_until

    def _rest(self) -> list[np.ndarray]:
        """The configurations at which the rest of the path is checked: from the reference's
        configuration now, every ``check_resolution`` rad (largest joint motion) along it."""
        ref = self.reference
        assert ref is not None
        here = ref.at(self.t_ref)[0]
        ends = np.vstack([here, ref.waypoints[1:][np.cumsum(ref.durations) > self.t_ref]])
        out = [here]
        for a, b in zip(ends[:-1], ends[1:], strict=True):
            n = max(1, math.ceil(float(np.max(np.abs(b - a))) / self.config.check_resolution))
            out.extend(a + u * (b - a) for u in np.arange(1, n + 1) / n)
        return out

    def _drop_path(self, why: str, hold: np.ndarray | None = None, stop_job: bool = True) -> None:
        """Stop tracking: hold the reference's configuration now (or ``hold``) and plan again;
        ``stop_job``: end the job under way (not when that job is the caller)."""
        if self.reference is not None:
            self.hold = self.reference.at(self.t_ref)[0].copy() if hold is None else np.array(hold, dtype=float)
        self.reference = None
        self.stats["replans"][why] += 1
        if stop_job and self.job is not None:
            self.job.close()
            self.job = None

    # --- control ------------------------------------------------------------------------------------------
    def _command(self, t: float, q: np.ndarray) -> np.ndarray:
        """The tracking law (module docstring) toward the reference, or the held configuration."""
        c, period = self.config, self.task.period
        late = 1 if self.t_last is None else max(1, round((t - self.t_last) / period))
        self.t_last = t
        ref = self.reference
        if ref is not None:
            for _ in range(late - 1):  # a late tick: the held command moved the arm on meanwhile
                self.t_ref = ref.next_time(self.t_ref, period)
            r, _, remaining = ref.at(self.t_ref)
            lag = float(np.max(np.abs(q - r)))
            if lag > c.replan_lag:
                self._drop_path("lag", hold=q)
                ref = None
        if ref is not None:
            t_next = ref.next_time(self.t_ref, period)
            r_next = ref.at(t_next)[0]
            w = push_weight(lag, c.max_lag, remaining, c.goal_fade)
            self.t_ref = t_next
        else:
            r = r_next = self.hold
            w = push_weight(float(np.max(np.abs(q - r))), c.max_lag, 1.0, 0.0)  # no goal fade while holding
        push = None
        if w > 0 and c.repulsion_gain > 0 and self.grid is not None:
            points, F, support, _ = self.arm.at(q)
            push = w * T.repulsion_joint_velocity(self.arm.kin.S, points, F, support)
            if ref is None and c.hold_gives_way and np.any(push):
                # holding: the hold gives way to the push (an obstacle coming at the arm drives it
                # back); with no push the arm stays where it was driven
                r = r_next = self.hold = q.copy()
        else:
            self.arm.kin.update(q)  # where the arm is: the unknown cells near it are read there
        return tracking_velocity(q, r, r_next, period, c.tracking_gain, push, self.qd_max, self.lower, self.upper)

    def _unknown_read(self, observation: Observation) -> OccupancyGrid:
        """The frame's grid as ``unknown`` reads it: itself with ``"free"`` or when every cell is
        known, else with the unknown cells near the arm (where the last step left it) occupied."""
        c, grid = self.config, observation.grid
        if c.unknown == "free" or grid.known is None:
            return grid
        arm = (self.arm.kin.points, self.radii)
        cells = near_unknown(grid, [arm], c.unknown_reach, c.unknown_self_margin, self.counted)
        self.counted = cells
        self.stats["unknown_cells"] = 0 if cells is None else int(np.count_nonzero(cells))
        return unknown_as_occupied(grid, cells)
