"""The ``matrix-field-qp`` planner: the matrix-field planner with each step solved as a QP.

Everything but the step is the matrix-field planner's (the shared IK loop of
:mod:`planbench_plugins.ik_loop`, the matrix field of :mod:`planbench.field.scene_field`, the
endings, the diagnostics): this class replaces only
:meth:`~planbench_plugins.ik_loop.IKLoopPlanner.solve_step`, which builds
the QP of :mod:`.formulation` from the matrix-field task terms and solves it (:mod:`.solve`).
Joint position and velocity limits are hard constraints of the QP instead of a scaling and a clip
after the fact, and so (``collision_constraints``, default on) is collision avoidance: velocity
dampers on coal's exact distances between the robot's geometries and the obstacles, and between
the robot's own geometries (:mod:`.distances`, :func:`.formulation.collision_constraints`), built
in :meth:`setup` from the problem's robot and scene (a controller gives its observed geometry with
:meth:`~MatrixFieldQPPlanner.use_distances`).

Extra per-step diagnostics (``result.info``, one entry per path row): ``qp_build_time`` [s]
(task terms, QP matrices, the bounds check and qpsolvers' problem wrapping), ``qp_solve_time`` [s]
(the backend's solve call alone), ``qp_active`` (active
constraints), ``qp_residual`` (the solver's constraint violation before the projection onto the
bounds), ``qp_clearance`` [m] (the smallest distance the collision constraints saw, robot-obstacle
or robot-robot, ``inf`` with none within ``collision_influence``), ``qp_collision_rows`` (collision constraints in
the QP before the check), ``qp_corrections`` (rows the check added: witness points found ahead).
Totals: ``info["solver_time"]``, ``info["build_time"]`` [s]; ``info["solver"]``.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from planbench.field.scene_field import scene_repulsion
from planbench.planner import PlanResult
from planbench.problem import Pose, Problem
from planbench_plugins.ik_loop import (
    ArmKinematics,
    ControlPoints,
    DistanceModel,
    IKLoopPlanner,
    LoopStepper,
    PairDistances,
    Repulsion,
    StepInputs,
    ZeroRepulsion,
)
from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.matrix_field_qp.config import MatrixFieldQPConfig
from planbench_plugins.matrix_field_qp.formulation import (
    StepQP,
    collision_constraints,
    limit_bounds,
    objective,
    velocity_dampers,
)
from planbench_plugins.matrix_field_qp.solve import QPFailure, QPSolver

__all__ = ["MatrixFieldQPPlanner", "MAX_CORRECTIONS", "KEPT_POINTS", "CHECK_TOLERANCE"]

MAX_CORRECTIONS = 4
"""Re-solves of one step after its check found a pair closer than allowed (:meth:`solve_step`)."""
KEPT_POINTS = 8
"""Points kept per pair from the checks of earlier steps."""
CHECK_TOLERANCE = 1e-5
"""[m] Distance lost in one step beyond the constraints' allowance that the check lets pass (the
first-order error of a smooth approach is far smaller; a missed face is far larger)."""


class MatrixFieldQPPlanner(IKLoopPlanner):
    """Matrix-field IK planner with a QP per step (``matrix-field-qp``). See
    :class:`~planbench_plugins.matrix_field_qp.config.MatrixFieldQPConfig`."""

    name = "matrix-field-qp"
    Config = MatrixFieldQPConfig
    extra_diagnostics = (
        "qp_build_time",
        "qp_solve_time",
        "qp_active",
        "qp_residual",
        "qp_clearance",
        "qp_collision_rows",
        "qp_corrections",
    )

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        cfg = self.config
        self.solver = QPSolver(cfg.solver, cfg.options, cfg.residual_tolerance)
        self._joint_names: list[str] | None = None
        self.distances: DistanceModel | None = None
        """The exact distances of the collision constraints (None: off, or no obstacle)."""
        self._pairs: PairDistances | None = None  # the last step's near pairs (for failure messages)
        self._next: tuple[np.ndarray, PairDistances] | None = None  # (q, pairs) checked ahead by the last step
        self._last_qp: StepQP | None = None
        self._kept: dict[int, np.ndarray] = {}  # pair -> points kept on its first body, local [m]

    def pushes_off_itself(self) -> bool:
        """The collision constraints keep the robot's own pairs apart: no push is needed then."""
        return bool(self.config.self_collision and not self.config.collision_constraints)

    def escape_target_ok(self, q: np.ndarray) -> bool:
        """An escape ends where the collision constraints hold: every pair at least
        ``collision_safety`` apart on the convex hulls (the meshes alone may be free where the
        hulls overlap, and from there a step that must retreat can graze the meshes)."""
        if self.distances is None:
            return True
        pairs = self.distances.near_at(q)
        return not len(pairs) or float(pairs.distance.min()) >= self.config.collision_safety

    def setup(self, problem: Problem) -> None:
        """The loop's setup, and the distance model of the collision constraints (the problem's robot
        and scene)."""
        cfg = self.config
        if cfg.collision_constraints:
            self.use_distances(DistanceModel(problem.robot, problem.scene, cfg.collision_influence))
        else:
            self.use_distances(None)
        super().setup(problem)

    def prepare(
        self,
        robot: Any,
        goal: Pose,
        repulsion: Repulsion,
        *,
        start: np.ndarray | None = None,
        points: ControlPoints | None = None,
    ) -> LoopStepper:
        """The loop's :meth:`~planbench_plugins.ik_loop.IKLoopPlanner.prepare`; the collision
        constraints measure :attr:`distances` as they are (:meth:`setup` or :meth:`use_distances`
        set them)."""
        self._joint_names = list(robot.joint_names)
        stepper = super().prepare(robot, goal, repulsion, start=start, points=points)
        self._next, self._kept = None, {}  # nothing of the warm-up step carries over
        return stepper

    def use_distances(self, model: DistanceModel | None) -> None:
        """The collision constraints measure ``model`` from the next step on (None, or a model
        without pairs: no constraints). What earlier steps remembered of their distances (the pairs
        checked ahead, the witness points kept) is dropped: it belongs to the geometry it was
        measured in (a controller's observed scene changes every frame)."""
        self.distances = model if model is not None and model.n_pairs else None
        self._next, self._kept = None, {}

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
        self._pairs = None
        diag[10:13] = (math.inf, 0, 0)
        if self.distances is not None:
            collision = self._collision_rows(kin, q)
            if collision is not None and self._pairs is not None:
                Gc, hc = collision
                G, h = (Gc, hc) if G is None or h is None else (np.vstack((Gc, G)), np.concatenate((hc, h)))
                diag[10:12] = (float(self._pairs.distance.min()), float(hc.shape[0]))
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

    def _collision_rows(self, kin: ArmKinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``(G, h)`` of the collision constraints at ``q`` (None without a pair within reach).

        One row per pair within ``collision_influence`` at coal's witness points, plus one per
        point of the pair's first body that an earlier step's check found nearest (kept while the
        pair stays within reach, :data:`KEPT_POINTS` at most per pair): each must stay on the free
        side of the second body's supporting plane at its witness point. The first body lies at
        least the pair's distance from that plane, so these rows never ask more than the witness
        point's row does."""
        assert self.distances is not None
        ahead = self._next
        if ahead is not None and np.array_equal(ahead[0], q):  # checked by the last step: the same q
            pairs = self._pairs = ahead[1]
        else:
            pairs = self._pairs = self.distances.near(kin.model, kin.data)
        if not len(pairs):
            self._kept.clear()
            return None
        point, other, normal = [pairs.point], [pairs.other_point], [pairs.normal]
        support, other_support, distance = [pairs.support], [pairs.other_support], [pairs.distance]
        if self._kept:
            index = {k: i for i, k in enumerate(pairs.pair.tolist())}
            for k in [k for k in self._kept if k not in index]:
                del self._kept[k]  # the pair left the influence distance
            for k, local in self._kept.items():
                i = index[k]
                m = len(local)
                x = pairs.world(np.full(m, pairs.first[i]), local)
                n = pairs.normal[i]
                point.append(x)
                other.append(np.broadcast_to(pairs.other_point[i], x.shape))
                normal.append(np.broadcast_to(n, x.shape))
                support.append(np.broadcast_to(pairs.support[i], (m, pairs.support.shape[1])))
                other_support.append(np.broadcast_to(pairs.other_support[i], (m, pairs.support.shape[1])))
                distance.append((pairs.other_point[i] - x) @ n)
        cfg = self.config
        return collision_constraints(
            kin.S,
            np.concatenate(point),
            np.concatenate(normal),
            np.concatenate(support),
            np.concatenate(distance),
            gain=cfg.collision_gain,
            safety=cfg.collision_safety,
            other_point=np.concatenate(other),
            other_support=np.concatenate(other_support),
        )

    def _keep(self, ahead: PairDistances, bad: np.ndarray) -> None:
        """Remember the witness points ``ahead.point[bad]`` (in their first bodies' frames) for the
        rows of the next steps (:meth:`_collision_rows`); a point within 1 mm of one kept is not
        added again, and the oldest goes beyond :data:`KEPT_POINTS`."""
        local = ahead.local(ahead.first[bad], ahead.point[bad])
        for j, x in zip(bad.tolist(), local, strict=True):
            k = int(ahead.pair[j])
            old = self._kept.get(k)
            if old is None:
                self._kept[k] = x[None].copy()
            elif np.min(np.linalg.norm(old - x, axis=1)) > 1e-3:
                self._kept[k] = np.vstack((old, x))[-KEPT_POINTS:]

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
        Raises :class:`~.solve.QPFailure` when there is no valid step.

        With the collision constraints, the step is checked before it is taken: coal's distances
        at ``q + qd dt`` (kept for the next step, which starts there). A pair that ends closer
        than ``min(d_s, d_now) - CHECK_TOLERANCE`` (``d_now`` its distance at ``q``) means the
        linearisation missed something: another part of the geometry (a face turning onto an
        obstacle: the nearest point jumps from one corner to another), or the curvature of a fast
        turn. Its new witness point gets a row of its own (:class:`_Corrections`), tightened by
        the error of its linear prediction, and the QP is solved again, at most
        ``MAX_CORRECTIONS`` times; a point found again tightens its row further."""
        t0 = time.perf_counter()
        qp = self.build_qp(kin, q, inputs, points, F, support, tool, diag)
        base = qp
        x, residual, solver_seconds = self._solve(qp)
        corrections = 0
        dist, now = self.distances, self._pairs
        if dist is not None and now is not None:
            cfg = self.config
            dt = cfg.dt
            floor = np.minimum(now.by_pair(), cfg.collision_safety) - CHECK_TOLERANCE
            rows = _Corrections(kin.S, now, cfg.collision_gain, cfg.collision_safety, dt)
            for attempt in range(MAX_CORRECTIONS + 1):
                q_next = np.clip(q + x * dt, inputs.lower, inputs.upper)  # as the loop will advance
                ahead = dist.near_at(q_next)
                self._next = (q_next, ahead)
                bad = np.flatnonzero(ahead.distance < floor[ahead.pair])
                if not len(bad) or attempt == MAX_CORRECTIONS:
                    break
                self._keep(ahead, bad)
                rows.add(ahead, bad, x)
                Gc, hc = rows.G, rows.h
                G = Gc if base.G is None or base.h is None else np.vstack((base.G, Gc))
                h = hc if base.G is None or base.h is None else np.concatenate((base.h, hc))
                qp = StepQP(base.P, base.c, base.lb, base.ub, G, h)
                x, residual, seconds = self._solve(qp)
                solver_seconds += seconds
                corrections += len(bad)
        self._last_qp = qp
        t1 = time.perf_counter()
        qd_out[:] = x
        # solve time: the backend's call alone; its wrapping (checks, qpsolvers.Problem) counts as build
        diag[6:10] = (t1 - t0 - solver_seconds, solver_seconds, qp.active(x), residual)
        diag[12] = corrections

    def _solve(self, qp: StepQP) -> tuple[np.ndarray, float, float]:
        try:
            return self.solver.solve(qp, self._joint_names)
        except QPFailure as exc:
            raise self._explain(exc) from exc

    def _explain(self, exc: QPFailure) -> QPFailure:
        """``exc``, naming the pair when a collision constraint asked for a retreat (closer than
        ``collision_safety``): that is when the constraints can conflict with the joint limits."""
        pairs, dist = self._pairs, self.distances
        safety = self.config.collision_safety
        if pairs is None or dist is None or not len(pairs) or pairs.distance.min() >= safety:
            return exc
        k = int(np.argmin(pairs.distance))
        first, second = dist.pair_names[pairs.pair[k]]
        message = (
            f"{exc.message}; the collision constraints ask {first} to move away from {second} "
            f"(distance {pairs.distance[k] * 1000:.2f} mm, under the safety distance of {safety * 1000:g} mm), "
            "and within the joint limits no step does"
        )
        out = QPFailure(message, exc.solver, exc.solver_status)
        out.info["qp_failure"]["collision_pair"] = [first, second]
        return out

    def step_at(self, q: np.ndarray) -> tuple[StepQP, np.ndarray, np.ndarray]:
        """``(qp, qd, diag)`` of one step at ``q`` for the prepared loop (tests, inspection), on
        kinematics and buffers of its own. Raises :class:`~.solve.QPFailure` like the step itself."""
        stepper = self.stepper
        q = np.asarray(q, dtype=float)
        kin = stepper.kinematics_at(q)
        points, F, support, joint = stepper.repulsion.forces(kin)
        tool = stepper.tool_points(joint)
        diag = np.full(6 + len(self.extra_diagnostics), np.nan)
        qd = np.zeros_like(q)
        self.solve_step(kin, q, stepper.inputs, points, F, support, tool, qd, diag)
        assert self._last_qp is not None
        return self._last_qp, qd, diag

    # --- the timed query ---------------------------------------------------------------------
    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        """The loop's plan (a :class:`~.solve.QPFailure` ends it as ``INFEASIBLE`` with the path so
        far), plus the solver's and the build's total time in ``info``."""
        self._next, self._kept = None, {}  # nothing carried over from an earlier query
        result = super().plan(problem, time_limit=time_limit, rng=rng)
        info = dict(result.info)
        info["solver"] = self.solver.name
        info["solver_time"] = float(np.nansum(info.get("qp_solve_time", np.zeros(0))))
        info["build_time"] = float(np.nansum(info.get("qp_build_time", np.zeros(0))))
        return result.replace(info=info)


class _Corrections:
    """The rows one step's check adds (:meth:`MatrixFieldQPPlanner.solve_step`).

    A pair's witness points found ahead (at ``q + qd dt``), carried back rigidly with their bodies
    to where they are at this step's ``q`` (``x`` on the first body, ``w`` on the second; an
    obstacle's stays), give the plane distance ``n . (w - x)`` along the normal ``n`` found ahead;
    for an obstacle it never exceeds the true distance (the plane through ``w`` supports the convex
    obstacle). The row is the damper on that plane distance, tightened by ``e / dt``: ``e`` the
    amount by which its linear prediction overestimated the distance found ahead for the step that
    was checked (the curvature of the motion over one step). A point within 1 mm of one with a row
    tightens that row by the new error instead.
    """

    def __init__(self, S: np.ndarray, now: PairDistances, gain: float, safety: float, dt: float) -> None:
        self.S, self.now, self.gain, self.safety, self.dt = S, now, gain, safety, dt
        self.G = np.zeros((0, S.shape[1]))
        self.h = np.zeros(0)
        self._plane = np.zeros(0)  # each row's plane distance at q [m]
        self._key: list[tuple[int, np.ndarray]] = []  # (pair, local point on the first body)

    def add(self, ahead: PairDistances, bad: np.ndarray, qd: np.ndarray) -> None:
        """Rows for ``ahead``'s pairs ``bad``, after the step ``qd`` that was checked."""
        local = ahead.local(ahead.first[bad], ahead.point[bad])
        other = ahead.local(ahead.second[bad], ahead.other_point[bad])
        for j, p_local, w_local in zip(bad.tolist(), local, other, strict=True):
            k = int(ahead.pair[j])
            row = next(
                (i for i, (kk, kp) in enumerate(self._key) if kk == k and np.linalg.norm(kp - p_local) < 1e-3),
                None,
            )
            if row is None:
                x = self.now.world(ahead.first[j : j + 1], p_local[None])
                w = self.now.world(ahead.second[j : j + 1], w_local[None])
                n = ahead.normal[j : j + 1]
                plane = np.einsum("kj,kj->k", n, w - x)
                G, h = collision_constraints(
                    self.S,
                    x,
                    n,
                    ahead.support[j : j + 1],
                    plane,
                    gain=self.gain,
                    safety=self.safety,
                    other_point=w,
                    other_support=ahead.other_support[j : j + 1],
                )
                self.G, self.h = np.vstack((self.G, G)), np.concatenate((self.h, h))
                self._plane = np.concatenate((self._plane, plane))
                self._key.append((k, p_local))
                row = len(self.h) - 1
            error = self._plane[row] - float(self.G[row] @ qd) * self.dt - float(ahead.distance[j])
            self.h[row] -= max(error, 0.0) / self.dt
