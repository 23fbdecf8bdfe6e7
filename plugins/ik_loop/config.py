"""Settings of the IK loop shared by the field planners (:mod:`.loop`).

:class:`IKLoopConfig` holds what every loop planner shares: time step, attraction, damping,
secondary tasks, limits, endings, the stand-off. A planner built on the loop subclasses it and
adds the settings of its repulsion (or step solver).

Units: metres, radians, seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from planbench.errors import InvalidConfigError

__all__ = [
    "IKLoopConfig",
    "DAMPING_MODES",
    "HIERARCHIES",
    "Hierarchy",
    "check_number",
    "repulsion_scale",
    "resolve_hierarchy",
]

DAMPING_MODES = ("fixed", "adaptive")
HIERARCHIES = ("auto", "nullspace", "priority")
RAMP_WITHOUT_REDUNDANCY = (0.0, 1.0)
"""``(onset, full)`` push ratios of the repulsion rows on an arm without redundancy, where they are
the repulsion's only way to the joints and replace the null-space push: on from the field's edge,
fully on at the stand-off, where by definition the push equals the cruising speed (a redundant
arm uses ``priority_onset`` and ``priority_full``)."""


class Hierarchy(NamedTuple):
    """The hierarchy a step uses on one arm (:func:`resolve_hierarchy`)."""

    mode: str
    """``"nullspace"`` or ``"priority"``."""
    onset: float
    """Push ratio [-] where the repulsion rows switch on."""
    full: float
    """Push ratio [-] where they are fully on."""
    orientation_weight: float
    """Weight [-] of the orientation rows against the repulsion rows."""


def resolve_hierarchy(cfg: Any, n_joints: int, redundant: str = "nullspace") -> Hierarchy:
    """The hierarchy of ``cfg`` (an :class:`IKLoopConfig`) on an arm of ``n_joints`` joints.

    ``"auto"`` is chosen from the arm's redundancy ``n_joints - 6`` (at setup). Without redundancy
    the pose task leaves the repulsion no null space, so only the priority rows let it act, and
    they replace it: they ramp from the field's edge to the stand-off
    (:data:`RAMP_WITHOUT_REDUNDANCY`), the same distances in every field since each derives its
    gain from the stand-off. With redundancy the null space carries the repulsion and the rows may
    help only close to obstacles (``priority_onset`` to ``priority_full``), where a push ratio
    means a different distance in each field: ``"auto"`` is then ``redundant``, the planner's
    measured choice (:attr:`~.loop.IKLoopPlanner.auto_hierarchy_redundant`; ``"nullspace"``
    unless measured otherwise). The orientation rows weigh ``orientation_priority`` without
    redundancy, else 1."""
    is_redundant = n_joints > 6
    orientation = 1.0 if is_redundant else float(cfg.orientation_priority)
    onset, full = float(cfg.priority_onset), float(cfg.priority_full)
    if not is_redundant:
        onset, full = RAMP_WITHOUT_REDUNDANCY
    mode = str(cfg.hierarchy)
    if mode == "auto":
        mode = redundant if is_redundant else "priority"
    return Hierarchy(mode, onset, full, orientation)


def repulsion_scale(cfg: Any, n_joints: int, mode: str) -> float:
    """The multiplier of the scene's push on an arm of ``n_joints`` joints whose step uses the
    hierarchy ``mode`` (resolved): ``repulsion_scale_without_redundancy`` where the repulsion
    rows replace the null space (``"priority"`` on 6 joints or fewer), else 1."""
    if n_joints <= 6 and mode == "priority":
        return float(cfg.repulsion_scale_without_redundancy)
    return 1.0


@dataclass(frozen=True)
class IKLoopConfig:
    """Settings of the IK loop shared by the field planners (:mod:`.loop`).

    Stand-off: every repulsion source derives its gain from ``standoff``, so that a point on the
    arm ``standoff`` from a flat wall is pushed away at the attraction's cruising speed
    ``speed_max``: closer than that, the push beats the pull. ``repulsion_gain`` scales that gain
    (2 pushes twice as hard everywhere). One stand-off, whatever the field and whatever the grid
    resolution, keeps the comparison between fields fair and a setting's meaning fixed.
    """

    # --- time and budget -----------------------------------------------------------------
    dt: float = 0.01
    """Integration time step [s]; the trajectory is time-stamped ``t = k * dt``."""
    max_steps: int = 20000
    """Step budget; ``STEP_LIMIT`` when spent (escapes spend it too: 3000 before they existed)."""

    # --- attraction (primary task) -------------------------------------------------------
    speed_max: float = 0.25
    """Cruising speed of the end effector far from the goal, ``v_max`` [m/s]."""
    sigmoid_gain: float = 20.0
    """``k_sigm`` [1/m] of the arctan speed profile ``v_max atan(k_sigm d) / (pi/2)``."""
    position_gain: float = 1.0
    """``k_p`` [-]: weight of the translational attraction."""
    orientation_gain: float = 4.0
    """``k_w`` [1/s]: angular velocity per radian of orientation error."""
    angular_speed_max: float = 1.5
    """Cap on the commanded angular speed ``|k_w omega|`` [rad/s]."""
    goal_tolerance_scale: float = 0.5
    """Success when both pose errors are under this fraction of the problem's tolerances [-]."""

    # --- damped least squares ------------------------------------------------------------
    damping: str = "adaptive"
    """``"fixed"``: ``lambda = damping_factor`` always; ``"adaptive"``: ``lambda = 0`` while the
    manipulability is above ``manipulability_threshold``, rising to ``damping_factor`` at 0."""
    damping_factor: float = 0.05
    """``lambda`` [m] of the damped least squares (the largest value in adaptive mode)."""
    manipulability_threshold: float = 0.02
    """``m0`` [m^3]: adaptive damping switches on below it."""

    # --- repulsion (gain, tool, control points) ----------------------------------------
    standoff: float = 0.10
    """Distance [m] from a flat wall at which a point on the arm is pushed at ``speed_max``."""
    repulsion_gain: float = 1.0
    """Multiplier [-] of the gain derived from ``standoff``: 1 pushes a point ``standoff`` from a
    flat wall at ``speed_max``, 0 turns the repulsion off. The same number means the same push
    whatever the field and the grid resolution (the derived gain is computed for both)."""
    tool_repulsion_gain: float = 0.0
    """Weight [-] of the repulsion added to the primary task: the strongest ``f_i`` among the
    control points carried by the goal frame's joint (hand, fingers) is added to the attraction's
    linear velocity, so the end effector itself bends around obstacles. 0 = the method as specified
    (all repulsion in the null space, where it can never move the end effector)."""
    tool_fade_distance: float = 0.1
    """Within this distance [m] of the goal position the tool repulsion fades linearly to 0: the
    goal pose is collision-free, and a hand that must end next to a shelf would otherwise stop
    short of it."""
    control_point_spacing: float = 0.12
    """Largest distance between control points along a link [m] (automatic placement)."""
    control_points: Any = None
    """Override of the automatic placement: ``{link: [[x, y, z], ...]}`` in the link frame [m];
    an empty list removes a link's points. Other links keep their automatic points."""

    # --- secondary tasks -----------------------------------------------------------------
    manipulability_gain: float = 0.5
    """``k_m`` [rad/s per m^3/rad]: gradient ascent on the manipulability; 0 switches it off."""
    mid_joint_gain: float = 2.0
    """``k_c`` [rad^2/s]: ``qd_c = -k_c (q - q_mid) / (q_max - q_min)^2`` [rad/s]."""
    slowdown_gain: float = 2.0
    """``k_s`` [s/m]: primary-task factor ``s = 1 / (1 + k_s |f|_max)``, ``|f|_max`` the largest
    repulsive speed at a control point [m/s]; 0 switches the slow-down off."""
    slowdown_min: float = 0.2
    """Smallest slow-down factor ``s`` [-]."""
    velocity_scale: float = 1.0
    """Fraction of the robot's joint velocity limits the planner may use [-]."""

    backend: str = "auto"
    """Step arithmetic: ``"numba"`` (one compiled call per step), ``"numpy"`` (the task functions
    composed in Python), ``"auto"`` (numba when installed). Same numbers to rounding."""

    # --- failure detection ---------------------------------------------------------------
    stall_window: float = 1.0
    """Local-minimum window [s] (see :func:`~planbench_plugins.ik_loop.loop.stalled`)."""
    stall_ratio: float = 0.02
    """Smallest relative decrease of the best goal error over one window [-]."""
    rotation_weight: float = 0.1
    """``rho`` [m/rad]: goal error ``e = |p_g - p| + rho * angle`` used for progress."""
    collision_check_every: int = 25
    """Check the robot against the true scene every this many steps while planning (coal; an
    early exit); 0 = never."""
    verify_path: bool = True
    """Before claiming success, certify the whole trajectory against the true scene with the
    harness's checker (:mod:`planbench.checking.certified`), so that success is never claimed on a colliding path."""

    # --- self-collision (:mod:`.self_collision`) ---------------------------------------------
    self_collision: bool = True
    """Push the robot's own links apart (coal's distances between the pairs of its collision model)
    beside the repulsion from the scene, in the same hierarchy. Off: the scene's push only, as the
    method specifies."""
    self_collision_influence: float = 0.05
    """[m] Pairs of the robot's own geometries closer than this are pushed apart."""
    self_collision_gain: float = 3.0
    """[-] The push at contact in units of ``speed_max`` (it falls quadratically to 0 at the
    influence distance); 3 makes a pair at contact a fully active priority row."""

    # --- leaving local minima (:mod:`.escape`) -------------------------------------------------
    escape_attempts: int = 32
    """Escapes per query: when progress stalls, or a collision is found (by the periodic check, or
    by the certified check of a path that reached the goal; the loop then rewinds to the last
    configuration known free), the arm moves in a straight joint-space line to a collision-free
    configuration drawn about ``escape_radius`` away (every other draw part of the way to the goal
    configuration, ``escape_toward_goal``) and the loop resumes from there. 0: the plan ends
    there, as the method specifies. ``info`` reports ``escapes``, ``escape_after``,
    ``escape_steps`` and ``escape_toward_goal``. Chosen on the tuning sets, MotionBenchMaker
    0001-0020 and a UR5 set generated with seed 1 (40 problems, not the shipped seed-0 set), with
    ``matrix-field``: 102/140 and 24/40 with 32 escapes of 100 draws at two scales (20000 steps);
    83 and 21 with 20 draws at one scale; 82 and 16 with 16 escapes (10000 steps); random escapes
    only: 70 and 7; none: 48 and 2."""
    escape_radius: float = 0.7
    """[rad] Standard deviation per joint of an escape's random displacement."""
    escape_draws: int = 100
    """Random configurations tried for one escape before the plan ends (each costs a collision
    test, and a certified check of the straight move when the target is free). With 20, 56 of the
    57 failures on MotionBenchMaker 0001-0020 ended on an escape that found no target, after a
    median 0.17 s of the 5 s budget."""
    escape_scales: int = 2
    """Radii an escape's draws cycle through: ``escape_radius``, half of it, ... (``escape_scales``
    radii in all, each for a pair of draws: one random, one towards the goal); 1: every draw at
    ``escape_radius``. A long straight move rarely stays free in clutter; a shorter one does."""
    escape_toward_goal: bool = True
    """Every other draw of an escape, from the first, is centred part of the way (20-100 %) to the
    problem's goal configuration instead of at the arm's own (when the problem gives one): the pose
    task then resumes in the goal's IK branch, which a Jacobian step cannot reach on an arm without
    redundancy. False: random detours only."""

    escape_backtrack: int = 3
    """Further rewinds [-] when an escape finds no target: the loop rewinds along its own path
    (the trajectory is cut there, as after a collision) ``escape_backtrack_window`` before the
    step it escaped from, then twice as far back as the previous rewind each time (0.5, 1, 2 s with
    the defaults; never before the start, and not once the time limit has passed), and draws again
    from there, so that an arm wedged in clutter (a hand in a shelf) escapes from where it still
    had room. 0: the plan ends at the first escape that finds no target, as before issue 32. A
    query whose escapes all find a target is unchanged by it, so it can only turn such endings into
    later ones: on Panda tuning sets generated with seeds 1-3 (120 problems, 20 s), 5 of
    ``matrix-field``'s 20 failures and 7 of ``edt-field``'s 25 were solved with it."""
    escape_backtrack_window: float = 0.5
    """[s] How far back along the path the first further rewind goes (``escape_backtrack``)."""

    # --- task hierarchy -------------------------------------------------------------------
    hierarchy: str = "auto"
    """Where the repulsion acts. ``"nullspace"``: only in the null space of the 6-D pose task (the
    method as specified; a 6-joint arm has none, so there it does nothing, and the planner warns).
    ``"priority"``: the null-space step plus, for each control point near an obstacle, a task row
    beside the pose task asking it to move away along its push ``n_i^T J_i qd = |f_i|``
    (``n_i = f_i / |f_i|``), activated smoothly by the push (``priority_onset`` to
    ``priority_full``) and weighted ``priority_weight`` against 1 for the position rows, so close
    to an obstacle the push wins over the pose task. ``"auto"``: chosen from the arm's redundancy
    ``n - 6`` at setup: ``"priority"`` without redundancy (the rows are the only way the
    repulsion acts, and they replace it: on from the field's edge, fully on at the stand-off); with
    it, the planner's measured choice (``matrix-field``: ``"priority"``, measured on
    MotionBenchMaker 0001-0020; the other loop planners: ``"nullspace"``; :func:`resolve_hierarchy`)."""
    priority_onset: float = 2.0
    """Push ratio ``|f_i| / speed_max`` [-] below which a point's row is off (1: the push at the
    stand-off from a flat wall; 2: about 3 cm from it with the default field; corners and shelves
    add up). Chosen for the matrix field on MotionBenchMaker 0001-0020 (0.5, 1, 1.5, 2, 3
    measured); other fields push harder close in. On an arm without redundancy the rows ramp from
    0 to 1 instead (they replace the null-space push there)."""
    priority_full: float = 3.0
    """Push ratio [-] at which a point's row is fully on (smoothstep, C1, from ``priority_onset``;
    redundant arms)."""
    priority_weight: float = 10.0
    """Weight [-] of a fully active repulsion row, against 1 for the position rows: above 1 the
    push wins over the pose task where they conflict (0 turns the rows off)."""
    priority_fade_distance: float = 0.1
    """[m] the repulsion rows fade linearly to 0 within this position error of the goal, so a goal
    next to an obstacle (a grasp) stays reachable."""
    repulsion_scale_without_redundancy: float = 0.25
    """Multiplier [-] of the scene's push on an arm without redundancy (6 joints or fewer) in the
    ``"priority"`` hierarchy (``"auto"`` there), on top of ``repulsion_gain``; the self-collision
    push is left as it is. There the push has no null space to act in: each repulsion row is
    obeyed only by giving up the pose task, so a push sized for a redundant arm (which absorbs it
    in its null space) stalls the arm short of the goal again and again. Chosen with
    ``matrix-field`` on a UR5 tuning set (generated with seed 1, 5 problems per family; the
    shipped ``gen:`` set is seed 0 and a test set): solved 9/20 at 1 (the push as on a redundant
    arm), 17/20 at 0.5, 18/20 at 0.25, 15/20 at 0 (no push); a smaller ``standoff`` did as well
    (0.07 m: 17/20, 0.05 m: 19/20) but would move every arm (:func:`repulsion_scale`)."""
    orientation_priority: float = 0.1
    """Weight [-] of the orientation rows in ``"priority"`` mode on arms without redundancy, so
    the order is position, then repulsion, then orientation (1 on redundant arms)."""

    def __post_init__(self) -> None:
        if self.control_points is not None:
            object.__setattr__(self, "control_points", _freeze_points(self.control_points))
        self.validate()

    def validate(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad setting."""
        positive = (
            "dt",
            "speed_max",
            "sigmoid_gain",
            "position_gain",
            "orientation_gain",
            "angular_speed_max",
            "goal_tolerance_scale",
            "standoff",
            "control_point_spacing",
            "tool_fade_distance",
            "velocity_scale",
            "stall_window",
            "rotation_weight",
            "slowdown_min",
            "damping_factor",
            "manipulability_threshold",
        )
        for name in positive:
            check_number(self, name, lambda v: v > 0, "finite and > 0")
        for name in ("tool_repulsion_gain", "manipulability_gain", "mid_joint_gain", "slowdown_gain", "stall_ratio"):
            check_number(self, name, lambda v: v >= 0, "finite and >= 0")
        for name, hi in (("goal_tolerance_scale", 1.0), ("slowdown_min", 1.0), ("velocity_scale", 1.0)):
            check_number(self, name, lambda v, hi=hi: v <= hi, f"<= {hi}")
        check_number(self, "repulsion_gain", lambda v: v >= 0, "finite and >= 0")
        for name in (
            "max_steps",
            "collision_check_every",
            "escape_attempts",
            "escape_draws",
            "escape_scales",
            "escape_backtrack",
        ):
            v = getattr(self, name)
            least = 1 if name in ("max_steps", "escape_draws", "escape_scales") else 0
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise InvalidConfigError(f"{name} must be a whole number >= {least}, got {v!r}")
        check_number(self, "escape_radius", lambda v: v > 0, "finite and > 0")
        check_number(self, "escape_backtrack_window", lambda v: v > 0, "finite and > 0")
        if not isinstance(self.escape_toward_goal, bool):
            raise InvalidConfigError(f"escape_toward_goal must be true or false, got {self.escape_toward_goal!r}")
        check_number(self, "self_collision_influence", lambda v: v > 0, "finite and > 0")
        check_number(self, "self_collision_gain", lambda v: v >= 0, "finite and >= 0")
        if not isinstance(self.self_collision, bool):
            raise InvalidConfigError(f"self_collision must be true or false, got {self.self_collision!r}")
        if not isinstance(self.verify_path, bool):
            raise InvalidConfigError(f"verify_path must be true or false, got {self.verify_path!r}")
        check_number(self, "priority_fade_distance", lambda v: v > 0, "finite and > 0")
        for name in ("priority_onset", "priority_weight", "orientation_priority", "repulsion_scale_without_redundancy"):
            check_number(self, name, lambda v: v >= 0, "finite and >= 0")
        check_number(
            self, "priority_full", lambda v: v > self.priority_onset, f"> priority_onset ({self.priority_onset})"
        )
        for name, choices in (
            ("backend", ("auto", "numba", "numpy")),
            ("damping", DAMPING_MODES),
            ("hierarchy", HIERARCHIES),
        ):
            if getattr(self, name) not in choices:
                raise InvalidConfigError(f"{name} must be one of {choices}, got {getattr(self, name)!r}")

    @property
    def stall_steps(self) -> int:
        """The local-minimum window in steps."""
        return max(1, int(round(self.stall_window / self.dt)))


def check_number(cfg: Any, name: str, ok: Any, what: str) -> None:
    """Raise :class:`InvalidConfigError` unless ``cfg.name`` is a finite number with ``ok(value)``."""
    value = getattr(cfg, name)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidConfigError(f"{name} must be a number, got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(v) or not ok(v):
        raise InvalidConfigError(f"{name} must be {what}, got {value!r}")


def _freeze_points(points: Any) -> tuple[tuple[str, tuple[tuple[float, float, float], ...]], ...]:
    items = points.items() if isinstance(points, Mapping) else points
    out = []
    try:
        for link, pts in items:
            row = []
            for p in pts if isinstance(pts, Sequence) or hasattr(pts, "__len__") else ():
                xyz = tuple(float(x) for x in p)
                if len(xyz) != 3 or not all(math.isfinite(x) for x in xyz):
                    raise ValueError(f"{xyz}")
                row.append(xyz)
            out.append((str(link), tuple(row)))
    except (TypeError, ValueError) as exc:
        raise InvalidConfigError(
            "control_points must map link names to lists of [x, y, z] points [m] in the link frame, "
            f"got {points!r} ({exc})"
        ) from None
    return tuple(out)
