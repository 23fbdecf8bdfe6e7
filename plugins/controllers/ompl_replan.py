"""``ompl-replan``: a global sampling planner on the latest observation, a path follower, and a
replan whenever the path it follows becomes invalid.

This is how a sampling planner is deployed in a changing scene, and the comparator the reactive
methods must beat: RRT-Connect (any registered static planner, ``planner``) plans from the arm's
configuration to the goal in the observed scene: the exact geometry with ``truth`` sensing, the
occupied cells with ``depth`` sensing (whole cells, as one coal octree when the planner takes a
checker, :meth:`~planbench_plugins.ompl_planners.base.OMPLPlanner.use_checker`, else as boxes;
``cell_inset`` shrinks the boxes). The obstacles the arm already touches where a plan starts are
left out of that plan and of the path's checks (truth: whole obstacles; depth: the occupied cells
within a cell of the arm's body, and of its body at the goal, which the static scene leaves free:
observed cells lie up to a cell beyond the true surface, so an arm a centimetre from a table can be
"in" its cells; but at the goal, by default (``goal_obstacles = "appeared"``), the cells that a
frame saw free and that are occupied since are an obstacle standing on the goal, kept for up to
``goal_block_time``: no plan reaches the goal, the refused plans relax nothing, and the arm waits
until it leaves, ``goal_blocked`` in ``info``). The follower
moves along the path at ``speed_scale`` of every joint's velocity limit. On every new frame the
rest of the path is checked against the new observation every ``check_resolution`` rad (with
depth sensing, after the first frame on a path, only against the cells no earlier check of it held,
and only where the boxes around the links reach them: :meth:`OMPLReplanController._rest_collides`);
when it collides, the controller commands a stop in that tick and
replans in the next, so that the command the runner holds while the planning time is charged (as
on a robot) is the stop, not the old path's velocity. A failed plan leaves the arm
still until the next frame. A plan's time limits count the CPU time that is charged
(``plan_clock = "cpu"``), so a loaded machine gives a plan as much work as an idle one.

**Safe mode** (``unknown = "occupied"``, the default, chosen on ``dynamic-tune``; ``"free"`` plans and
follows through unknown cells as through free ones; :class:`~.unknown.UnknownSettings`):
plan optimistically, enter unknown space only where there is no other way, and look first (as
FASTER does for quadrotors: the plan may cross unknown space, the committed motion may not):

- **hidden surfaces**: the unknown cells within ``surface_margin`` of an occupied cell are the
  unseen rest of a seen surface (the far side of a plate seen from above, an edge seen edge-on):
  obstacles for every plan, never entered after a look (below); found when a plan needs them, as
  a frame's check of the rest of the path stops short of every unknown cell anyway. When plans
  fail (``relax_after`` in a row), the margin is relaxed a step toward 0 (``relax_steps``), for
  the rest of the run: on a cluttered shelf the unseen rest of boards and cans can leave no plan,
  and the arm stood still to the horizon; at margin 0 those cells are unknown like any other
  (stopped short of, looked at, then entered). A dead end (after its looks every unknown cell in
  the way is such a cell) waits, or replans (``dead_end``), and relaxes nothing;
- **known space first**: a plan is made as the default does; if its path fills a cell the arm may
  not enter (below), the arm plans again with every such cell an obstacle (the occupied cells and
  the two-cell layer of unknown ones next to the space the arm may enter stand for them all: any
  motion into the rest crosses that layer). That plan, and the plan to the goal, are made at once
  (within ``known_plan_time`` and ``plan_time``, the arm held still) unless an obstacle tracked
  near the arm could reach it meanwhile (``known_sliced_when``, ``plan_sliced_when``:
  ``"contact"`` by default); then they run in slices of the tick's CPU time
  (``known_checks_per_tick``, ``known_cpu_share``), ``known_plan_time`` and ``plan_time`` of CPU
  in all, while the arm follows the first path up to the unknown cells, or stands and reads every
  frame (the plan to the goal), ready to retreat (measured on ``dynamic-tune`` and
  ``dynamic-test``, docs/reactive.md).
  When a sliced plan has a path and the first path still enters cells the arm may not enter, the
  arm goes straight to the farthest of its waypoints that a free motion reaches (else back the way
  it came); while the plan runs, the arm waits short of unknown cells instead of going in after
  its looks (going in meanwhile took it into the unseen cap of ``mbm:box``);
- **stop short, look, go on**: on every frame the next ``scan_horizon`` seconds of the path are
  scanned with the arm's body (:class:`~planbench.reactive.body.ArmBody`, the cells the
  ``unobserved_motion`` metric counts) at fixed times along the path; the follower stops
  ``lookahead`` seconds of motion short of the first configuration that fills a cell the frame
  does not know (the runner stops a command at once: the margin covers the scan's spacing and a
  command held while a frame is checked). Held there for ``look_frames`` new frames (the map may
  fill the cells in meanwhile, and a path through what it shows is replanned), the arm goes into
  the unknown cells its body fills over the next ``scan_horizon`` (``forced`` in ``info``).

**Prediction** (depth; ``prediction``, :class:`~.prediction.PredictionSettings`): with
``"swept"`` the cells the moving clusters of the frames sweep over ``prediction_horizon`` (from
:class:`~.prediction.MotionPredictor`, one ``observe`` per frame, charged) are obstacles of the
frame's check of the rest of the path and of its plans, as occupied cells are: a tracked obstacle
heading across the path drops it (a stop, then a plan around the sweep) before its own cells reach
it. A plan that fails while cells are swept does not count toward relaxing the surface margin.
With truth sensing the scene's exact geometry is checked as it is. Off by default: on the 24 fast
depth scenarios of ``dynamic-tune`` it solved 15 against 19 without (docs/reactive.md, "Prediction
in ompl-replan"): the frames reach the predictor too sparsely while plans are charged for a track
to form in most runs, and the differences were mostly in runs where it predicted nothing.

**Getting out of the way** (``evade``, :class:`~.evade.EvadeSettings`; with either sensing): with
``"retreat"`` (the default since 2026-11-27, chosen on ``dynamic-tune``), on every frame the
cells of obstacles that came in lately (the predictor's moving clusters, and what its tracks
sweep) within ``evade_distance`` of the arm's body (the parts a joint moves) make it retreat,
unless its path leads well away from them (twice that distance within ``scan_horizon``): a
short straight joint motion, at the full velocity limits, to where the body is farthest from them
(:func:`~.evade.retreat`), checked against every occupied cell (truth: the frame's scene) and
the arm itself. A retreat is worked out only where the arm stands: a moving arm is stopped in the
tick the threat is found and retreats in the next, as a plan waits for a stop (the runner holds
the last command while either is computed). With truth sensing the frame's voxelised grid is
what the predictor reads.
Once no such cell is that close, or the retreat's end is reached, it plans to the goal again.
Standing still while a plan is refused or the path is blocked is safe from a static scene, not
from a box on its way through the arm.

The arm may always enter the unknown cells within ``start_margin`` of its body where the run
started (the sensor's robot filter blinds it there, so they are never seen until the arm has
moved) and at the goal (which the task asserts free). With ``arm_shadow``, when a new path enters
unknown cells, those of them that the arm's own body hides from a camera (the task's cameras,
:mod:`planbench.reactive.shadows`; never those within the surface margin of an occupied cell) may
be entered too, before the plan in known space is asked for: a look from a standstill never shows
them, and moving the arm does.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid, grow_cells
from planbench.planner import PlanStatus
from planbench.problem import Goal, Problem
from planbench.reactive.body import ArmBody, body_points
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.reactive.shadows import ARM, SURFACE, occluders
from planbench.registry import REGISTRY
from planbench.scene import Scene
from planbench_plugins.controllers.cells import cell_boxes
from planbench_plugins.controllers.evade import ArmSamples, EvadeSettings, Threat, retreat
from planbench_plugins.controllers.observed import ArmCells, GoalCells, LinkBoxes, PathBoxes, scene_without_touched
from planbench_plugins.controllers.prediction import MotionPredictor, PredictionSettings, Track, warm_up
from planbench_plugins.controllers.unknown import UnknownSettings
from planbench_plugins.ompl_planners import SlicedRRTConnect, cells_checker

__all__ = ["OMPLReplanConfig", "OMPLReplanController"]


@dataclass(frozen=True)
class OMPLReplanConfig(UnknownSettings, PredictionSettings, EvadeSettings):
    """Settings of ``ompl-replan``. ``unknown = "occupied"`` is its safe mode (module docstring):
    plan optimistically, move only into cells an observation knows."""

    unknown: str = "occupied"
    """``"occupied"``: the safe mode (module docstring), the default: on the 24 fast depth
    scenarios of ``dynamic-tune`` it solved 22 (the same as with truth sensing) where ``"free"``
    solved 20 (docs/reactive.md, "Unknown space"); ``"free"``: unknown cells are free."""
    planner: str = "ompl-rrtconnect"
    """The registered static planner that (re)plans."""
    plan_time: float = 1.0
    """Time limit of one (re)plan [s]."""
    plan_clock: str = "cpu"
    """What ``plan_time`` and ``known_plan_time`` count: ``"cpu"`` (the default), this process's
    CPU time, which is what the closed loop charges, so a plan gets the same compute on a loaded
    machine as on an idle one; ``"wall"``, elapsed time (before 2026-11-27: a plan on a machine
    shared by two benchmark jobs got less work done, and verdicts moved with the load). Sets the
    planner's ``clock`` (the OMPL planners have it; a planner without it needs ``"wall"``)."""
    known_plan_time: float = 0.5
    """Safe mode: time limit [s] of the plan in known space, made when a plan's path enters cells
    the arm may not enter (with ``known_checks_per_tick`` 0: the plan is made at once, the arm
    held still meanwhile)."""
    known_plan_at: str = "start"
    """Safe mode, when the plan in known space is made at once (``known_checks_per_tick`` 0, or
    ``known_sliced_when`` finds no threat in reach): when it is made.
    ``"start"``: at once after the optimistic plan whose path enters cells the arm may not enter,
    the arm held still meanwhile; ``"stop"``: only when the follower, stopped short of such cells,
    has looked ``look_frames`` frames and the cells are still unknown, before it would go into
    them. With ``"stop"`` the arm sets off along the optimistic path at once (as with truth
    sensing), and a stretch of unknown cells that the frames on the way show (the shadow of a
    moving obstacle moves on) costs no plan at all."""
    known_checks_per_tick: int = 2000
    """Safe mode: 0, the plan in known space is made at once, the arm held still for up to
    ``known_plan_time``; > 0: in slices of at most this many collision checks, one slice per tick
    (50: about 3-6 ms, 60-110 µs a check on a loaded 2-core machine; the default 2000 with
    ``known_cpu_share`` 0.9: as many as fit in the tick), while the arm follows the optimistic path
    up to the unknown cells (:mod:`planbench_plugins.ompl_planners.sliced`), when
    ``known_sliced_when`` says so. 0 needs ``plan_sliced_when = "never"``. Default since
    2026-12-04 with the ``"contact"`` rules (docs/reactive.md, "A threat from its tracked
    speed"): on ``dynamic-tune`` 61 of 72 and no collision with an observed obstacle, against 64
    with one for the plan at once; on ``dynamic-test`` 128 of 144 with none."""
    known_sliced_when: str = "contact"
    """Safe mode, with ``known_checks_per_tick`` > 0: ``"always"``, every plan in known space runs
    in slices; ``"threat"``, in slices only while standing still may not be safe: before the
    arm has had two frames (no obstacle's motion can be told from one) or while a cell of an
    obstacle that came in lately (``evade``'s threat) lies within ``known_hold_distance`` of the
    arm's body; otherwise it is made at once, the arm held still. ``"contact"`` (the default): as
    ``"threat"``, but a tracked obstacle counts only within what its speed covers in ``hold_time``
    (plus ``evade_distance``). Obstacles are tracked for it with ``evade = "none"`` too."""
    plan_sliced_when: str = "contact"
    """The plan to the goal (the optimistic one): ``"never"``, made at once, the arm held still for
    up to ``plan_time``; ``"threat"``, in slices (``known_checks_per_tick`` checks,
    with ``known_cpu_share`` of each tick's CPU; ``plan_time`` of CPU in all, or
    ``known_plan_checks`` checks without a share) while standing still may not be safe, as
    ``known_sliced_when`` tells it (``"contact"``: as ``known_sliced_when = "contact"``): the arm
    stands meanwhile, every frame is read and a threat
    within ``evade_distance`` makes it retreat (the plan dropped). A plan made at once blinds the
    arm for its whole time: a forearm swinging back 7 cm from the Panda's start reached it while it
    planned (``panda_swinging_fast/0003``, docs/reactive.md); with ``evade = "none"`` it only
    reads the frames. Needs ``known_checks_per_tick`` > 0; a pose goal is planned at once.
    Measured on ``dynamic-tune`` with ``"threat"``: 54 of 72 against 64 made at once (plans
    dropped and late where something always moves near the arm); ``"contact"`` (the default, see
    ``known_checks_per_tick``) slices only where a tracked obstacle could arrive while the arm is
    held."""
    known_hold_distance: float = 0.5
    """Safe mode, ``known_sliced_when = "threat"``: [m] the distance from the arm's body within
    which a threat's cell makes the plan in known space run in slices (0.5 m: what an obstacle at
    1 m/s, the fast scenarios' peak speed, covers in ``known_plan_time``'s 0.5 s). With
    ``"contact"``, only for moving cells whose track has no trusted velocity yet."""
    hold_time: float = 1.5
    """``"contact"`` (``known_sliced_when``, ``plan_sliced_when``): [s] how long a plan made at once
    may hold the arm still (1.5 s: ``plan_time`` and then ``known_plan_time``; with 0.5 s a
    forearm tracked beyond reach came back during the two plans in 3 of 5 seeds of
    ``panda_swinging_fast/0003``). A tracked obstacle makes the plan run in slices when it is
    within what its tracked speed covers in this time, plus ``evade_distance``, of the arm's body:
    a slow one near the arm leaves the plan made at once, a fast one farther off does not."""
    known_plan_checks: int = 10000
    """Safe mode: the most collision checks of a sliced plan in known space (its budget: about
    0.5-1 s of work, spread over 200 ticks), with ``known_cpu_share`` 0; with a share, the budget is
    ``known_plan_time`` of CPU time, the plan made at once's."""
    known_cpu_share: float = 0.9
    """Safe mode, with ``known_checks_per_tick`` > 0: 0, a slice ends by its count alone; in
    (0, 1) (the default 0.9), a slice also ends at the first check after the tick has used this
    share of the control period in CPU time, its frame's work included (the search then runs on a thread of
    its own, paused between slices: :class:`~planbench_plugins.ompl_planners.SlicedRRTConnect`
    with ``exact``). With a large count it spreads the work of the plan made at once over the
    fewest ticks that keep each within the period, while the arm moves."""
    speed_scale: float = 0.5
    """Speed along the path, as a fraction of each joint's velocity limit (0, 1]."""
    check_resolution: float = 0.02
    """Spacing of the configurations at which the rest of the path is checked on a new frame [rad]."""
    cell_inset: float = 0.0
    """How far each box of observed cells is shrunk on each side, in cells [0, 0.5): 0 plans
    around whole cells (the grid's ``"any"`` rule: conservative); measured on the ``dynamic``
    suite, an inset of a quarter cell let the follower's fingers touch the tables it planned next to."""
    lookahead: float = 0.05
    """Safe mode: [s] of motion along the path (at ``speed_scale``) the follower keeps between the
    arm and the first configuration that fills an unknown cell (more than ``check_resolution``)."""
    scan_horizon: float = 0.5
    """Safe mode: [s] of the path ahead of the arm scanned for unknown cells on each frame; the
    stretch entered at once after a look."""
    look_frames: int = 3
    """Safe mode: new frames the arm waits, stopped short of unknown cells, before it goes on into
    them (the map may fill them in meanwhile; a path through what it shows is replanned)."""
    surface_margin: float = 0.04
    """Safe mode: [m] unknown cells within this of an occupied cell (centre to centre) are the
    unseen rest of a seen surface (the far side of a plate seen from above, the edge seen
    edge-on): obstacles for a plan, and never entered, even where no plan avoids other unknown cells."""
    relax_steps: int = 2
    """Safe mode: how many steps ``surface_margin`` is relaxed in, toward 0, when plans fail (0:
    never). After ``relax_after`` failures in a row the margin drops by ``surface_margin /
    relax_steps``, for the rest of the run: on the Panda's tall bookshelf the unseen rest of the
    boards and cans can leave no plan under the full margin, and the arm stood still to the
    horizon. Only a plan without a path counts, not a dead end (``dead_end``: relaxing there took
    the Panda into the unseen cap of ``mbm:box`` on ``dynamic-tune``). At margin 0 the hidden
    cells are unknown cells like any other: the arm stops short of them and looks before it goes
    in (``look_frames``). Chosen on ``dynamic-tune`` (docs/reactive.md, "Relaxing the surface
    margin")."""
    dead_end: str = "wait"
    """Safe mode: what the arm does at a dead end, where after its looks every unknown cell in its
    way is the unseen rest of a surface (``surface_margin``; a frame since the plan showed more of
    it), counted in ``stuck``: ``"wait"`` (the default) stays short of them, looking, and goes on
    if a frame shows them; ``"replan"`` drops the path and plans around them. On the Panda's 24
    depth scenarios of ``dynamic-tune`` ``"replan"`` turned the three ``occluded`` runs that ended
    short of the goal into collisions with the box's side, which a frame had shown
    (docs/reactive.md)."""
    relax_after: int = 1
    """Safe mode: failed plans in a row before ``surface_margin`` is relaxed by one step (>= 1)."""
    gate: bool = True
    """Safe mode: plan in known space first and stop short of unknown cells on a path that enters
    them (else only the hidden cells next to occupied ones, ``surface_margin``, are kept out of)."""
    goal_obstacles: str = "appeared"
    """Depth: what occupied cells on the goal are (those within a cell of the arm's body there):
    ``"appeared"`` (the default) keeps the cells that a frame saw free and that are occupied since,
    for at most ``goal_block_time`` (:class:`~.observed.GoalCells`, as ``matrix-field-guided``
    does): an obstacle standing on the goal, which no plan reaches and the arm waits out; it leaves
    out those occupied when first seen (the static scene a grasp touches) and the unknown ones;
    ``"ignore"`` leaves them all out, as a surface the goal touches; ``"wait"`` keeps them when more
    than a contact's few of the cells the body fills at the goal are occupied, until they are seen
    free again. On the 72 depth scenarios of ``dynamic-tune`` (2026-11-27) ``"appeared"`` solved 60
    and ``"ignore"`` 58 (paired 5 against 3; ``blocking`` 8/9 against 5/9), with 4 collisions
    against 11; ``"wait"`` lost 6 of 25 runs ``"ignore"`` solved earlier: cells a moving obstacle
    leaves at the goal where no camera sees stay in the map (docs/reactive.md)."""
    goal_block_time: float = 6.0
    """[s] Depth, ``goal_obstacles = "appeared"``: how long cells that appeared on the goal block
    it at most (then they are taken for what the map keeps where no ray passes, and left out)."""
    goal_fringe: int = 0
    """[cells] Depth: an occupied cell near the goal within this many cells of one that was
    occupied when first seen is taken for that static surface and left out, however it flickered
    (:class:`~.observed.GoalCells`); 0 (the default): only the first sight decides. 1 ended a
    flickering can's blocks of the goal in a traced run, and was not better in benchmark runs
    (docs/reactive.md, "A flickering shelf blocked the goal")."""
    start_margin: float = 0.04
    """Safe mode: [m] unknown cells within this of the arm's body where the run starts (rounded up
    to whole cells) may be entered: the sensor's robot filter blinds it within ``robot_margin``
    (0.03 m) of the arm, so these are never seen until the arm has moved; the same at the goal."""

    arm_shadow: bool = False
    """Safe mode, depth: a path's unknown cells that the arm's own body hides from a camera (the
    line of sight from the camera, :attr:`~planbench.reactive.controller.ControlTask.cameras`, meets
    the arm before any occupied cell; :mod:`planbench.reactive.shadows`) may be entered without a
    plan in known space or a look, as the cells near the start may (``start_margin``): looking from
    a standstill never shows them, moving the arm does. Never those within ``surface_margin`` of an
    occupied cell."""

    surface_shadow: str = "enter"
    """Safe mode, depth: after its looks, whether the arm goes into unknown cells that an observed
    surface hides from every camera that has them in view (the task's cameras,
    :mod:`planbench.reactive.shadows`): ``"enter"`` (the default: as into any other unknown cell)
    or ``"avoid"`` (never: they are a dead end, as the unseen rest of a surface is; the cameras do
    not move, so no look shows them). Without cameras in the task, ``"avoid"`` avoids nothing."""

    def __post_init__(self) -> None:
        for name in (
            "plan_time",
            "known_plan_time",
            "check_resolution",
            "lookahead",
            "scan_horizon",
            "start_margin",
            "surface_margin",
            "goal_block_time",
            "known_hold_distance",
            "hold_time",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be a finite number > 0, got {v!r}")
        if not 0 < self.speed_scale <= 1:
            raise InvalidConfigError(f"speed_scale must be in (0, 1], got {self.speed_scale!r}")
        if self.plan_clock not in ("cpu", "wall"):
            raise InvalidConfigError(f'plan_clock must be "cpu" or "wall", got {self.plan_clock!r}')
        if self.surface_shadow not in ("enter", "avoid"):
            raise InvalidConfigError(f'surface_shadow must be "enter" or "avoid", got {self.surface_shadow!r}')
        if self.known_plan_at not in ("start", "stop"):
            raise InvalidConfigError(f'known_plan_at must be "start" or "stop", got {self.known_plan_at!r}')
        if self.known_sliced_when not in ("always", "threat", "contact"):
            raise InvalidConfigError(
                f'known_sliced_when must be "always", "threat" or "contact", got {self.known_sliced_when!r}'
            )
        if self.plan_sliced_when not in ("never", "threat", "contact"):
            raise InvalidConfigError(
                f'plan_sliced_when must be "never", "threat" or "contact", got {self.plan_sliced_when!r}'
            )
        if self.plan_sliced_when != "never" and self.known_checks_per_tick == 0:
            raise InvalidConfigError(
                f'plan_sliced_when = "{self.plan_sliced_when}" slices by known_checks_per_tick: set '
                'known_checks_per_tick > 0, or plan_sliced_when = "never"'
            )
        if self.dead_end not in ("wait", "replan"):
            raise InvalidConfigError(f'dead_end must be "wait" or "replan", got {self.dead_end!r}')
        if self.goal_obstacles not in ("ignore", "wait", "appeared"):
            raise InvalidConfigError(
                f'goal_obstacles must be "ignore", "wait" or "appeared", got {self.goal_obstacles!r}'
            )
        if not (isinstance(self.known_cpu_share, (int, float)) and 0 <= self.known_cpu_share < 1):
            raise InvalidConfigError(f"known_cpu_share must be in [0, 1), got {self.known_cpu_share!r}")
        if not 0 <= self.cell_inset < 0.5:
            raise InvalidConfigError(f"cell_inset must be in [0, 0.5) cells, got {self.cell_inset!r}")
        for name in ("look_frames", "known_checks_per_tick", "relax_steps", "goal_fringe"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise InvalidConfigError(f"{name} must be an integer >= 0, got {v!r}")
        for name in ("known_plan_checks", "relax_after"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidConfigError(f"{name} must be an integer >= 1, got {v!r}")
        self.validate_unknown()
        self.validate_prediction()
        self.validate_evade()


def _ball(radius: float) -> np.ndarray:
    """The cell offsets (n, 3) within ``radius`` cells of a cell (centre to centre), itself apart."""
    r = int(math.floor(radius))
    span = np.arange(-r, r + 1)
    offsets = np.stack(np.meshgrid(span, span, span, indexing="ij"), axis=-1).reshape(-1, 3)
    return offsets[(np.sum(offsets**2, axis=1) <= radius * radius) & np.any(offsets != 0, axis=1)]


def _near_any(cells: np.ndarray, occupancy: np.ndarray, radius: float) -> np.ndarray:
    """For each of ``cells`` (flat indices into the grid of ``occupancy``), whether an occupied
    cell (``occupancy`` >= 0.5) lies within ``radius`` cells of it: :func:`_next_to` asked of a
    few cells."""
    if not len(cells) or radius < 1:
        return np.zeros(len(cells), dtype=bool)
    idx = np.column_stack(np.unravel_index(cells, occupancy.shape))[:, None, :] + _ball(radius)[None, :, :]
    inside = np.all((idx >= 0) & (idx < np.asarray(occupancy.shape)), axis=-1)
    hit = np.zeros(inside.shape, dtype=bool)
    hit[inside] = occupancy[tuple(idx[inside].T)] >= 0.5
    return np.asarray(hit.any(axis=1), dtype=bool)


def _next_to(cells: np.ndarray, shape: tuple[int, ...], radius: float, known: np.ndarray) -> np.ndarray:
    """Flat indices of the unknown cells (``known`` False) whose centres lie within ``radius``
    cells of one of ``cells`` (flat indices into a grid of ``shape``); a few milliseconds for
    thousands of cells (flat offsets; the cells within ``radius`` of the grid's faces apart)."""
    r = int(math.floor(radius))
    if not len(cells) or r < 1:
        return np.zeros(0, dtype=np.intp)
    offsets = _ball(radius)
    dims = np.asarray(shape)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    idx = np.column_stack(np.unravel_index(cells, shape))
    inner = np.all((idx >= r) & (idx < dims - r), axis=1)
    near = (cells[inner][:, None] + (offsets @ strides)[None, :]).ravel()  # no wrap: r from every face
    edge = (idx[~inner][:, None, :] + offsets[None, :, :]).reshape(-1, 3)
    edge = edge[np.all((edge >= 0) & (edge < dims), axis=1)] @ strides
    near = np.concatenate([near, edge])
    flat_known = known.reshape(-1)
    return np.unique(near[~flat_known[near]])


_FRONTIER = 2
"""Safe mode: [cells] the depth of unknown space a plan in known space treats as obstacles, next to
the space the arm may enter (:meth:`OMPLReplanController._known_space_obstacles`): two cells
(4 cm at the default resolution) are more than any body point moves between two of the planner's
checks (0.01 rad per joint), and the follower's scan checks the path against every unknown cell
anyway."""

_CONTACT_CELLS = 4
"""Depth, ``goal_obstacles = "wait"``: at most this many occupied cells among those the arm's body
fills at the goal are a surface it touches there (observed cells lie up to a cell beyond the true
surface), left out of plans like the cells next to the body; more are an obstacle standing on the
goal (a box parked there): kept, so that no plan drives into it and the arm waits until it leaves. In the static
scenes of ``dynamic-tune`` and ``dynamic-test`` none of the 216 depth scenarios' goals has one
(Panda ``/0002``: 8 cells next to the body, none in it)."""

_GAIN = 0.3
"""Of the way back to the path per period the follower steers (stable while a command is held for
fewer than 1 / 0.3 periods: a frame's checks cost 10-25 ms at a 10 ms period)."""


class OMPLReplanController(Controller):
    """``ompl-replan`` (module docstring)."""

    name = "ompl-replan"
    Config = OMPLReplanConfig

    def setup(self, task: ControlTask) -> None:
        self.task = task
        self.planner = REGISTRY.make(self.config.planner, **self._clock_setting())
        self.vmax = self.config.speed_scale * np.asarray(task.robot.velocity_limit, dtype=float)
        self.pace = self.vmax  # [rad/s] the path's timing: the scaled limits, a retreat's the full ones
        self.safe = self.config.unknown == "occupied"
        body_points(task.robot, 0.02)  # the body's sample points at the default resolution, untimed
        self.samples = ArmSamples(task.robot) if self._watches() else None  # built untimed
        self.link_boxes = LinkBoxes(task.robot)
        shadows = self.config.arm_shadow or self.config.surface_shadow == "avoid"
        if shadows and task.cameras:  # the compiled line walk loaded (or compiled), untimed
            tiny = OccupancyGrid.empty(np.zeros(3), np.full(3, 0.1), 0.05)
            occluders(np.arange(2), tiny, np.zeros(tiny.shape, dtype=bool), task.cameras[:1])
        tracked = self.config.prediction != "none" or self._watches()
        self.predictor = MotionPredictor(self.config) if tracked else None
        if self.predictor is not None:
            warm_up(self.config, lambda block: None)  # scipy's k-d tree and graph code loaded, untimed

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        self.rng = rng
        self.start = np.array(q, dtype=float)
        self.path: np.ndarray | None = None  # the path being followed, its first row where the arm was
        self.times: np.ndarray | None = None  # [s] at each of its waypoints, at the scaled velocity limits
        self.tau = 0.0  # [s] position along it
        self.t_follow: float | None = None  # [s] when the follower last commanded
        self.tau_limit = math.inf  # [s] where the follower stops (safe mode: short of unknown cells)
        self.through = np.zeros(0, dtype=np.intp)  # safe mode: unknown cells entered after a look
        self.looks = 0  # safe mode: frames the arm has waited short of unknown cells
        self.known_path = False  # safe mode: the path was planned in known space
        self.known_query: SlicedRRTConnect | None = None  # safe mode: the plan in known space, in slices
        self.known_cpu = 0.0  # [s] CPU time its slices have taken (its budget with known_cpu_share)
        self.plan_query: SlicedRRTConnect | None = None  # plan_sliced_when: the plan to the goal, in slices
        self.plan_cpu = 0.0  # [s] CPU time its slices have taken
        self.plan_frame = 0  # the frame count when it began
        self.known_pending = False  # safe mode, known_plan_at "stop": the path's plan in known space is yet to be made
        self.observation: Observation | None = None
        self.checker: CollisionChecker | None = None  # truth: the frame's scene, less what the arm touches
        self.reach: PathBoxes | None = None  # depth: the path's boxes, from the first frame on it
        self.reach_times = np.zeros(0)  # [s] along the path of the configurations it was built from
        self.reach_q = np.zeros((0, len(q)))  # those configurations
        self.verified: np.ndarray | None = None  # depth: the cells (flat, bool) the path's rest was checked clear of
        self.scan_clear = -math.inf  # safe mode: [s] along the path up to which the scans found only allowed cells
        self.stretch: tuple[float, np.ndarray] | None = None  # safe mode: a look's start [s], its cells
        self.occupied_cells: np.ndarray | None = None  # depth: the frame's occupied cells, once asked (``occupied``)
        self.scene: Scene | None = None  # truth: the frame's scene, less what the arm touches
        self.body: ArmBody | None = None
        self.arm = ArmCells(self.task.robot, self.task.goal.q)  # the cells the arm fills, per grid
        self.near_goal: np.ndarray | None = None  # cells within a cell of the body at the goal
        self.goal_cells = GoalCells(
            self.config.goal_block_time, self.config.goal_fringe
        )  # depth, "appeared": which of them block the goal
        self.goal_refused = False  # the last plan failed because the goal is in collision
        self.own: np.ndarray | None = None  # safe mode: unknown cells the arm may enter (start, goal)
        self.allowed: np.ndarray | None = None  # safe mode: known or own, the frame's (bool, grid shape)
        self.hidden: np.ndarray | None = None  # safe mode: unknown cells next to occupied ones
        self.relaxed = 0  # safe mode: steps surface_margin has been relaxed by (relax_steps)
        self.failed_in_row = 0  # plans failed since the last that found a path
        self.predicted = np.zeros(0, dtype=np.intp)  # depth, "swept": the cells moving clusters sweep (flat)
        self.threat = np.zeros(0, dtype=np.intp)  # evade: moving cells and what tracks sweep (flat)
        self.moving = np.zeros(0, dtype=np.intp)  # evade: the frame's clustered moving cells (flat)
        self.tracks: tuple[Track, ...] = ()  # evade: the tracks alive after the frame
        self.evading = False  # the path followed is a retreat (evade)
        self.retreat_due = False  # evade: a threat came at the moving arm; it stops, then retreats
        if self.predictor is not None:
            self.predictor.reset()
        self.fresh = False
        self.frames = 0  # observations taken in this run
        self.still = True  # the last command was a stop (or nothing): a plan may start now
        self.may_plan = False  # one plan per frame at most
        self.stats: dict[str, Any] = {"plans": 0, "failed_plans": 0, "plan_times": [], "invalidated": 0, "dropped": 0}
        self.stats.update(known_plans=0, looks=0, forced=0, known_slices=0, known_unneeded=0, known_failed=0)
        self.stats.update(goal_blocked=0, relaxed=0, stuck=0, predicted_frames=0, predicted_cells_max=0)
        self.stats.update(rest_checks=0, arm_shadow=0, evasions=0, evade_failed=0, known_calm=0, known_threat_slices=0)
        self.stats.update(sliced_plans=0, plan_slices=0, plan_calm=0, plan_threat_slices=0)
        self.frame_q = self.start.copy()  # depth: the arm where it was when the last frame came
        self.tick_cpu = time.process_time()  # [s] process CPU time when the current tick began

    def update(self, observation: Observation) -> None:
        self.observation = observation
        self.frames += 1
        depth = observation.scene is None
        if self.predictor is not None and (depth or self._watches()):  # where obstacles go
            prediction = self.predictor.observe(observation)
            if self._watches():
                self.threat = np.union1d(prediction.moving, prediction.cells)
                self.moving, self.tracks = prediction.moving, prediction.tracks
            if self.config.prediction != "none" and depth:  # truth: its plans check the exact scene
                self.predicted = prediction.cells
            if len(self.predicted):
                self.stats["predicted_frames"] += 1
                self.stats["predicted_cells_max"] = max(self.stats["predicted_cells_max"], len(self.predicted))
        self.checker = None  # truth: built in the step (it needs the arm's configuration)
        self.fresh = True

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        self.tick_cpu = time.process_time()  # [s] the tick's start, for a sliced plan's share of it
        if self.observation is None:
            return np.zeros_like(q)
        if self.fresh:  # a new frame: the rest of the path is checked, one plan is allowed
            self.fresh, self.may_plan = False, True
            self._frame(q)
            retreating = self.config.evade != "none" and self._evade(q)  # a new retreat: nothing to check
            if not retreating and self.path is not None:
                self._check_rest(q)
        if self.path is None:
            if not self.still:  # stop first: the runner holds this command while the plan is made
                self.still = True
                return np.zeros_like(q)
            if self.retreat_due:  # stopped: the retreat starts where the arm stands
                self.retreat_due = False
                self._retreat(q)
            if self.path is None and self.plan_query is not None:
                self._plan_slice(q)
            elif self.path is None and self.may_plan:
                self.may_plan = False
                self._plan(q)
            if self.path is None:
                return np.zeros_like(q)
        self.still = False
        command = self._follow(q, t)
        if self.known_query is not None:
            self._known_slice(q)
        return command

    def info(self) -> dict[str, Any]:
        return dict(self.stats)

    # --- getting out of the way ---------------------------------------------------------------
    def _evade(self, q: np.ndarray) -> bool:
        """Depth, ``evade``: on a new frame, whether the arm retreats now (a new path, the
        retreat, at the full velocity limits; :mod:`~.evade`). A retreat ends when its end is
        reached or no moving cell is within ``evade_distance`` of the arm any more: then the arm
        plans to the goal again; one whose end is no farther from the threat than the arm is now
        (the obstacle came on) is replaced. A path that takes the arm twice ``evade_distance``
        from the threat's cells within ``scan_horizon`` is kept (a path that is only farther from
        where they are now let a box that followed the arm run into it on ``dynamic-tune``)."""
        obs, body = self.observation, self.samples
        evading = self.evading and self.path is not None
        self.evading, self.retreat_due = evading, False  # each frame decides again
        if obs is None or body is None or (not len(self.threat) and not evading):
            return False
        threat = Threat(obs.grid, self.threat)
        cap = 2.0 * self.config.evade_distance
        near = threat.distance(body, q, cap)
        if near >= self.config.evade_distance:
            if evading:  # out of the way: plan to the goal again
                self.evading, self.path = False, None
            return False
        if self.path is not None and self.times is not None:
            if evading and self.tau < float(self.times[-1]) - 1e-9:
                if threat.distance(body, self.path[-1], cap) > near + obs.grid.resolution:
                    return False  # on its way out: its rest is checked as any path's
            if not evading:
                ahead = self._at(min(self.tau + self.config.scan_horizon, float(self.times[-1])))
                if threat.distance(body, ahead, cap) >= cap:
                    return False  # the path leads well away (the threat may follow: farther than near is not enough)
        if not self.still:  # moving: stop now, retreat from where the arm stops (``_retreat``)
            self.path, self.evading, self.retreat_due = None, False, True
            return True
        return self._retreat(q, threat)

    def _retreat(self, q: np.ndarray, threat: Threat | None = None) -> bool:
        """Evade: take a retreat from ``q``, where the arm stands, if one gets it farther from the
        threat. Only from a standing arm: the runner holds the last command while this is
        computed (tens of milliseconds, charged), so a retreat worked out for a moving arm would
        start from wherever that command carried it, along a motion nothing checked (the UR5's
        upper arm was driven into a table so on ``dynamic-tune``, 2026-11-27). ``threat``: the
        frame's, when the caller has it already."""
        obs, body = self.observation, self.samples
        assert obs is not None and body is not None
        threat = threat if threat is not None else Threat(obs.grid, self.threat)
        if obs.scene is not None:  # truth: the frame's scene less what the arm touches (``_frame``)
            checker = self.checker
        else:
            assert self.occupied is not None
            checker = self._cells_checker(self.occupied, q)
        assert checker is not None
        limits = (np.asarray(self.task.robot.lower), np.asarray(self.task.robot.upper))
        end = retreat(q, threat, body, checker, limits, self.config, self.config.check_resolution, self.rng)
        if end is None:
            self.stats["evade_failed"] += 1
            if self.evading:  # at a retreat's end with nowhere farther to go: plan to the goal again
                self.evading, self.path = False, None
            return False
        self._take(np.vstack([q, end]), self.vmax / self.config.speed_scale)  # at the full limits
        self.evading = True
        self.stats["evasions"] += 1
        return True

    # --- the frame ----------------------------------------------------------------------------
    def _frame(self, q: np.ndarray) -> None:
        """The frame's checker (less the obstacles the arm at ``q`` touches) and, in safe mode, the
        cells the arm may enter."""
        obs = self.observation
        assert obs is not None
        self.frame_q = np.array(q, dtype=float)
        if obs.scene is not None:  # truth: the exact geometry
            self.scene, self.checker = self._around(obs.scene, q)
            self.allowed = None
            return
        grid = obs.grid
        self._geometry(grid)
        if self.config.goal_obstacles == "appeared" and self.near_goal is not None:
            self.goal_cells.classify(obs.time, grid, self.near_goal)  # its ``blocking`` cells are kept
        self.occupied_cells = None  # found when first asked: a frame whose check reads only the path's cells never does
        before, self.allowed = self.allowed, None
        if not self.safe or grid.known is None:
            return
        self.hidden = None  # the unseen rest of seen surfaces: found when a plan needs them
        if self.config.gate:
            allowed = grid.known.copy()
            assert self.own is not None and self.near_goal is not None
            flat = allowed.reshape(-1)  # a view
            flat[self.own] = True
            flat[self.through] = True
            flat[self.near_goal] = True
            if before is None or before.shape != allowed.shape or np.any(before > allowed):
                self.scan_clear = -math.inf  # a cell the scans allowed may not be entered now
            self.allowed = allowed

    def _geometry(self, grid: OccupancyGrid) -> None:
        """The caches that belong to the grid's cells: the arm's body, the cells near it at the goal
        and, in safe mode, where it started."""
        if not self.arm.fit(grid):
            return
        self.reach, self.stretch = None, None  # another grid: its cells are not those checked
        self.body = self.arm.body
        self.near_goal = self.arm.near_goal
        goal_q = self.task.goal.q
        self.through = np.zeros(0, dtype=np.intp)
        if self.safe:
            cells = max(1, math.ceil(self.config.start_margin / grid.resolution))
            own = [self.arm.near(self.start, cells)]
            if goal_q is not None:
                own.append(self.arm.near(np.asarray(goal_q), cells))
            self.own = np.unique(np.concatenate(own))

    def _obstacles(self) -> np.ndarray:
        """Depth: the frame's obstacle cells (flat indices): the occupied ones and, with
        ``prediction = "swept"``, those the moving clusters sweep over ``prediction_horizon``."""
        assert self.occupied is not None
        if not len(self.predicted):
            return self.occupied
        return np.union1d(self.occupied, self.predicted)

    def _cells_checker(self, cells: np.ndarray, q: np.ndarray, swept: np.ndarray | None = None) -> CollisionChecker:
        """A checker of the cells (flat indices) less those within a cell of the arm at ``q`` and at
        the goal, when the arm touches them there (counted in ``dropped``); with ``swept`` (the
        cells moving clusters sweep), those too, less the ones within a cell of the arm at ``q`` or
        at the goal, always: an arm in a sweep plans its way out of it, and a sweep near the arm
        does not drop the static cells it touches."""
        return self._cells_and_checker(cells, q, swept)[1]

    def _cells_and_checker(
        self, cells: np.ndarray, q: np.ndarray, swept: np.ndarray | None = None, touched: bool | None = None
    ) -> tuple[np.ndarray, CollisionChecker]:
        """:meth:`_cells_checker`, and the cells (flat indices) its checker holds; ``touched``:
        whether the arm touches the frame's cells, when ``cells`` are only some of them."""
        checker, kept = self._kept(cells, q, touched)
        if swept is None or not len(swept):
            return (cells, checker) if kept is None else (kept, self._checker_of(kept))
        assert self.near_goal is not None
        near = np.concatenate([self.arm.near(q, 1), self.near_goal])
        held = np.union1d(cells if kept is None else kept, swept[~np.isin(swept, near)])
        return held, self._checker_of(held)

    def _kept(
        self, cells: np.ndarray, q: np.ndarray, touched: bool | None = None
    ) -> tuple[CollisionChecker, np.ndarray | None]:
        """A checker of the cells (flat indices), and the cells less those within a cell of the
        arm at ``q`` and at the goal when the arm touches them there (counted in ``dropped``; None
        when it touches none). ``touched`` given: whether it touches the frame's occupied cells
        (``cells`` being some of them)."""
        checker = self._checker_of(cells)
        goal_q = self.task.goal.q
        some = touched is not None  # ``cells`` are some of the frame's
        if touched is None:
            touched = checker.in_collision(q) or (goal_q is not None and checker.in_collision(np.asarray(goal_q)))
        if not touched:
            return checker, None
        assert self.near_goal is not None
        near_goal = self.near_goal
        every = self.occupied if some and self.config.goal_obstacles == "wait" else cells
        assert every is not None
        on_goal = every[np.isin(every, self.arm.at_goal)] if self.config.goal_obstacles == "wait" else cells[:0]
        if len(on_goal) > _CONTACT_CELLS:  # an obstacle on the goal: planned around, waited out
            near_goal = near_goal[~np.isin(near_goal, on_goal)]
            self.stats["goal_blocked"] += 1
        blocking = self.goal_cells.blocking  # the rest near the goal is left out as with "ignore"
        if self.config.goal_obstacles == "appeared" and len(blocking) == len(near_goal):
            if np.isin(near_goal[blocking], cells).any():  # cells that appeared on the goal: kept
                self.stats["goal_blocked"] += 1
            near_goal = near_goal[~blocking]
        near = np.concatenate([self.arm.near(q, 1), near_goal])
        kept = cells[~np.isin(cells, near)]
        self.stats["dropped"] += len(cells) - len(kept)
        return checker, kept

    def _checker_of(self, cells: np.ndarray) -> CollisionChecker:
        obs = self.observation
        assert obs is not None
        grid = obs.grid
        if self.config.cell_inset <= 0:
            return cells_checker(self.task.robot, grid, cells)
        return CollisionChecker(self.task.robot, self._boxes(cells))

    def _boxes(self, cells: np.ndarray) -> Scene:
        """The cells (flat indices) as boxes, shrunk by ``cell_inset``."""
        grid = self.observation.grid  # type: ignore[union-attr]
        mask = np.zeros(grid.shape, dtype=bool)
        mask.flat[cells] = True
        inset = self.config.cell_inset * grid.resolution
        boxes = tuple(
            dataclasses.replace(o, size=tuple(s - 2 * inset for s in o.size)) if o.size is not None else o
            for o in cell_boxes(mask, grid.origin, grid.resolution)
        )
        return Scene(boxes, "observed-cells")

    def _around(self, scene: Scene, q: np.ndarray) -> tuple[Scene, CollisionChecker]:
        """Truth: the scene without the obstacles the arm at ``q`` touches (counted in ``dropped``),
        and a checker of it."""
        scene, checker, dropped = scene_without_touched(self.task.robot, scene, q)
        self.stats["dropped"] += dropped
        return scene, checker

    # --- the rest of the path ------------------------------------------------------------------
    def _rest(self, q: np.ndarray, tau: float, until: float = math.inf) -> list[tuple[float, np.ndarray]]:
        """The configurations at which the rest of the path from ``q`` (at ``tau`` [s] along it) is
        checked, each with its time along the path [s], up to ``until`` [s]."""
        path, times = self.path, self.times
        assert path is not None and times is not None
        i = min(int(np.searchsorted(times, tau, side="right")), len(path) - 1)
        ends = np.vstack([q, path[i:]])
        stamps = np.concatenate([[tau], times[i:]])
        out: list[tuple[float, np.ndarray]] = []
        for a, b, ta, tb in zip(ends[:-1], ends[1:], stamps[:-1], stamps[1:], strict=True):
            n = max(1, int(math.ceil(np.max(np.abs(b - a)) / self.config.check_resolution)))
            for u in np.arange(1, n + 1) / n:
                if ta + u * (tb - ta) > until:
                    return out
                out.append((ta + u * (tb - ta), a + u * (b - a)))
        return out

    def _rest_collides(self, q: np.ndarray) -> bool:
        """Whether the rest of the path collides with the frame's obstacles. Truth: the rest from
        ``q``, against the frame's scene. Depth: the path's own configurations from where the
        follower is on it (``_samples``, a grid fixed along the path), checked only

        - against the cells no earlier frame's check of this path held (``verified``): the rest
          only shrinks, and a path clear of a cell stays clear of it;
        - against those of them inside the boxes around the links at one of the configurations
          (:class:`~.observed.PathBoxes`, built on the first frame), and only the (configuration,
          link) pairs whose box holds one, with coal's exact test of that link.

        A frame costs milliseconds where an octree of every occupied cell and a check of the
        whole arm at every configuration cost 20-40 ms (over the 10 ms period: a missed deadline
        on most frames, docs/reactive.md)."""
        assert self.times is not None
        obs = self.observation
        assert obs is not None
        if obs.scene is not None:
            assert self.checker is not None
            return any(self.checker.in_collision(x) for _, x in self._rest(q, self.tau))
        if self.reach is None:  # the first frame on this path: its configurations and their boxes
            stamps = self._samples(self.tau, float(self.times[-1]))
            self.reach_times = np.array([when for when, _ in stamps])
            self.reach_q = np.array([x for _, x in stamps])
            self.reach = self.link_boxes.along(self.reach_q, obs.grid)
            self.verified = np.zeros(obs.grid.data.size, dtype=bool)
        assert self.verified is not None
        cells = self.reach.fresh(obs.grid, self.verified)  # occupied, in the boxes, not yet checked
        swept = self.predicted
        if len(swept):  # swept, not occupied, in the boxes, not yet checked
            swept = swept[~self.verified[swept] & (obs.grid.data.reshape(-1)[swept] < 0.5)]
            swept = self.reach.near(swept)
        if not len(cells) and not len(swept):
            return False
        held, _ = self._cells_and_checker(cells, q, swept, self._touches(q))
        if len(held):
            rows, objects = self.reach.touching(held)
            rest = self.reach_times[rows] >= self.tau - 1e-9  # the rest only
            self.stats["rest_checks"] += int(np.count_nonzero(rest))
            if self.reach.collides(held, rows[rest], objects[rest]):
                return True
        self.verified[held] = True  # not the cells dropped next to the arm: checked again
        return False

    def _touches(self, q: np.ndarray) -> bool:
        """Depth: whether the arm at ``q`` or at the goal touches the frame's occupied cells (the
        question :meth:`_kept` asks of its cells, asked of all of them without an octree of all)."""
        obs = self.observation
        assert obs is not None
        goal_q = self.task.goal.q
        return self.link_boxes.touches(q, obs.grid) or (
            goal_q is not None and self.link_boxes.touches(np.asarray(goal_q), obs.grid)
        )

    @property
    def occupied(self) -> np.ndarray | None:
        """Depth: the frame's occupied cells (flat indices), found on first use in a frame."""
        obs = self.observation
        if self.occupied_cells is None and obs is not None and obs.scene is None:
            self.occupied_cells = np.flatnonzero(obs.grid.data >= 0.5)
        return self.occupied_cells

    def _check_rest(self, q: np.ndarray) -> None:
        """On a new frame: drop the path if its rest collides with the frame's obstacles; in safe
        mode, set where the follower stops short of unknown cells and, when the arm has waited
        there ``look_frames`` frames, let it into the next ``scan_horizon`` of them."""
        assert self.times is not None
        if self._rest_collides(q):
            self.stats["invalidated"] += 1
            self.path = None
            self.known_query = None  # the next plan starts over
            return
        if self.allowed is None:
            return
        block = self._limit(self.tau)
        if block is None or self.tau < self.tau_limit - 1e-9:
            self.looks = 0
            return
        self.looks += 1  # held short of unknown cells: look, then go on
        self.stats["looks"] += 1
        if self.looks > self.config.look_frames and self.known_query is None:  # not while a way round is sought
            if self.known_pending:  # known_plan_at "stop": a way round in known space, before going in
                self.known_pending = False
                if self._plan_known(q):
                    return
            self._go_through(block)

    def _go_through(self, block: float) -> None:
        """Let the arm into the unknown cells its body fills over ``scan_horizon`` from ``block``
        [s] along the path (``forced``: the only way on goes through space no frame has seen)."""
        assert self.body is not None and self.allowed is not None and self.observation is not None
        if self.stretch is None or self.stretch[0] != block:  # the body's cells from there, kept per path
            mark = np.zeros(self.body.shape, dtype=bool)
            for _, x in self._samples(block, block + self.config.scan_horizon):
                self.body.mark(mark, x)
            self.stretch = (block, np.flatnonzero(mark))
        flat = self.allowed.reshape(-1)
        cells = self.stretch[1][~flat[self.stretch[1]]]
        grid = self.observation.grid
        cells = cells[~_near_any(cells, grid.data, self._margin() / grid.resolution)]  # never a hidden surface
        if self.config.surface_shadow == "avoid" and len(cells):
            cells = cells[self._occluders(cells) != SURFACE]  # nor what a surface hides from every camera
        if not len(cells):  # every cell in the way is the unseen rest of a surface: a dead end
            self.stats["stuck"] += 1
            if self.config.dead_end == "replan":
                self.path, self.known_query, self.looks = None, None, 0
            return
        self.through = np.union1d(self.through, cells)
        flat[cells] = True
        self.stats["forced"] += 1
        self.looks = 0
        self._limit(self.tau)

    def _margin(self) -> float:
        """Safe mode: the surface margin [m] now, ``surface_margin`` less the steps relaxed."""
        c = self.config
        return c.surface_margin * (1.0 - self.relaxed / c.relax_steps) if c.relax_steps else c.surface_margin

    def _relax(self) -> None:
        """Safe mode, after a failed plan: one more failure in a row; after ``relax_after`` of them,
        relax the surface margin one step (the next frame's plan keeps out of fewer hidden cells)."""
        self.failed_in_row += 1
        c = self.config
        if self.relaxed >= c.relax_steps or self.failed_in_row < c.relax_after:
            return
        self.relaxed += 1
        self.failed_in_row = 0
        self.hidden = None
        self.stats["relaxed"] = self.relaxed

    def _hidden(self) -> np.ndarray:
        """Safe mode, depth: the frame's unknown cells within the surface margin (``_margin``) of
        an occupied one (the unseen rest of a seen surface; computed once per frame, when first
        needed; none at margin 0)."""
        obs = self.observation
        known = obs.grid.known if obs is not None else None
        if obs is None or known is None or self.occupied is None:
            return np.zeros(0, dtype=np.intp)
        if self.hidden is None:
            grid = obs.grid
            self.hidden = _next_to(self.occupied, grid.shape, self._margin() / grid.resolution, known)
        return self.hidden

    # --- planning ---------------------------------------------------------------------------
    def _plan(self, q: np.ndarray) -> None:
        """Plan from ``q`` as the default does; in safe mode, when that path enters cells the arm
        may not enter, plan again in known space (every unknown cell an obstacle but those it may
        enter) and follow that path instead if there is one."""
        self.known_path, self.known_query, self.known_pending = False, None, False
        obs = self.observation
        assert obs is not None
        checker = self.checker  # truth: the frame's scene
        depth = self._safe_depth()
        if depth:
            assert self.occupied is not None
            checker = self._cells_checker(np.union1d(self.occupied, self._hidden()), q, self.predicted)
        elif obs.scene is None:
            assert self.occupied is not None
            checker = self._cells_checker(self.occupied, q, self.predicted)
        if self._slice_plan(q, checker):
            return
        if not self._plan_once(q, checker):
            self._plan_failed(depth)
            return
        self._planned(q)

    def _safe_depth(self) -> bool:
        """Safe mode with a depth frame (one that knows which cells it has not seen)."""
        obs = self.observation
        return self.safe and obs is not None and obs.grid.known is not None and obs.scene is None

    def _plan_failed(self, depth: bool) -> None:
        """After a plan to the goal without a path: in safe mode with depth, one more failure
        toward relaxing the surface margin (not while cells are swept or the goal is refused)."""
        if depth and not len(self.predicted) and not self.goal_refused:  # nor is a sweep or a blocked goal
            self._relax()

    def _planned(self, q: np.ndarray) -> None:
        """After a plan to the goal found the path followed now, from ``q``: in safe mode, when it
        enters cells the arm may not enter, the plan in known space (at once or in slices)."""
        self.failed_in_row = 0
        if self.allowed is None or self.body is None:
            return
        if getattr(self.planner, "use_checker", None) is None:
            return
        assert self.path is not None and self.times is not None and self.occupied is not None
        if not self._enters_unknown(0.0):
            return
        if self.config.arm_shadow:  # cells the arm hides are let in: maybe no plan in known space is needed
            self._admit_arm_shadow()
            if not self._enters_unknown(0.0):
                return
        goal_q = self.task.goal.q
        if self.config.known_checks_per_tick > 0 and goal_q is not None and self._hold_unsafe(q):
            known = self._cells_checker(self._known_space_obstacles(), q, self.predicted)
            try:  # in slices, while the arm follows the optimistic path up to the unknown cells
                seed = int(self.rng.integers(2**31))
                exact = self.config.known_cpu_share > 0  # a slice's end by CPU time needs the exact mode
                self.known_query = SlicedRRTConnect(known, q, np.asarray(goal_q), seed=seed, exact=exact)
                self.known_cpu = 0.0
            except ValueError:  # the start or the goal touches the cells that stand for unknown space
                self.known_query = None
            return
        if self.config.known_plan_at == "stop":  # made if the follower is still held short of them
            self.known_pending = True
            return
        self._plan_known(q)

    def _watches(self) -> bool:
        """Whether the frames' moving cells and tracks are followed: for a retreat (``evade``) or to
        tell whether a plan runs in slices (``known_sliced_when``, ``plan_sliced_when``)."""
        c = self.config
        return c.evade != "none" or c.known_sliced_when != "always" or c.plan_sliced_when != "never"

    def _hold_unsafe(self, q: np.ndarray, when: str | None = None, counted: str = "known") -> bool:
        """Slices on: whether a plan from ``q`` runs in slices (``when``: ``known_sliced_when`` by
        default): always, or while the arm cannot tell that no obstacle is coming at it (fewer
        than two frames, or a threat's cell within ``known_hold_distance``; ``"contact"``: within
        what it covers while the arm is held, :meth:`_contact_near`). ``counted``: the
        prefix of the counters in ``info`` (``known_calm``, ``known_threat_slices``)."""
        if (when or self.config.known_sliced_when) == "always":
            return True
        obs, body = self.observation, self.samples
        if obs is None or body is None or self.frames < 2:
            return True
        if (when or self.config.known_sliced_when) == "contact":
            near = self._contact_near(q)
        else:
            reach = self.config.known_hold_distance
            near = Threat(obs.grid, self.threat).distance(body, q, reach) < reach
        self.stats[f"{counted}_threat_slices" if near else f"{counted}_calm"] += 1
        return near

    def _contact_near(self, q: np.ndarray) -> bool:
        """``"contact"``: whether an obstacle that came in lately could reach the arm's body at
        ``q`` while a plan made at once holds it (``hold_time``): a track with a trusted velocity
        within its speed times ``hold_time`` plus ``evade_distance``; moving cells with no such
        track within ``known_hold_distance``."""
        obs, body = self.observation, self.samples
        assert obs is not None and body is not None
        c = self.config
        timed = [tr for tr in self.tracks if tr.velocity is not None]
        for tr in timed:
            assert tr.velocity is not None
            reach = float(np.linalg.norm(tr.velocity)) * c.hold_time + c.evade_distance
            if Threat(obs.grid, tr.cells).distance(body, q, reach) < reach:
                return True
        untimed = self.moving
        if timed and len(untimed):
            untimed = np.setdiff1d(untimed, np.concatenate([tr.cells for tr in timed]), assume_unique=False)
        reach = c.known_hold_distance
        return bool(len(untimed)) and Threat(obs.grid, untimed).distance(body, q, reach) < reach

    def _slice_plan(self, q: np.ndarray, checker: CollisionChecker | None) -> bool:
        """``plan_sliced_when``: whether the plan to the goal from ``q`` against ``checker`` starts
        in slices now (advanced by :meth:`_plan_slice`, one slice a tick, the arm standing); False:
        it is made at once (never sliced, a pose goal, nothing coming, or the start or the goal in
        the checker's obstacles, which the planner made at once reports)."""
        goal_q = self.task.goal.q
        if self.config.plan_sliced_when == "never" or goal_q is None or checker is None:
            return False
        if not self._hold_unsafe(q, self.config.plan_sliced_when, "plan"):
            return False
        try:
            exact = self.config.known_cpu_share > 0
            seed = int(self.rng.integers(2**31))
            self.plan_query = SlicedRRTConnect(checker, q, np.asarray(goal_q), seed=seed, exact=exact)
        except ValueError:
            return False
        self.plan_cpu, self.plan_frame = 0.0, self.frames
        self.stats["sliced_plans"] += 1
        return True

    def _plan_slice(self, q: np.ndarray) -> None:
        """One slice of the plan to the goal in slices; once it has a path, follow it from ``q``
        (where the plan started: the arm stood meanwhile, and a retreat drops the plan), checked
        first against the frame that came last if one came while it ran."""
        query = self.plan_query
        assert query is not None
        done, self.plan_cpu, over = self._advance(query, self.plan_cpu, self.config.plan_time)
        self.stats["plan_slices"] += 1
        if not done and not over:
            return
        self.plan_query = None
        self.stats["plans"] += 1
        self.stats["plan_times"].append(self.plan_cpu)
        if not done:
            self.stats["failed_plans"] += 1
            self.goal_refused = False
            self._plan_failed(self._safe_depth())
            return
        assert query.path is not None
        self._take(query.path)
        if self.frames > self.plan_frame and self._rest_collides(q):  # a frame since showed it blocked
            self.stats["invalidated"] += 1
            self.path = None
            return
        self._planned(q)

    def _plan_known(self, q: np.ndarray) -> bool:
        """Safe mode: plan from ``q`` in known space (every unknown cell an obstacle but those the
        arm may enter) within ``known_plan_time``, the arm held still; True when it found a path
        (then followed), else the path followed so far stays (a failed plan leaves it as it was)."""
        assert self.occupied is not None
        known = self._cells_checker(self._known_space_obstacles(), q, self.predicted)
        if not self._plan_once(q, known, self.config.known_plan_time):
            return False
        self.known_path = True
        self.stats["known_plans"] += 1
        return True

    def _known_slice(self, q: np.ndarray) -> None:
        """Safe mode: one slice of the plan in known space; once it has a path, switch to it from
        where the arm is, unless the optimistic path's rest no longer enters cells the arm may not
        enter (the frames seen since have shown them)."""
        query = self.known_query
        assert query is not None
        done, self.known_cpu, over = self._advance(query, self.known_cpu, self.config.known_plan_time)
        self.stats["known_slices"] += 1
        if not done:
            if over:
                self.known_query = None  # over its budget, or stuck: the optimistic path stays
                self.stats["known_failed"] += 1
            return
        self.known_query = None
        assert query.path is not None and self.times is not None and self.allowed is not None
        if self.body is None or not self._enters_unknown(self.tau):
            self.stats["known_unneeded"] += 1
            return
        here, known = q, query.path
        for j in range(len(known) - 1, -1, -1):  # the farthest waypoint the arm reaches straight
            if query.segments.motion_free(here, known[j]):
                path = np.vstack([here, known[j:]])
                break
        else:  # back along the way it came, then the path in known space
            i = min(int(np.searchsorted(self.times, self.tau, side="right")) - 1, len(self.path) - 1)  # type: ignore[arg-type]
            path = np.vstack([here, self.path[i::-1], known[1:]])  # type: ignore[index]
        self._take(path)
        self.known_path = True
        self.stats["known_plans"] += 1

    def _advance(self, query: SlicedRRTConnect, cpu: float, cpu_budget: float) -> tuple[bool, float, bool]:
        """One slice of a plan in slices (``known_checks_per_tick`` checks, ending at
        ``known_cpu_share`` of the tick's CPU time when that is set), ``cpu`` [s] of CPU spent on it
        before: whether it is done, the CPU spent on it now, and whether it is over without a path
        (its budget spent: ``cpu_budget`` [s] of CPU with a share, else ``known_plan_checks``
        checks; or stuck, or its search ended)."""
        c = self.config
        before, t0 = query.checks, time.process_time()
        cpu_until = self.tick_cpu + c.known_cpu_share * self.task.period if c.known_cpu_share > 0 else None
        done = query.advance(c.known_checks_per_tick, cpu_until)
        cpu += time.process_time() - t0
        if done:
            return True, cpu, False
        spent = cpu >= cpu_budget if c.known_cpu_share > 0 else query.checks >= c.known_plan_checks
        return False, cpu, spent or query.checks == before or query.failed

    def _admit_arm_shadow(self) -> None:
        """Safe mode, depth: let the arm into the unknown cells its body fills along the new path
        that the arm itself hides from a camera (``arm_shadow``)."""
        obs, body = self.observation, self.body
        cameras = self.task.cameras
        if obs is None or body is None or self.allowed is None or not cameras or self.times is None:
            return
        grid = obs.grid
        mark = np.zeros(body.shape, dtype=bool)
        for _, x in self._samples(0.0, float(self.times[-1])):
            body.mark(mark, x)
        flat = self.allowed.reshape(-1)
        cells = np.flatnonzero(mark.reshape(-1) & ~flat)
        cells = cells[~_near_any(cells, grid.data, self._margin() / grid.resolution)]
        if not len(cells):
            return
        cells = cells[self._occluders(cells) == ARM]
        if not len(cells):
            return
        self.through = np.union1d(self.through, cells)
        flat[cells] = True
        self.stats["arm_shadow"] += len(cells)

    def _occluders(self, cells: np.ndarray) -> np.ndarray:
        """What hides each of ``cells`` (flat) from the task's cameras in the latest frame, the arm
        taken where it was when the frame came, grown by the robot filter's margin
        (:func:`~planbench.reactive.shadows.occluders`)."""
        obs, body = self.observation, self.body
        assert obs is not None and body is not None
        grid = obs.grid
        grow = math.ceil(self.task.robot_margin / grid.resolution) + 1
        arm = np.zeros(body.shape, dtype=bool)
        arm.reshape(-1)[self.arm.near(self.frame_q, grow)] = True
        return occluders(cells, grid, arm, self.task.cameras)

    def _enters_unknown(self, tau: float) -> bool:
        """Safe mode: the path from ``tau`` [s] along it to its end fills a cell the arm may not enter."""
        assert self.body is not None and self.allowed is not None and self.times is not None
        return any(self.body.in_unknown(x, self.allowed) for _, x in self._samples(tau, float(self.times[-1])))

    def _known_space_obstacles(self) -> np.ndarray:
        """Safe mode: flat indices of the obstacles of a plan in known space: the occupied cells
        and the cells the arm may not enter within ``_FRONTIER`` cells of one it may (free and
        allowed). A motion from where the arm is into the rest of the unknown space crosses these,
        so they stand for all of it: a tenth of the unknown cells or fewer, an octree built in tens
        of milliseconds where all of them took half a second."""
        assert self.allowed is not None and self.occupied is not None
        open_ = self.allowed.copy()
        open_.reshape(-1)[self.occupied] = False
        blocked = grow_cells(open_, _FRONTIER) & ~self.allowed
        blocked.reshape(-1)[self.occupied] = True
        return np.flatnonzero(blocked)

    def _clock_setting(self) -> dict[str, str]:
        """The planner's ``clock`` setting for ``plan_clock`` (none for ``"wall"``, every planner's
        default); a named error when the planner has no such setting."""
        if self.config.plan_clock == "wall":
            return {}
        _, cls, _ = REGISTRY.resolve(self.config.planner)
        config = getattr(cls, "Config", None)
        if not dataclasses.is_dataclass(config) or "clock" not in {f.name for f in dataclasses.fields(config)}:
            raise InvalidConfigError(
                f"planner {self.config.planner!r} has no 'clock' setting, so its time limits cannot count CPU"
                " time: set plan_clock='wall' (elapsed time) or choose an OMPL planner"
            )
        return {"clock": self.config.plan_clock}

    def _plan_once(self, q: np.ndarray, checker: CollisionChecker | None, time_limit: float | None = None) -> bool:
        """One plan from ``q`` against ``checker`` within ``time_limit`` [s] (``plan_time`` by
        default); True when it found a path (then followed from its start)."""
        task = self.task
        t0 = time.perf_counter()
        assert checker is not None
        use_checker = getattr(self.planner, "use_checker", None)
        truth = self.observation is not None and self.observation.scene is not None
        if truth:
            assert self.scene is not None
            scene = self.scene
        elif use_checker is not None:
            scene = Scene(name="observed-cells")  # the checker holds the cells; certified for self-collision
        else:
            assert self.occupied is not None
            scene = self._boxes(np.union1d(self._obstacles(), self._hidden()) if self.safe else self._obstacles())
        problem = Problem.create(
            task.robot, scene, q, goal_q=task.goal.q, goal_pose=task.goal.pose, tolerances=task.tolerances
        )
        if use_checker is not None and not truth:
            use_checker(problem, checker)
        else:
            self.planner.setup(problem)
        limit = self.config.plan_time if time_limit is None else time_limit
        result = self.planner.plan(problem, time_limit=limit, rng=self.rng)
        self.stats["plans"] += 1
        self.stats["plan_times"].append(time.perf_counter() - t0)
        self.goal_refused = result.status is PlanStatus.INVALID_GOAL
        if result.status is not PlanStatus.SUCCESS or result.path is None or len(result.path) < 1:
            self.stats["failed_plans"] += 1
            return False
        self._take(np.array(result.path, dtype=float))
        return True

    def _take(self, path: np.ndarray, pace: np.ndarray | None = None) -> None:
        """Follow ``path`` from its start, timed at ``pace`` [rad/s] per joint (by default the
        scaled velocity limits)."""
        self.pace = self.vmax if pace is None else pace
        self.plan_query = None  # a plan under way in slices is superseded (a retreat's path, or its own)
        steps = np.max(np.abs(np.diff(path, axis=0)) / self.pace, axis=1) if len(path) > 1 else np.zeros(0)
        self.path, self.times = path, np.concatenate([[0.0], np.cumsum(steps)])
        self.evading = False  # a retreat says so after taking its path
        self.reach = None  # the next frame checks the new path against every cell
        self.scan_clear = -math.inf
        self.stretch = None
        self.tau, self.tau_limit, self.looks, self.t_follow = 0.0, math.inf, 0, None
        self._limit(0.0)

    def _samples(self, t0: float, t1: float) -> list[tuple[float, np.ndarray]]:
        """The path's configurations at the times [s] in ``[t0, t1]`` on a fixed grid along it
        (no joint moves more than ``check_resolution`` between two), the path's end included."""
        assert self.times is not None
        dt = self.config.check_resolution / float(np.max(self.pace))
        end = float(self.times[-1])
        stamps = np.arange(math.ceil(t0 / dt - 1e-9), math.floor(min(t1, end) / dt + 1e-9) + 1) * dt
        if t1 >= end and (not len(stamps) or stamps[-1] < end):
            stamps = np.append(stamps, end)
        return [(float(t), self._at(float(t))) for t in stamps]

    def _limit(self, tau: float) -> float | None:
        """Safe mode: set where the follower stops, short of the first configuration within
        ``scan_horizon`` of ``tau`` [s] along the path that fills a cell it may not enter; that
        configuration's time [s] (None: none). The samples lie on a grid fixed along the path, so
        the stop does not creep forward from frame to frame."""
        self.tau_limit = math.inf
        if self.allowed is None or self.body is None:
            return None
        assert self.times is not None
        horizon = tau + self.config.scan_horizon
        for when, x in self._samples(tau, horizon):
            if when <= self.scan_clear:  # found in allowed cells by an earlier scan; none has left them since
                continue
            if self.body.in_unknown(x, self.allowed):
                self.tau_limit = when - self.config.lookahead
                return when
            self.scan_clear = when
        if horizon < self.times[-1]:
            self.tau_limit = horizon - self.config.lookahead
        return None

    # --- following --------------------------------------------------------------------------
    def _at(self, tau: float) -> np.ndarray:
        """The path's configuration at ``tau`` [s] along it."""
        path, times = self.path, self.times
        assert path is not None and times is not None
        if tau <= 0 or len(path) == 1:
            return path[0].copy()
        if tau >= times[-1]:
            return path[-1].copy()
        i = int(np.searchsorted(times, tau, side="right")) - 1
        f = (tau - times[i]) / (times[i + 1] - times[i]) if times[i + 1] > times[i] else 1.0
        return path[i] + f * (path[i + 1] - path[i])

    def _follow(self, q: np.ndarray, t: float) -> np.ndarray:
        """Advance along the path by one control period at the scaled velocity limits (not past
        ``tau_limit``): the path's velocity there, plus a pull of ``_GAIN`` of the way back to the
        path. When the last call was more than a period ago (the controller was late), the arm may
        have moved on along the path meanwhile (the last command held) or not (a stop held while
        that command was computed, a plan's): the position on the path moves to the point nearest
        the arm within that much time ahead.
        A command that steered all the way back in one period would overshoot by as many periods as
        it is held, and a late controller would swing the arm ever wider (the self-collision
        measured before, with 160 ms per frame)."""
        T = self.task.period
        assert self.times is not None
        end = float(self.times[-1])
        if self.t_follow is not None and t - self.t_follow > T + 1e-9:
            # late: where along the path (up to that much farther) is the arm now? The command may
            # have been held, moving it on, or have come late itself, a stop held before it
            late = min(t - self.t_follow - T, self.tau_limit - self.tau, end - self.tau)
            ahead = self.tau + np.linspace(0.0, max(late, 0.0), max(2, min(100, math.ceil(late / T) + 1)))
            gaps = [float(np.max(np.abs(self._at(float(x)) - q))) for x in ahead]
            self.tau = float(ahead[int(np.argmin(gaps))])
        self.t_follow = t
        here = self._at(self.tau)
        self.tau = max(self.tau, min(self.tau + T, self.tau_limit, end))
        command = (self._at(self.tau) - here) / T + _GAIN * (here - q) / T
        full = self.vmax / self.config.speed_scale
        return np.clip(command, -full, full)
