"""One planner step as a quadratic program in the joint velocity ``qd`` (docs/method.md, section 5).

The QP of a step, in qpsolvers' form ``min 1/2 x^T P x + c^T x  s.t.  G x <= h,  lb <= x <= ub``::

    minimise   1/2 w_task |W (J qd - s v_att)|^2                 primary task (end effector)
             + 1/2 w_sec  |qd - (qd_rep + qd_m + qd_c)|^2        repulsion, manipulability, mid-joint
             + 1/2 mu     |qd|^2                                 damping
    subject to max(-qd_max, (q_min - q)/dt) <= qd <= min(qd_max, (q_max - q)/dt)   hard limits
               n_k^T J_k qd <= xi (d_k - d_s)   every robot geometry / obstacle pair k   collision constraints
                                  with d_k < d_i
               -u_i^T J_i qd <= a_i   for every damped control point i          field dampers (optional)

so ``P = w_task J^T W^2 J + (w_sec + mu) I`` and ``c = -(w_task s J^T W^2 v_att + w_sec x_sec)``.
The task terms (``v_att``, ``s``, ``qd_rep``, ``qd_m``, ``qd_c``, ``lambda``) are the matrix-field
planner's own functions (:mod:`planbench_plugins.ik_loop.tasks`); only the way they are
combined differs. Unconstrained and with ``W = I``, the minimiser is
``J^T (J J^T + l^2 I)^-1 s v_att + w_sec / (w_sec + mu) N_l x_sec`` with ``l^2 = (w_sec + mu) /
w_task``: the matrix-field step before its limits, with damped least squares and a damped
null-space projector ``N_l``.

Collision constraint (the velocity damper of Faverjon and Tournassoud 1987; Kanoun, Lamiraux and
Wieber 2011), per pair ``k`` of a robot collision geometry and an obstacle closer than ``d_i``:
coal's distance ``d_k`` between them, the witness point ``p_k`` on the robot and the unit normal
``n_k`` from the robot towards the obstacle (:mod:`.distances`). The obstacle is still, so
``d_k_dot = -n_k^T J_k qd`` with ``J_k`` the translational Jacobian of ``p_k``, and the damper
``d_k_dot >= -xi (d_k - d_s)`` is the row above: the approach speed allowed falls linearly to 0 at
the safety distance ``d_s``, and below it the row asks for a retreat. One step of ``dt`` shrinks
``d_k - d_s`` by at most the factor ``1 - xi dt`` (to first order; ``xi dt <= 1``), so the
distance never crosses ``d_s``. With every ``d_k >= d_s`` and ``q`` inside its limits, ``qd = 0``
is feasible; below ``d_s`` the retreat may conflict with the joint limits, and the solver reports
the QP infeasible (a named step failure, never a collision).

Field damper (after Faverjon and Tournassoud 1987, with the field in place of a distance):
``u_i = f_i / |f_i|`` points away from the obstacles, ``J_i`` is the point's translational
Jacobian, and the allowed approach speed ``a_i = xi max(0, 1 - |f_i| / (k_stop v_max))`` [m/s]
falls as the field grows. It never asks for a retreat (``a_i >= 0``), so ``qd = 0`` satisfies
every damper: with ``q`` inside its limits the QP is always feasible, and the repulsion term of
the objective does the pushing away.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planbench_plugins.ik_loop import tasks as T

__all__ = [
    "StepQP",
    "objective",
    "limit_bounds",
    "collision_constraints",
    "velocity_dampers",
    "infeasible_joints",
    "VELOCITY_MARGIN",
]

VELOCITY_MARGIN = 1e-9
"""Relative margin under the velocity limits (see :func:`limit_bounds`)."""


@dataclass
class StepQP:
    """One step's QP: ``min 1/2 x^T P x + c^T x`` s.t. ``G x <= h``, ``lb <= x <= ub``."""

    P: np.ndarray
    c: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    G: np.ndarray | None = None
    h: np.ndarray | None = None

    def unconstrained(self) -> np.ndarray:
        """The minimiser without constraints, ``-P^-1 c`` (for tests and diagnostics)."""
        return np.linalg.solve(self.P, -self.c)  # type: ignore[no-any-return]

    def violation(self, x: np.ndarray) -> float:
        """Largest constraint violation of ``x`` (0 when feasible) [rad/s, m/s]."""
        v = max(float(np.max(self.lb - x)), float(np.max(x - self.ub)), 0.0)
        if self.G is not None and self.h is not None and len(self.h):
            v = max(v, float(np.max(self.G @ x - self.h)))
        return v

    def active(self, x: np.ndarray, tol: float = 1e-7) -> int:
        """Number of constraints active at ``x`` (within ``tol``)."""
        n = int(np.sum(x <= self.lb + tol) + np.sum(x >= self.ub - tol))
        if self.G is not None and self.h is not None and len(self.h):
            n += int(np.sum(self.G @ x >= self.h - tol))
        return n


def objective(
    J: np.ndarray,
    v: np.ndarray,
    x_sec: np.ndarray,
    *,
    task_weight: float,
    orientation_weight: float,
    secondary_weight: float,
    damping: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``(P, c)`` of the objective above; ``v`` is the primary target ``s v_att`` (6,), ``damping``
    is ``mu`` [s^2/rad^2]."""
    w2 = np.array([1.0, 1.0, 1.0, orientation_weight, orientation_weight, orientation_weight])
    JW = J.T * (task_weight * w2)  # J^T w_task W^2, (n, 6)
    P = JW @ J
    P.flat[:: P.shape[0] + 1] += secondary_weight + damping
    c = -(JW @ v + secondary_weight * x_sec)
    return P, c


def limit_bounds(
    q: np.ndarray, lower: np.ndarray, upper: np.ndarray, qd_max: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(lb, ub)``: velocity limits and the position limits over one step, ``q + qd dt`` in
    ``[lower, upper]``. ``lb > ub`` on a joint means no velocity keeps it within both.

    The velocity limits are shrunk by :data:`VELOCITY_MARGIN` (relative): the harness measures
    velocities as ``(q_k+1 - q_k) / dt`` of the stored trajectory, and that difference, rounded in
    floating point, can exceed the commanded velocity by ~1e-14 relative."""
    vmax = qd_max * (1.0 - VELOCITY_MARGIN)
    return np.maximum(-vmax, (lower - q) / dt), np.minimum(vmax, (upper - q) / dt)


def infeasible_joints(lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Indices of joints whose bounds are inconsistent (``lb > ub``)."""
    return np.flatnonzero(lb > ub)


def velocity_dampers(
    S: np.ndarray,
    points: np.ndarray,
    F: np.ndarray,
    support: np.ndarray,
    rows: np.ndarray,
    *,
    speed: float,
    stop: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``(G, h)`` of the velocity dampers of control points ``rows`` (those with ``f_i != 0``).

    Row ``i``: ``-u_i^T J_i qd <= a_i`` with ``u_i = f_i / |f_i|`` and ``a_i = speed * max(0, 1 -
    |f_i| / stop)``; ``speed`` [m/s] is ``xi``, ``stop`` [m/s] the field at which the approach stops.
    """
    f = F[rows]
    mag = np.sqrt(np.einsum("ij,ij->i", f, f))
    u = f / mag[:, None]
    Jp = T.point_jacobians(S, points[rows], support[rows])  # (M, 3, n)
    G = -np.einsum("mjn,mj->mn", Jp, u)
    h = speed * np.maximum(0.0, 1.0 - mag / stop)
    return G, h


def collision_constraints(
    S: np.ndarray,
    point: np.ndarray,
    normal: np.ndarray,
    support: np.ndarray,
    distance: np.ndarray,
    *,
    gain: float,
    safety: float,
    other_point: np.ndarray | None = None,
    other_support: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(G, h)`` of the collision constraints of ``K`` pairs: row ``k`` is ``n_k^T (J_k - J'_k) qd
    <= gain (d_k - safety)``, ``d_k_dot = -n_k^T (J_k - J'_k) qd`` being the rate of the distance
    ``distance[k]`` [m] along the unit normal ``normal[k]`` (from the first body to the second).
    ``J_k[:, j] = support[k, j] (S_v,j + S_w,j x p_k)`` is the translational Jacobian of the first
    body's witness point ``point[k]`` [m] (``S`` the spatial Jacobian, WORLD); ``J'_k`` that of the
    second body's ``other_point[k]`` with ``other_support`` (left out for still obstacles).
    ``gain`` [1/s], ``safety`` [m]."""
    # n^T (S_v,j + S_w,j x p) = n . S_v,j + (p x n) . S_w,j
    G = support * (normal @ S[:3] + np.cross(point, normal) @ S[3:])
    if other_point is not None and other_support is not None and np.any(other_support):
        G -= other_support * (normal @ S[:3] + np.cross(other_point, normal) @ S[3:])
    h = gain * (distance - safety)
    return G, h
