"""The ``matrix-field-qp`` planner: the matrix-field planner with each step solved as a QP.

Everything but the step is the matrix-field planner's (the shared IK loop of
:mod:`planbench_plugins.ik_loop`, the matrix field of :mod:`planbench.field.scene_field`, the
endings, the diagnostics): this class replaces only
:meth:`~planbench_plugins.ik_loop.IKLoopPlanner.solve_step`, which builds
the QP of :mod:`.formulation` from the matrix-field task terms and solves it (:mod:`.solve`).
Joint position and velocity limits are hard constraints of the QP instead of a scaling and a clip
after the fact.

Extra per-step diagnostics (``result.info``, one entry per path row): ``qp_build_time`` [s]
(task terms, QP matrices, the bounds check and qpsolvers' problem wrapping), ``qp_solve_time`` [s]
(the backend's solve call alone), ``qp_active`` (active
constraints), ``qp_residual`` (the solver's constraint violation before the projection onto the
bounds). Totals: ``info["solver_time"]``, ``info["build_time"]`` [s]; ``info["solver"]``.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from planbench.field.scene_field import scene_repulsion
from planbench.planner import PlanResult
from planbench.problem import Problem
from planbench_plugins.ik_loop import ArmKinematics, ControlPoints, IKLoopPlanner, Repulsion, StepInputs, ZeroRepulsion
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field_qp.config import MatrixFieldQPConfig
from planbench_plugins.matrix_field_qp.formulation import StepQP, limit_bounds, objective, velocity_dampers
from planbench_plugins.matrix_field_qp.solve import QPFailure, QPSolver

__all__ = ["MatrixFieldQPPlanner"]


class MatrixFieldQPPlanner(IKLoopPlanner):
    """Matrix-field IK planner with a QP per step (``matrix-field-qp``). See
    :class:`~planbench_plugins.matrix_field_qp.config.MatrixFieldQPConfig`."""

    name = "matrix-field-qp"
    Config = MatrixFieldQPConfig
    extra_diagnostics = ("qp_build_time", "qp_solve_time", "qp_active", "qp_residual")

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        cfg = self.config
        self.solver = QPSolver(cfg.solver, cfg.options, cfg.residual_tolerance)
        self._joint_names: list[str] | None = None

    def setup(self, problem: Problem) -> None:
        self._joint_names = list(problem.robot.joint_names)
        try:
            super().setup(problem)
        except QPFailure:
            pass  # the untimed warm-up step at an infeasible start: plan() reports it

    def make_repulsion(self, problem: Problem, points: ControlPoints) -> Repulsion:
        """The matrix field of the scene, as ``matrix-field``'s (:mod:`planbench.field.scene_field`)."""
        return scene_repulsion(problem, self.config) or ZeroRepulsion()

    # --- one step ----------------------------------------------------------------------------
    def build_qp(
        self,
        kin: ArmKinematics,
        q: np.ndarray,
        inputs: StepInputs,
        points: np.ndarray,
        F: np.ndarray,
        support: np.ndarray,
        tool: np.ndarray,
        diag: np.ndarray,
    ) -> StepQP:
        """The step's QP (:mod:`.formulation`) from the matrix-field task terms; writes the six
        standard diagnostics into ``diag[:6]``."""
        cfg = self.config
        p, R, S = kin.p, kin.R, kin.S
        err_p = float(np.linalg.norm(inputs.p_goal - p))
        err_r = float(np.linalg.norm(T.orientation_error(R, inputs.R_goal)))
        v = T.attraction(
            p,
            R,
            inputs.p_goal,
            inputs.R_goal,
            speed_max=cfg.speed_max,
            sigmoid_gain=cfg.sigmoid_gain,
            position_gain=cfg.position_gain,
            orientation_gain=cfg.orientation_gain,
            angular_speed_max=cfg.angular_speed_max,
        )
        x_sec = T.mid_joint_velocity(q, inputs.lower, inputs.upper, cfg.mid_joint_gain)
        m, grad = T.manipulability_gradient(S, kin.descendants)
        if cfg.manipulability_gain > 0:
            x_sec += cfg.manipulability_gain * grad
        mag2 = np.einsum("ij,ij->i", F, F) if len(F) else np.zeros(0)
        rep = math.sqrt(float(mag2.max())) if len(F) else 0.0
        G = h = None
        if rep > 0:
            x_sec += T.repulsion_joint_velocity(S, points, F, support)
            if cfg.tool_repulsion_gain > 0:
                fade = min(1.0, err_p / cfg.tool_fade_distance)
                v[:3] += cfg.tool_repulsion_gain * fade * T.strongest(F, tool)
            if cfg.velocity_dampers:
                on = mag2 > 0
                if not cfg.damper_tool:
                    on[tool] = False
                rows = np.flatnonzero(on)
                if len(rows):
                    G, h = velocity_dampers(
                        S, points, F, support, rows, speed=cfg.damper_speed, stop=cfg.damper_stop * cfg.speed_max
                    )
        lam = (
            T.adaptive_damping(m, cfg.damping_factor, cfg.manipulability_threshold)
            if cfg.damping == "adaptive"
            else cfg.damping_factor
        )
        s = T.slowdown_factor(rep, cfg.slowdown_gain, cfg.slowdown_min) if cfg.slowdown_gain > 0 else 1.0
        P, c = objective(
            kin.J,
            s * v,
            x_sec,
            task_weight=cfg.task_weight,
            orientation_weight=cfg.orientation_weight,
            secondary_weight=cfg.secondary_weight,
            damping=cfg.task_weight * lam * lam + cfg.damping_weight,
        )
        lb, ub = limit_bounds(q, inputs.lower, inputs.upper, inputs.qd_max, cfg.dt)
        diag[:6] = (err_p, err_r, rep, m, s, lam)
        return StepQP(P, c, lb, ub, G, h)

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
        """Build the QP, solve it, write ``qd`` (within the limits exactly) and the diagnostics.
        Raises :class:`~.solve.QPFailure` when there is no valid step."""
        t0 = time.perf_counter()
        qp = self.build_qp(kin, q, inputs, points, F, support, tool, diag)
        x, residual, solver_seconds = self.solver.solve(qp, self._joint_names)
        t1 = time.perf_counter()
        qd_out[:] = x
        # solve time: the backend's call alone; its wrapping (checks, qpsolvers.Problem) counts as build
        diag[6:10] = (t1 - t0 - solver_seconds, solver_seconds, qp.active(x), residual)

    def step_at(self, q: np.ndarray) -> tuple[StepQP, np.ndarray, np.ndarray]:
        """``(qp, qd, diag)`` of one step at ``q`` for the prepared problem (tests, inspection).
        Raises :class:`~.solve.QPFailure` like the step itself."""
        prep = self._prepared
        if prep is None:
            raise RuntimeError("call setup(problem) first")
        problem = prep["problem"]
        frame_id = problem.robot.frame_id(problem.goal.pose.frame)
        kin = ArmKinematics(problem.robot, frame_id, prep["points"])
        q = np.asarray(q, dtype=float)
        kin.update(q)
        inputs = self._inputs(problem, frame_id)
        points, F, support, joint = prep["repulsion"].forces(kin)
        tool = np.flatnonzero(joint == inputs.tool_joint)
        diag = np.full(6 + len(self.extra_diagnostics), np.nan)
        qp = self.build_qp(kin, q, inputs, points, F, support, tool, diag)
        qd = np.zeros(problem.robot.nq)
        self.solve_step(kin, q, inputs, points, F, support, tool, qd, diag)
        return qp, qd, diag

    # --- the timed query ---------------------------------------------------------------------
    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        """The loop's plan (a :class:`~.solve.QPFailure` ends it as ``INFEASIBLE`` with the path so
        far), plus the solver's and the build's total time in ``info``."""
        result = super().plan(problem, time_limit=time_limit, rng=rng)
        info = dict(result.info)
        info["solver"] = self.solver.name
        info["solver_time"] = float(np.nansum(info.get("qp_solve_time", np.zeros(0))))
        info["build_time"] = float(np.nansum(info.get("qp_build_time", np.zeros(0))))
        return result.replace(info=info)
