"""The IK loop shared by every field planner: attraction, null-space repulsion, limits, endings.

docs/method.md, section 4. Per step ``k`` (``t = k dt``), from ``q``:

1. kinematics: goal-frame pose ``(p, R)``, its Jacobian ``J`` (LOCAL_WORLD_ALIGNED), the spatial
   Jacobian ``S`` and the control points ``p_i`` (:mod:`.kinematics`);
2. repulsion: the planner's :class:`Repulsion` gives repulsive velocities ``f_i`` [m/s] at points
   on the arm (the matrix field at the control points, a distance field's gradient, coal's witness
   points...), mapped to ``qd_rep = sum_i J_i^T f_i``. This is the only part that differs between
   ``matrix-field``, ``edt-field`` and ``distance-field``, so comparing them compares the fields;
3. attraction ``v_att`` (arctan speed profile, quaternion-log orientation error); the strongest
   ``f_i`` on the tool (points carried by the goal frame's joint), times ``tool_repulsion_gain``
   (fading to 0 within ``tool_fade_distance`` of the goal), may be added to its linear part;
4. manipulability gradient ``qd_m``, mid-joint task ``qd_c``;
5. ``qd_1 = J_dls^+ v_att`` and ``N (qd_rep + qd_m + qd_c)`` with one factorisation;
6. ``qd = s qd_1 + N (...)``, ``s`` the slow-down factor;
7. velocity limits (one factor, direction kept), then position limits (per joint);
8. ``q <- q + qd dt``.

Steps 3-7 are :meth:`IKLoopPlanner.solve_step`; ``matrix-field-qp`` replaces only that method.
Steps 1-7 from any configuration are a :class:`~.stepper.LoopStepper`, which
:meth:`IKLoopPlanner.prepare` builds for a robot, a goal and a repulsion: ``plan`` integrates it,
a controller calls it once per tick (:mod:`planbench_plugins.controllers`).

Endings (:class:`~planbench.planner.PlanStatus`):

- ``SUCCESS``: both pose errors under ``goal_tolerance_scale`` times the problem's tolerances, and
  the whole trajectory free of collision with the true geometry (checked densely, see below);
- ``LOCAL_MINIMUM``: progress stalls, see :func:`stalled`;
- ``STEP_LIMIT``: ``max_steps`` steps taken;
- ``TIMEOUT``: the time limit passed (checked every 16 steps);
- ``COLLISION``: the exact checker (coal, the scene's true geometry) finds the arm in collision.
  A field sees the voxel grid (or only nearby points), not the true geometry, so the planner
  checks the true geometry every ``collision_check_every`` steps while it runs (an early exit) and,
  before it claims success, along the whole trajectory with the harness's certified checker
  (``verify_path``). The returned path then ends at the first configuration found in collision.

The result is a trajectory: ``path[k]`` at ``times[k] = k dt``, with velocities within the limits
by construction, and ``target="pose"``. ``info`` holds per-step diagnostics as arrays (one entry
per path row): ``position_error`` [m], ``orientation_error`` [rad], ``repulsion`` (largest
``|f_i|`` [m/s]), ``manipulability`` [m^3], ``slowdown`` [-], ``damping`` [m], plus what
:attr:`IKLoopPlanner.extra_diagnostics` adds; and ``steps``, ``field_gain`` (the gain in use, in the repulsion's units),
``n_control_points``.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Pose, Problem
from planbench.runtime import backend as field_backend
from planbench.scene import Scene
from planbench.validate import verdict_checker
from planbench_plugins.ik_loop import fast
from planbench_plugins.ik_loop.config import IKLoopConfig, repulsion_scale, resolve_hierarchy
from planbench_plugins.ik_loop.control_points import ControlPoints, place_control_points
from planbench_plugins.ik_loop.escape import escape_motion
from planbench_plugins.ik_loop.kinematics import ArmKinematics
from planbench_plugins.ik_loop.self_collision import SelfCollisionPush
from planbench_plugins.ik_loop.stepper import LoopStepper

__all__ = ["IKLoopPlanner", "Repulsion", "StepFailure", "StepInputs", "stalled", "DIAGNOSTICS"]

log = logging.getLogger(__name__)

DIAGNOSTICS = ("position_error", "orientation_error", "repulsion", "manipulability", "slowdown", "damping")
"""The per-step diagnostics every loop planner records, in the order of the step's ``diag`` array."""


def stalled(best_error: Sequence[float] | np.ndarray, k: int, window: int, ratio: float) -> bool:
    """The local-minimum test: True when progress stalls over a window.

    ``best_error[k]`` is the smallest goal error ``e = |p_g - p| + rho * angle`` [m] seen in steps
    ``0..k``. Progress stalls when, over the last ``window`` steps, that best error fell by less
    than ``ratio`` of its value at the window's start: ``best[k - window] - best[k] <
    ratio * best[k - window]``. The test is relative so the exponential approach to the goal
    (error shrinking by a constant factor per second) never counts as a stall, while an arm held
    by the repulsion far from the goal does. Never True before ``window`` steps.
    """
    if k < window:
        return False
    before = best_error[k - window]
    return bool(before - best_error[k] < ratio * before)


class StepFailure(Exception):
    """Raised by :meth:`IKLoopPlanner.solve_step` when there is no valid step (e.g. an infeasible
    QP). The loop ends the plan with ``status`` and ``message``, keeps the trajectory up to the
    last valid configuration, and adds ``info`` (JSON-friendly) to the result's ``info``."""

    def __init__(self, status: PlanStatus, message: str, info: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.info = dict(info or {})


class Repulsion(Protocol):
    """Where one step's repulsion comes from.

    ``forces(kin)`` returns ``(points, F, support, joint)`` for the arm at ``kin``'s configuration:
    ``points`` (M, 3) world points on the arm [m], ``F`` (M, 3) repulsive velocities there [m/s],
    ``support`` (M, n) 1.0 where joint ``k`` moves point ``i``, ``joint`` (M,) the pinocchio joint
    carrying each point. Returned arrays may be reused buffers: they are read before the next call.
    A source that returns the same arrays every step (``kin.points``, ``kin.support``, its own
    ``F`` filled in place) lets the loop call its compiled step without numba's type dispatch.
    ``gain`` is the gain in use (reported in the result's ``info``).
    """

    @property
    def gain(self) -> float: ...  # read-only here: an attribute or a property (the controllers' live holder)

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...


class ZeroRepulsion:
    """No obstacles in reach: no repulsion."""

    gain = 0.0

    def __init__(self) -> None:
        self._zeros = np.zeros((0, 3))

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self._zeros.shape != kin.points.shape:
            self._zeros = np.zeros_like(kin.points)
        return kin.points, self._zeros, kin.support, kin.cp_joint


class ScaledRepulsion:
    """``inner``'s repulsion times ``scale`` (the push on an arm without redundancy,
    :func:`.config.repulsion_scale`), into a buffer of its own that keeps its identity, so the
    loop's compiled step stays bound to it."""

    def __init__(self, inner: Repulsion, scale: float) -> None:
        self.inner, self.scale = inner, float(scale)
        self._F = np.zeros((0, 3))

    @property
    def gain(self) -> float:
        return float(self.inner.gain) * self.scale

    def restart(self) -> None:
        restart = getattr(self.inner, "restart", None)
        if callable(restart):
            restart()

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        points, F, support, joint = self.inner.forces(kin)
        if self._F.shape != F.shape:
            self._F = np.empty_like(F)
        np.multiply(F, self.scale, out=self._F)
        return points, self._F, support, joint


class StepInputs:
    """What :meth:`IKLoopPlanner.solve_step` reads besides the kinematics (fixed for one query;
    a controller moves the goal between steps with :meth:`.LoopStepper.aim`)."""

    def __init__(
        self,
        p_goal: np.ndarray,
        R_goal: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        qd_max: np.ndarray,
        tool_joint: int,
        params: fast.StepParams,
    ) -> None:
        self.p_goal, self.R_goal = p_goal, R_goal
        self.lower, self.upper, self.qd_max = lower, upper, qd_max
        self.tool_joint = tool_joint
        self.params = params


class IKLoopPlanner(Planner):
    """Base of the field planners: the loop of the module docstring around a :class:`Repulsion`.

    Subclasses give :meth:`make_repulsion` (and may replace :meth:`solve_step`).
    """

    name = "ik-loop"
    Config = IKLoopConfig
    extra_diagnostics: tuple[str, ...] = ()
    """Names of per-step diagnostics a subclass's ``solve_step`` writes after :data:`DIAGNOSTICS`."""
    auto_hierarchy_redundant = "nullspace"
    """What ``hierarchy="auto"`` is on a redundant arm (:func:`.config.resolve_hierarchy`): a
    planner whose repulsion was measured better with the priority rows says ``"priority"``."""

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self._stepper: LoopStepper | None = None
        self._problem: Problem | None = None  # the problem of the last setup (None after a bare prepare)
        self._checker: CollisionChecker | None = None
        self._path = np.empty((0, 0))  # the query's trajectory, written in place by _advance
        self._advance: Callable[[int], None] = lambda k: None

    # --- for subclasses ---------------------------------------------------------------------
    def make_repulsion(self, problem: Problem, points: ControlPoints) -> Repulsion:
        """Build the repulsion source for ``problem`` (untimed setup)."""
        raise NotImplementedError

    def solve_step(
        self,
        kin: ArmKinematics,
        q: np.ndarray,
        inputs: StepInputs,
        points: np.ndarray,
        F: np.ndarray,
        support: np.ndarray,
        tool: np.ndarray,
        qd_out: np.ndarray,
        diag: np.ndarray,
    ) -> None:
        """Steps 3-7 of the module docstring: write the joint velocity into ``qd_out`` and the
        diagnostics into ``diag``. Default: the closed-form DLS step (compiled or numpy)."""
        self._step(
            kin.S,
            kin.J,
            kin.p,
            kin.R,
            inputs.p_goal,
            inputs.R_goal,
            q,
            inputs.lower,
            inputs.upper,
            inputs.qd_max,
            points,
            F,
            support,
            kin.descendants,
            tool,
            inputs.params,
            qd_out,
            diag,
        )

    def plot_result(self, problem: Problem, result: PlanResult, path_png: Any) -> Any:
        """The planner's figure of a result (``planbench plan ... --plot out.png``): the arm with
        its repulsion, the end-effector path, the diagnostics (:mod:`.plots`; matplotlib is
        imported on use, it costs start-up that planning does not need)."""
        from planbench_plugins.ik_loop.plots import plot_result

        return plot_result(problem, result, path_png, planner=self)

    # --- setup (untimed by the harness, reported as setup time) ------------------------------
    @property
    def use_numba(self) -> bool:
        backend = self.config.backend
        return backend == "numba" or (backend == "auto" and field_backend.resolve("auto") == "numba")

    def hierarchy_for(self, n_joints: int) -> str:
        """The hierarchy (``"nullspace"`` or ``"priority"``) on an arm of ``n_joints`` joints: the
        setting, ``"auto"`` chosen from the arm's redundancy (:func:`.config.resolve_hierarchy`)."""
        return resolve_hierarchy(self.config, n_joints, self.auto_hierarchy_redundant).mode

    def setup(self, problem: Problem) -> None:
        """Place control points, build the repulsion source, :meth:`prepare` the loop on them, and
        the collision checker and trajectory buffer of the queries."""
        cfg = self.config
        robot = problem.robot
        self._problem = None
        points = place_control_points(robot, cfg.control_point_spacing, self.control_point_overrides(robot))
        checker = None
        if cfg.collision_check_every > 0 or cfg.verify_path:
            checker = CollisionChecker(robot, problem.scene)
        repulsion = self.make_repulsion(problem, points)
        stepper = self.prepare(robot, problem.goal.pose, repulsion, start=problem.start, points=points)
        path = np.empty((cfg.max_steps + 1, robot.nq))  # plan returns a copy
        args = (stepper.q, stepper.qd, cfg.dt, stepper.inputs.lower, stepper.inputs.upper, path)
        advance = fast.bind(fast.compiled().advance, *args, 0) if self.use_numba else fast.advance_numpy
        self._advance = functools.partial(advance, *args)  # (k): q <- clip(q + qd dt); path[k] = q
        self._path, self._checker, self._problem = path, checker, problem

    def prepare(
        self,
        robot: Any,
        goal: Pose,
        repulsion: Repulsion,
        *,
        start: np.ndarray | None = None,
        points: ControlPoints | None = None,
    ) -> LoopStepper:
        """The loop's step for ``robot`` steering ``goal.frame`` to ``goal`` with ``repulsion``, as
        a :class:`~.stepper.LoopStepper` (also :attr:`stepper` from now on).

        ``points``: the control points (default: placed from the settings and the robot's
        ``[control_points]``). The repulsion is wrapped in the self-collision push when
        :meth:`pushes_off_itself`. The kinematics, step inputs and buffers are made here, the
        repulsion asked and one step taken at ``start`` (default: the robot's home), so that
        compilation (or loading numba's cache), first-call costs and the binding of the compiled
        step stay out of the timed steps. A start without a valid step (:class:`StepFailure`) is
        left for the first real step to report."""
        cfg = self.config
        n = robot.nq
        q = np.array(robot.home if start is None else start, dtype=float)
        if q.shape != (n,):
            raise ValueError(f"{self.name}: start has shape {q.shape}, robot {robot.name!r} has {n} joints")
        if points is None:
            points = place_control_points(robot, cfg.control_point_spacing, self.control_point_overrides(robot))
        hierarchy = self.hierarchy_for(n)
        self._step = fast.compiled().step if self.use_numba else fast.step_numpy
        warnings = self._warnings(robot, hierarchy, repulsion)
        scale = repulsion_scale(cfg, n, hierarchy) if type(self).solve_step is IKLoopPlanner.solve_step else 1.0
        if scale != 1.0 and not isinstance(repulsion, ZeroRepulsion):
            repulsion = ScaledRepulsion(repulsion, scale)
        if self.pushes_off_itself():
            push = SelfCollisionPush(
                repulsion,
                robot,
                Scene(name="own links"),  # the push measures the robot's own pairs only
                influence=cfg.self_collision_influence,
                gain=cfg.self_collision_gain,
                speed_max=cfg.speed_max,
            )
            repulsion = push if push.n_pairs else repulsion
        frame_id = robot.frame_id(goal.frame)
        kin = ArmKinematics(robot, frame_id, points, compiled=self.use_numba)
        kin.update(q)
        inputs = self._inputs(robot, goal, frame_id)
        at, F, support, joint = repulsion.forces(kin)
        tool = np.flatnonzero(joint == inputs.tool_joint)
        qd = np.zeros(n)
        dg = np.zeros(len(DIAGNOSTICS) + len(self.extra_diagnostics))
        solve = self._step_function(kin, q, inputs, qd, dg, at, F, support, tool)
        stepper = LoopStepper(robot, kin, repulsion, inputs, q, qd, dg, solve, joint, tool, hierarchy, tuple(warnings))
        self._stepper, self._problem = stepper, None
        try:
            self.solve_step(kin, q, inputs, at, np.zeros_like(F), support, tool, qd, dg)
        except StepFailure:
            pass  # the first step of a plan (or a controller's) meets it again and reports it
        return stepper

    @property
    def stepper(self) -> LoopStepper:
        """The loop's step prepared by the last :meth:`setup` or :meth:`prepare`."""
        if self._stepper is None:
            raise RuntimeError(f"{self.name}: call setup(problem) or prepare(...) first")
        return self._stepper

    @property
    def problem(self) -> Problem | None:
        """The problem of the last :meth:`setup` (None before one, and after a bare :meth:`prepare`)."""
        return self._problem

    def pushes_off_itself(self) -> bool:
        """Whether the self-collision push (:mod:`.self_collision`) is added to the repulsion: the
        ``self_collision`` setting (a planner that avoids self-collision otherwise says False)."""
        return bool(self.config.self_collision)

    def _warnings(self, robot: Any, hierarchy: str, repulsion: Repulsion) -> list[str]:
        """What the configuration cannot do on this arm (logged once per preparation, and reported in
        every result's ``info["warnings"]``)."""
        out = []
        n = robot.nq
        nullspace_step = type(self).solve_step is IKLoopPlanner.solve_step
        if nullspace_step and hierarchy == "nullspace" and n <= 6 and not isinstance(repulsion, ZeroRepulsion):
            out.append(
                f"robot {robot.name!r} has {n} joints: the 6-D pose task leaves no null space, so the "
                "repulsion, projected into it, cannot move the arm (hierarchy='priority' or 'auto' lets it act)"
            )
        for text in out:
            log.warning("%s: %s", self.name, text)
        return out

    def _step_function(
        self,
        kin: ArmKinematics,
        q: np.ndarray,
        inputs: StepInputs,
        qd: np.ndarray,
        dg: np.ndarray,
        points: np.ndarray,
        F: np.ndarray,
        support: np.ndarray,
        tool: np.ndarray,
    ) -> Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], None]:
        """:meth:`solve_step` on the query's buffers, as a function of what the repulsion returns.

        The default step with numba calls the compiled step bound to the types of these arrays
        (:func:`.fast.bind`): numba's per-call check of 18 argument types costs more than the
        step's arithmetic. The bound call is taken while the repulsion returns the arrays given
        here (sources that fill buffers do); other arrays go through :meth:`solve_step`."""
        solve_step = self.solve_step

        def general(points: np.ndarray, F: np.ndarray, support: np.ndarray, tool: np.ndarray) -> None:
            solve_step(kin, q, inputs, points, F, support, tool, qd, dg)

        if not self.use_numba or type(self).solve_step is not IKLoopPlanner.solve_step:
            return general
        args = (kin.S, kin.J, kin.p, kin.R, inputs.p_goal, inputs.R_goal, q, inputs.lower, inputs.upper)
        qd_max, desc, prm = inputs.qd_max, kin.descendants, inputs.params
        entry = fast.bind(self._step, *args, qd_max, points, F, support, desc, tool, prm, qd, dg)
        S, J, p, R, p_goal, R_goal, _, lower, upper = args
        points0, F0, support0, tool0 = points, F, support, tool

        def bound(points: np.ndarray, F: np.ndarray, support: np.ndarray, tool: np.ndarray) -> None:
            if points is points0 and F is F0 and support is support0 and tool is tool0:
                entry(S, J, p, R, p_goal, R_goal, q, lower, upper, qd_max, points, F, support, desc, tool, prm, qd, dg)
            else:
                solve_step(kin, q, inputs, points, F, support, tool, qd, dg)

        return bound

    def _inputs(self, robot: Any, goal: Pose, frame_id: int) -> StepInputs:
        """The step's inputs; the goal's arrays are copies, which :meth:`.LoopStepper.aim` writes."""
        return StepInputs(
            np.array(goal.position, dtype=float),
            np.array(goal.rotation, dtype=float),
            np.asarray(robot.lower, dtype=float),
            np.asarray(robot.upper, dtype=float),
            self.config.velocity_scale * np.asarray(robot.velocity_limit, dtype=float),
            int(robot.model.frames[frame_id].parentJoint),
            fast.step_params(self.config, robot.nq, self.auto_hierarchy_redundant),
        )

    def control_point_overrides(self, robot: Any) -> list[tuple[str, Any]]:
        """Per-link control points: the robot's (``[control_points]`` in ``robots/<name>.toml``),
        then the planner settings' ``control_points`` on top (a link named in both takes the
        settings' points)."""
        merged = dict(robot.settings.control_points)
        merged.update(dict(self.config.control_points or ()))
        return list(merged.items())

    @property
    def control_points(self) -> ControlPoints | None:
        """The control points of the prepared loop (None before :meth:`setup` or :meth:`prepare`)."""
        return None if self._stepper is None else self._stepper.control_points

    def repulsion_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(points, F)``: the points on the arm at ``q`` where the repulsion acts [m] and the
        repulsive velocities there [m/s] (for plots and inspection; :meth:`.LoopStepper.forces_at`)."""
        return self.stepper.forces_at(q)

    # --- the timed query ---------------------------------------------------------------------
    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        if self._problem is not problem:
            self.setup(problem)
        stepper = self.stepper
        cfg = self.config
        t_start = time.perf_counter()
        kin, inputs, q, dg = stepper.kin, stepper.inputs, stepper.q, stepper.diag
        q[:] = problem.start  # advanced in place, copied into path every step
        stepper.restart()  # the same answer however the previous query ended
        tol_p = cfg.goal_tolerance_scale * problem.tolerances.position
        tol_r = cfg.goal_tolerance_scale * problem.tolerances.orientation
        dt = cfg.dt
        repulsion: Repulsion = stepper.repulsion
        checker = self._checker
        check_every = cfg.collision_check_every
        window = cfg.stall_steps
        n_max = cfg.max_steps + 1
        names = DIAGNOSTICS + self.extra_diagnostics
        path = self._path
        diag = np.full((n_max, len(names)), np.nan)
        best: list[float] = []  # best[k]: the smallest goal error in steps 0..k
        budget_spent = PlanStatus.STEP_LIMIT, f"step budget of {cfg.max_steps} steps spent"
        status, message = budget_spent
        rho = cfg.rotation_weight
        last_joint, tool = stepper.joint, stepper.tool
        failure: dict[str, Any] = {}
        update, forces, step, advance = kin.update, repulsion.forces, stepper.solve, self._advance
        stall_ratio = cfg.stall_ratio
        best_k = np.inf
        escapes: list[tuple[str, int, bool]] = []  # (what it escaped, the step it left from, towards the goal)
        since = 0  # the step the last escape ended on: stalls are judged from there
        verified = False  # the path so far certified free (by a check before an escape could fire)
        k = 0  # the step (bound before escape, which rebinds it)
        back_window = max(1, int(round(cfg.escape_backtrack_window / dt)))
        # how far each try of an escape rewinds beyond the previous one, in steps: 0, w, w, 2w, 4w...
        backtrack_steps = [0] + [back_window * 2 ** max(0, i - 1) for i in range(cfg.escape_backtrack)]

        def escape(after: str, frm: int) -> bool:
            """Rewind to step ``frm`` and escape from there (:meth:`_escape`); when no target is
            found there, rewind further, ``escape_backtrack`` times, each twice as far back as the
            last (from ``escape_backtrack_window`` before ``frm``, never before step 0), and try
            again from each. False when no escape is left or none was found (the loop then ends as
            it would have)."""
            nonlocal k, best_k, since, status, message
            if checker is None or len(escapes) >= cfg.escape_attempts:
                return False
            saved = q.copy()
            moved, toward = 0, False
            for back in backtrack_steps:
                if back and (frm == 0 or time.perf_counter() - t_start > time_limit):
                    break
                frm = max(0, frm - back)
                q[:] = path[frm]
                moved, toward = self._escape(q, rng, checker, inputs, path, diag, frm, n_max)
                if moved:
                    break
            if not moved:
                q[:] = saved
                return False
            escapes.append((after, frm, toward))
            del best[frm + 1 :]
            best.extend([np.inf] * (moved - 1))  # best[i] stays the best of step i
            k = since = frm + moved
            best_k = np.inf
            status, message = budget_spent  # what the loop ends on if nothing else ends it
            return True

        path[0] = q
        while True:
            update(q)
            points, F, support, joint = forces(kin)
            if joint is not last_joint:  # sources on fixed control points return the same array
                tool, last_joint = np.flatnonzero(joint == inputs.tool_joint), joint
            try:
                step(points, F, support, tool)
            except StepFailure as exc:  # no valid step from q: q is the last configuration
                status, message, failure = exc.status, f"step {k}: {exc.message}", exc.info
                diag[k] = np.nan
                break
            diag[k] = dg
            err_p, err_r = dg.item(0), dg.item(1)
            best_k = min(err_p + rho * err_r, best_k)
            best.append(best_k)
            if checker is not None and check_every > 0 and k % check_every == 0 and k > 0 and checker.in_collision(q):
                status, message = PlanStatus.COLLISION, f"the arm is in collision at step {k} (t = {k * dt:.2f} s)"
                if escape("collision", max(0, k - check_every)):  # from the last configuration found free
                    continue
                break
            if err_p <= tol_p and err_r <= tol_r:
                status, message = PlanStatus.SUCCESS, f"goal reached in {k} steps"
                if checker is not None and len(escapes) < cfg.escape_attempts:
                    # certified now, so that a collision can still be escaped (else after the loop)
                    hit = self._first_collision(checker, problem, path[: k + 1])
                    verified = hit is None
                    if hit is not None and escape("collision", max(0, hit - max(1, check_every))):
                        continue
                break
            if k - since >= window and stalled(best, k, window, stall_ratio):
                status = PlanStatus.LOCAL_MINIMUM
                message = (
                    f"local minimum: the goal error fell by less than {cfg.stall_ratio:.0%} over "
                    f"{cfg.stall_window:g} s (position error {err_p * 1000:.1f} mm, "
                    f"orientation error {err_r:.3f} rad)"
                )
                if escape("local_minimum", k):
                    continue
                break
            if k >= cfg.max_steps:
                break
            if k % 16 == 0 and time.perf_counter() - t_start > time_limit:
                status, message = PlanStatus.TIMEOUT, f"time limit of {time_limit:g} s reached after {k} steps"
                break
            advance(k + 1)
            k += 1
        n = k + 1
        if checker is not None and status is not PlanStatus.COLLISION and not verified:
            hit = self._first_collision(checker, problem, path[:n])
            if hit is not None:
                n = hit + 1
                status, message = (
                    PlanStatus.COLLISION,
                    (
                        f"the arm is in collision at step {hit} "
                        f"(t = {hit * dt:.2f} s), found by the certified path check"
                    ),
                )
        info: dict[str, Any] = {name: diag[:n, i].copy() for i, name in enumerate(names)}
        info.update(failure)
        info.update(steps=n - 1, dt=dt, field_gain=repulsion.gain, n_control_points=len(stepper.control_points))
        info["hierarchy"] = stepper.hierarchy
        info["escapes"] = len(escapes)
        info["escape_after"] = [what for what, _, _ in escapes]
        info["escape_steps"] = [step for _, step, _ in escapes]
        info["escape_toward_goal"] = [toward for _, _, toward in escapes]
        if stepper.warnings:
            info["warnings"] = list(stepper.warnings)
        return PlanResult(status, path[:n].copy(), np.arange(n) * dt, target="pose", message=message, info=info)

    def escape_target_ok(self, q: np.ndarray) -> bool:
        """Whether an escape may end at ``q`` (free of collision already checked): a planner with a
        stricter notion of free than the true geometry (``matrix-field-qp``'s safety distance on
        convex hulls) refuses targets that its next step could not start from."""
        return True

    def _escape(
        self,
        q: np.ndarray,
        rng: np.random.Generator,
        checker: Any,
        inputs: StepInputs,
        path: np.ndarray,
        diag: np.ndarray,
        k: int,
        n_max: int,
    ) -> tuple[int, bool]:
        """Move from ``q`` (= ``path[k]``) to a free configuration nearby
        (:func:`.escape.escape_motion`): the motion is written to ``path[k + 1 :]`` (diagnostics NaN),
        ``q`` set to its end; returns its number of steps (0 when no escape was found or the step
        budget cannot hold it) and whether its target was drawn towards the goal configuration."""
        cfg = self.config
        problem = self._problem
        assert problem is not None
        certified = verdict_checker(problem)

        def segment_free(a: np.ndarray, b: np.ndarray) -> bool:
            return bool(certified.check_path(np.stack((a, b))).free)

        def refused(target: np.ndarray) -> bool:
            return bool(checker.in_collision(target)) or not self.escape_target_ok(target)

        goal = problem.goal.q
        motion, _, toward = escape_motion(
            q.copy(),
            rng,
            refused,
            segment_free,
            inputs.lower,
            inputs.upper,
            inputs.qd_max,
            cfg.dt,
            cfg.escape_radius,
            cfg.escape_draws,
            goal=None if goal is None else np.asarray(goal, dtype=float),
            toward_goal=cfg.escape_toward_goal,
            scales=cfg.escape_scales,
        )
        if motion is None or k + len(motion) >= n_max:
            return 0, False
        m = len(motion)
        path[k + 1 : k + 1 + m] = motion
        diag[k + 1 : k + 1 + m] = np.nan
        q[:] = motion[-1]
        return m, bool(toward)

    def _first_collision(self, checker: Any, problem: Problem, path: np.ndarray) -> int | None:
        """The first step whose segment (or end) is not proven free, or None. With ``verify_path``
        the whole trajectory, certified as the harness certifies it, else only the last configuration."""
        if not self.config.verify_path:
            return len(path) - 1 if checker.in_collision(path[-1]) else None
        verdict = verdict_checker(problem).check_path(path)
        if verdict.free:
            return None
        return max(0, verdict.segment) + (1 if verdict.fraction > 0 else 0)
