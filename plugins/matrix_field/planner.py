"""The matrix-field planner: IK steps towards the goal pose, repulsion in the null space.

METHOD.md section 4. Per step ``k`` (``t = k dt``), from ``q``:

1. kinematics: goal-frame pose ``(p, R)``, its Jacobian ``J`` (LOCAL_WORLD_ALIGNED), the spatial
   Jacobian ``S`` and the control points ``p_i`` (:mod:`.kinematics`);
2. attraction ``v_att`` (arctan speed profile, quaternion-log orientation error);
3. repulsion ``f_i = k_rep F(p_i)`` from the matrix field, ``qd_rep = sum_i J_i^T f_i``; the
   strongest ``f_i`` among the tool's points (carried by the goal frame's joint), times
   ``tool_repulsion_gain`` (fading to 0 within ``tool_fade_distance`` of the goal), is added to
   ``v_att``'s linear part. This is a choice beyond METHOD.md:
   in the null space alone the repulsion cannot move the end effector, so the hand would drive
   straight into anything on the straight line to the goal;
4. manipulability gradient ``qd_m``, mid-joint task ``qd_c``;
5. ``qd_1 = J_dls^+ v_att`` and ``N (qd_rep + qd_m + qd_c)`` with one factorisation;
6. ``qd = s qd_1 + N (...)``, ``s`` the slow-down factor;
7. velocity limits (one factor, direction kept), then position limits (per joint);
8. ``q <- q + qd dt``.

Endings (:class:`~planbench.planner.PlanStatus`):

- ``SUCCESS``: both pose errors under ``goal_tolerance_scale`` times the problem's tolerances;
- ``LOCAL_MINIMUM``: progress stalls, see :func:`stalled`;
- ``STEP_LIMIT``: ``max_steps`` steps taken;
- ``TIMEOUT``: the time limit passed (checked every 16 steps);
- ``COLLISION``: the exact checker (coal, the scene's true geometry) finds the arm in collision.
  The field only sees the voxel grid, so the planner checks the true geometry every
  ``collision_check_every`` steps and at the end (0: never; the harness validates every path
  densely anyway). The returned path then ends at the first configuration found in collision.

The result is a trajectory: ``path[k]`` at ``times[k] = k dt``, with velocities within the limits
by construction, and ``target="pose"``. ``info`` holds per-step diagnostics as arrays (one entry
per path row): ``position_error`` [m], ``orientation_error`` [rad], ``repulsion`` (largest
``|f_i|`` [m/s]), ``manipulability`` [m^3], ``slowdown`` [-], ``damping`` [m]; plus ``steps``,
``repulsion_gain`` and ``n_control_points``.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem
from planbench_plugins.matrix_field import fast
from planbench_plugins.matrix_field.config import MatrixFieldConfig
from planbench_plugins.matrix_field.control_points import ControlPoints, place_control_points
from planbench_plugins.matrix_field.kinematics import ArmKinematics

__all__ = ["MatrixFieldPlanner", "stalled", "wall_field", "repulsion_gain", "build_scene_field"]

log = logging.getLogger(__name__)


def stalled(best_error: np.ndarray, k: int, window: int, ratio: float) -> bool:
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


def wall_field(kernels: Any, distance: float) -> float:
    """Field magnitude at ``distance`` [m] from the face of a flat, one-cell-thick wall.

    Evaluated with the field module itself (lazy window sums, trilinear interpolation) on a plane
    wide enough to fill the kernel across its axis. The point lies on a cell-centre line, so the
    value is the kernel's own: ``|P(d)| (sum T)^2`` between cell centres.
    """
    from planbench.field import lazy_field
    from planbench.occupancy import OccupancyGrid

    r = kernels.resolution
    side = 2 * kernels.support + 3
    data = np.zeros((1, side, side))
    data[0] = 1.0
    origin = np.array([-0.5 * r, -(side / 2) * r, -(side / 2) * r])  # cell (0, c, c) centred at 0
    grid = OccupancyGrid(data, origin, r)
    point = np.array([[-(0.5 * r + distance), 0.0, 0.0]])
    return float(abs(lazy_field(grid, kernels, point)[0, 0]))


def repulsion_gain(config: MatrixFieldConfig, kernels: Any) -> float:
    """``k_rep`` [m/s per field unit]: ``config.repulsion_gain``, or ``speed_max / F_wall(standoff)``."""
    if config.repulsion_gain is not None:
        return float(config.repulsion_gain)
    f = wall_field(kernels, config.standoff)
    if f <= 0:
        return 0.0
    return config.speed_max / f


def build_scene_field(problem: Problem, config: MatrixFieldConfig) -> tuple[Any, Any, Any]:
    """``(grid, kernels, field)`` for a problem: the scene voxelized over the robot's reach.

    Bounds: the scene's bounding box grown by the kernel's reach and one cell, cut to the cube of
    half-side ``robot.reach() + kernel_reach`` around the base (nothing farther can touch the arm
    or push a control point). ``field`` is ``None`` in ``"lazy"`` mode or without obstacles; the
    grid is ``None`` without obstacles in reach.
    """
    from planbench.field import KernelSpec, full_field, surface_grid
    from planbench.occupancy import OccupancyGrid

    kernels = KernelSpec(reach=config.kernel_reach, profile=config.kernel_profile,
                         taper=config.kernel_taper).build(config.grid_resolution)
    if len(problem.scene) == 0:
        return None, kernels, None
    grow = kernels.reach + config.grid_resolution
    half = problem.robot.reach() + grow
    lo, hi = problem.scene.aabb()
    lo = np.maximum(np.asarray(lo) - grow, -half)
    hi = np.minimum(np.asarray(hi) + grow, half)
    if np.any(hi <= lo):
        return None, kernels, None
    grid = OccupancyGrid.from_scene(problem.scene, config.grid_resolution, bounds=(lo, hi), rule="any")
    if config.surface_only:
        grid = surface_grid(grid)
    field = full_field(grid, kernels, dtype=np.float64) if config.field_mode == "full" else None
    return grid, kernels, field


class MatrixFieldPlanner(Planner):
    """Matrix-field IK planner (``matrix-field``). See the module docstring and
    :class:`~planbench_plugins.matrix_field.config.MatrixFieldConfig`."""

    name = "matrix-field"
    Config = MatrixFieldConfig

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self._prepared: dict[str, Any] | None = None

    def plot_result(self, problem: Problem, result: PlanResult, path_png: Any) -> Any:
        """The planner's figure of a result (``planbench plan ... --plot out.png``)."""
        from planbench_plugins.matrix_field.plots import plot_result

        return plot_result(problem, result, path_png, config=self.config)

    # --- setup (untimed by the harness, reported as setup time) -----------------------------
    def setup(self, problem: Problem) -> None:
        """Voxelize the scene, build the kernels and (full mode) the whole field, place control
        points and derive the repulsion gain."""
        cfg = self.config
        grid, kernels, field = build_scene_field(problem, cfg)
        points = place_control_points(problem.robot, cfg.control_point_spacing, cfg.control_points)
        checker = None
        if cfg.collision_check_every > 0:
            from planbench.collision import CollisionChecker

            checker = CollisionChecker(problem.robot, problem.scene)
        self._prepared = {"problem": problem, "grid": grid, "kernels": kernels, "field": field,
                          "points": points, "gain": repulsion_gain(cfg, kernels), "checker": checker}
        if cfg.backend == "numba" or (cfg.backend == "auto" and fast.have_numba()):
            self._warm_up(problem)

    def _warm_up(self, problem: Problem) -> None:
        """Compile (or load from numba's cache) the step for the argument types the loop uses,
        here in the untimed setup rather than in the first timed step."""
        robot = problem.robot
        kin = ArmKinematics(robot, robot.frame_id(problem.goal.pose.frame), self._prepared["points"], compiled=True)
        q = np.array(problem.start, dtype=float)
        kin.update(q)
        n = robot.nq
        fast.step_compiled(kin.S, kin.J, kin.p, kin.R, np.zeros(3), np.eye(3), q, np.asarray(robot.lower),
                           np.asarray(robot.upper), np.ones(n), kin.points, np.zeros_like(kin.points),
                           kin.support, kin.descendants, np.zeros(0, dtype=np.intp),
                           fast.pack_params(self.config), np.zeros(n), np.zeros(6))

    @property
    def control_points(self) -> ControlPoints | None:
        return None if self._prepared is None else self._prepared["points"]

    def field_at(self, points: np.ndarray) -> np.ndarray:
        """Field (N, 3) at world points [m] for the prepared problem (zeros without obstacles)."""
        prep = self._prepared
        assert prep is not None, "call setup(problem) first"
        if prep["grid"] is None:
            return np.zeros((len(points), 3))
        if prep["field"] is not None:
            return prep["field"].sample(points)  # type: ignore[no-any-return]
        from planbench.field import lazy_field

        return lazy_field(prep["grid"], prep["kernels"], points)

    # --- the timed query ------------------------------------------------------------------
    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        if self._prepared is None or self._prepared["problem"] is not problem:
            self.setup(problem)
        prep = self._prepared
        assert prep is not None
        cfg: MatrixFieldConfig = self.config
        robot = problem.robot
        t_start = time.perf_counter()
        goal = problem.goal.pose
        frame_id = robot.frame_id(goal.frame)
        p_goal = np.asarray(goal.position, dtype=float)
        R_goal = np.asarray(goal.rotation, dtype=float)
        tol_p = cfg.goal_tolerance_scale * problem.tolerances.position
        tol_r = cfg.goal_tolerance_scale * problem.tolerances.orientation
        lower, upper = np.asarray(robot.lower), np.asarray(robot.upper)
        qd_max = cfg.velocity_scale * np.asarray(robot.velocity_limit)
        dt = cfg.dt
        k_rep = prep["gain"]
        has_field = prep["grid"] is not None and k_rep > 0
        field = prep["field"]
        grid, kernels = prep["grid"], prep["kernels"]
        checker = prep["checker"]
        lazy = None
        if has_field and field is None:
            from planbench.field import lazy_field as lazy
        window = cfg.stall_steps
        tool = np.flatnonzero(np.asarray(prep["points"].joint) == robot.model.frames[frame_id].parentJoint)
        tool = tool.astype(np.intp)
        n_max = cfg.max_steps + 1
        path = np.empty((n_max, robot.nq))
        diag = {name: np.full(n_max, np.nan) for name in
                ("position_error", "orientation_error", "repulsion", "manipulability", "slowdown", "damping")}
        best = np.empty(n_max)
        q = np.array(problem.start, dtype=float)
        status, message = PlanStatus.STEP_LIMIT, f"step budget of {cfg.max_steps} steps spent"
        k = 0
        use_numba = cfg.backend == "numba" or (cfg.backend == "auto" and fast.have_numba())
        step = fast.step_compiled if use_numba else fast.step_numpy
        kin = ArmKinematics(robot, frame_id, prep["points"], compiled=use_numba)
        prm = fast.pack_params(cfg)
        F = np.zeros((len(prep["points"]), 3))
        qd = np.zeros(robot.nq)
        dg = np.zeros(6)
        names = ("position_error", "orientation_error", "repulsion", "manipulability", "slowdown", "damping")
        columns = [diag[name] for name in names]
        while True:
            path[k] = q
            kin.update(q)
            if has_field:
                F = field.sample(kin.points) if field is not None else lazy(grid, kernels, kin.points)
                F *= k_rep
            step(kin.S, kin.J, kin.p, kin.R, p_goal, R_goal, q, lower, upper, qd_max, kin.points, F,
                 kin.support, kin.descendants, tool, prm, qd, dg)
            for col, value in zip(columns, dg.tolist(), strict=True):
                col[k] = value
            err_p, err_r = dg[0], dg[1]
            e = err_p + cfg.rotation_weight * err_r
            best[k] = e if k == 0 else min(e, best[k - 1])
            if checker is not None and (k % cfg.collision_check_every == 0) and k > 0 \
                    and checker.in_collision(q):
                status, message = PlanStatus.COLLISION, f"the arm is in collision at step {k} (t = {k * dt:.2f} s)"
                break
            if err_p <= tol_p and err_r <= tol_r:
                status, message = PlanStatus.SUCCESS, f"goal reached in {k} steps"
                break
            if stalled(best, k, window, cfg.stall_ratio):
                status = PlanStatus.LOCAL_MINIMUM
                message = (f"local minimum: the goal error fell by less than {cfg.stall_ratio:.0%} over "
                           f"{cfg.stall_window:g} s (position error {err_p * 1000:.1f} mm, "
                           f"orientation error {err_r:.3f} rad)")
                break
            if k >= cfg.max_steps:
                break
            if k % 16 == 0 and time.perf_counter() - t_start > time_limit:
                status, message = PlanStatus.TIMEOUT, f"time limit of {time_limit:g} s reached after {k} steps"
                break
            q = q + qd * dt
            np.clip(q, lower, upper, out=q)
            k += 1
        if status is not PlanStatus.SUCCESS and checker is not None and status is not PlanStatus.COLLISION \
                and checker.in_collision(path[k]):
            status, message = PlanStatus.COLLISION, f"the arm is in collision at step {k}"
        n = k + 1
        info: dict[str, Any] = {name: arr[:n].copy() for name, arr in diag.items()}
        info.update(steps=k, dt=dt, repulsion_gain=k_rep, n_control_points=len(prep["points"]),
                    field_mode=cfg.field_mode)
        return PlanResult(status, path[:n].copy(), np.arange(n) * dt, target="pose", message=message, info=info)
