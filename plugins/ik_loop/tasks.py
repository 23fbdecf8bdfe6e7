"""The task terms of one matrix-field step (docs/method.md, section 4), each a small pure function.

Conventions: ``q`` joint positions [rad], ``qd`` joint velocities [rad/s], world-aligned velocities
``[v; omega]`` ([m/s; rad/s]). ``S`` is pinocchio's spatial Jacobian in the WORLD convention
(``computeJointJacobians``, ``data.J``): column ``k`` is the twist of joint ``k`` expressed at the
world origin, ``S[:3]`` linear, ``S[3:]`` angular. The velocity of a world point ``p`` rigidly
carried by joint ``k`` and its ancestors is ``sum_k (S_v,k + S_w,k x p) qd_k``.

Step (``merge``): ``qd = s qd_1 + N (qd_rep + qd_m + qd_c)``, then velocity and position limits.
With ``hierarchy="priority"`` a correction is added before the limits: the repulsion rows
(:func:`repulsion_rows`, activations :func:`priority_activation`) against the pose rows, in one
damped least squares (:func:`push_correction`).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

__all__ = [
    "attraction_velocity",
    "orientation_error",
    "attraction",
    "adaptive_damping",
    "dls",
    "dls_with_nullspace",
    "nullspace_projector",
    "manipulability",
    "manipulability_gradient",
    "mid_joint_velocity",
    "strongest",
    "slowdown_factor",
    "repulsion_joint_velocity",
    "point_jacobians",
    "scale_to_velocity_limits",
    "clamp_to_position_limits",
    "merge",
    "smoothstep",
    "repulsion_rows",
    "priority_activation",
    "stacked_dls",
    "push_correction",
]

_HALF_PI = 0.5 * math.pi


def attraction_velocity(p: np.ndarray, p_goal: np.ndarray, speed_max: float, sigmoid_gain: float) -> np.ndarray:
    """Translational attraction [m/s] (draft eqs. 4-6, sign as in docs/method.md: towards the goal).

    ``v = (e / d) v_max atan(k_sigm d) / (pi / 2)`` with ``e = p_goal - p``, ``d = |e|``: speed
    ``v_max`` far away, ``v_max k_sigm d (2 / pi)`` near the goal. Its magnitude is below
    ``d / dt`` whenever ``dt < pi / (2 v_max k_sigm)``, so an Euler step never overshoots.
    """
    e = p_goal - p
    d = math.sqrt(float(e @ e))
    if d < 1e-15:
        return np.zeros(3)
    return e * (speed_max * math.atan(sigmoid_gain * d) / (_HALF_PI * d))


def orientation_error(R: np.ndarray, R_goal: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] (axis times angle, world frame) that turns ``R`` into ``R_goal``:
    ``omega = log(R_goal R^T)`` (``pin.log3``, angle in [0, pi]). Rotating ``R`` by
    ``exp(omega)`` in the world frame gives ``R_goal``: it points TO the goal. The compiled step
    computes the same through a unit quaternion (tested against this)."""
    return pin.log3(R_goal @ R.T)  # type: ignore[no-any-return]


def attraction(
    p: np.ndarray,
    R: np.ndarray,
    p_goal: np.ndarray,
    R_goal: np.ndarray,
    *,
    speed_max: float,
    sigmoid_gain: float,
    position_gain: float,
    orientation_gain: float,
    angular_speed_max: float,
) -> np.ndarray:
    """``v_att = [k_p v ; k_w omega]`` (6,), the angular part capped at ``angular_speed_max`` [rad/s]."""
    out = np.empty(6)
    out[:3] = position_gain * attraction_velocity(p, p_goal, speed_max, sigmoid_gain)
    w = orientation_gain * orientation_error(R, R_goal)
    n = math.sqrt(float(w @ w))
    if n > angular_speed_max:
        w *= angular_speed_max / n
    out[3:] = w
    return out


def manipulability(J: np.ndarray) -> float:
    """Yoshikawa's measure ``m = sqrt(det(J J^T))`` (0 at a singularity). It is the same for the
    spatial Jacobian and the end-effector Jacobian (they differ by a unimodular transform)."""
    return math.sqrt(max(float(np.linalg.det(J @ J.T)), 0.0))


def adaptive_damping(m: float, damping_max: float, threshold: float) -> float:
    """Damping ``lambda`` [m]: 0 while ``m >= threshold``, else ``damping_max sqrt(1 - (m/m0)^2)``
    (Nakamura and Hanafusa 1986): exact least squares away from singularities, damped near them."""
    if m >= threshold:
        return 0.0
    return damping_max * math.sqrt(1.0 - (m / threshold) ** 2)


def dls(J: np.ndarray, v: np.ndarray, damping: float) -> np.ndarray:
    """Damped least squares ``J^T (J J^T + lambda^2 I)^-1 v``."""
    A = J @ J.T
    A.flat[:: A.shape[0] + 1] += damping * damping
    return J.T @ np.linalg.solve(A, v)


def dls_with_nullspace(
    J: np.ndarray, v: np.ndarray, x: np.ndarray, damping: float, floor: float = 1e-9
) -> tuple[np.ndarray, np.ndarray]:
    """``(qd_1, N x)`` with one factorisation: ``qd_1 = J_dls^+ v`` and ``N x = x - J_dls^+ J x``.

    ``floor`` [m] is added to the damping only to keep the solve defined at an exact singularity.
    """
    A = J @ J.T
    A.flat[:: A.shape[0] + 1] += damping * damping + floor * floor
    rhs = np.stack((v, J @ x), axis=1)
    sol = J.T @ np.linalg.solve(A, rhs)
    return sol[:, 0], x - sol[:, 1]


def nullspace_projector(J: np.ndarray, damping: float = 0.0) -> np.ndarray:
    """``N = I - J_dls^+ J`` (n, n). Exact (``J N = 0``) when ``damping == 0`` and ``J`` has full row rank."""
    n = J.shape[1]
    A = J @ J.T
    A.flat[:: A.shape[0] + 1] += damping * damping
    return np.eye(n) - J.T @ np.linalg.solve(A, J)


def _cross_cols(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Column-wise cross product of two (3, n) arrays (np.cross is ~10x slower on small arrays)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))


def manipulability_gradient(S: np.ndarray, descendants: np.ndarray, eps: float = 1e-12) -> tuple[float, np.ndarray]:
    """``(m, grad_q m)`` of the manipulability from the spatial Jacobian ``S`` (6, n).

    ``dm/dq_k = m tr((S S^T)^-1 dS/dq_k S^T)`` and, for a kinematic tree, ``dS_i/dq_k = S_k x S_i``
    (the motion cross product) when joint ``i`` descends from joint ``k``, else 0.
    ``descendants[k, i]`` is True when joint ``i`` strictly descends from joint ``k``.
    """
    A = S @ S.T
    m = math.sqrt(max(float(np.linalg.det(A)), 0.0))
    A.flat[::7] += eps
    X = np.linalg.solve(A, S)
    # a_i = v_i x Xv_i + w_i x Xw_i and b_i = w_i x Xv_i, with one cross product of (3, 3n)
    c = _cross_cols(np.concatenate((S[:3], S[3:], S[3:]), axis=1), np.concatenate((X[:3], X[3:], X[:3]), axis=1))
    n = S.shape[1]
    a = c[:, :n] + c[:, n : 2 * n]
    b = c[:, 2 * n :]
    # column k of a @ D^T: the sum of a_i over the descendants i of k
    grad = (S[3:] * (a @ descendants.T) + S[:3] * (b @ descendants.T)).sum(axis=0)
    grad *= m
    return m, grad


def mid_joint_velocity(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, gain: float) -> np.ndarray:
    """``qd_c = -k_c (q - q_mid) / (q_max - q_min)^2`` [rad/s]: away from the joint limits."""
    span = upper - lower
    return -gain * (q - 0.5 * (lower + upper)) / (span * span)


def strongest(forces: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The largest of ``forces[rows]`` (3,) by magnitude (zeros when ``rows`` is empty)."""
    if len(rows) == 0:
        return np.zeros(3)
    sub = forces[rows]
    return sub[int(np.argmax(np.einsum("ij,ij->i", sub, sub)))]


def slowdown_factor(repulsion_speed: float, gain: float, minimum: float) -> float:
    """Primary-task factor ``s = max(s_min, 1 / (1 + k_s |f|_max))`` in ``[s_min, 1]``."""
    return max(minimum, 1.0 / (1.0 + gain * repulsion_speed))


def repulsion_joint_velocity(S: np.ndarray, points: np.ndarray, forces: np.ndarray, support: np.ndarray) -> np.ndarray:
    """``qd_rep = sum_i J_i^T f_i`` (n,) without forming the point Jacobians.

    ``points`` (N, 3) world positions [m], ``forces`` (N, 3) repulsive velocities [m/s],
    ``support[i, k]`` = 1.0 when joint ``k`` moves point ``i``. Row ``k`` of ``J_i^T f_i`` is
    ``(S_v,k + S_w,k x p_i) . f_i = S_v,k . f_i + S_w,k . (p_i x f_i)``, so the sum over points is
    two (3, N) x (N, n) products.
    """
    wrench = np.empty((6, len(points)))
    wrench[:3] = forces.T
    wrench[3:] = _cross_cols(points.T, forces.T)  # p_i x f_i
    return (S * (wrench @ support)).sum(axis=0)


def point_jacobians(S: np.ndarray, points: np.ndarray, support: np.ndarray) -> np.ndarray:
    """Translational Jacobians (N, 3, n) of world points: ``J_i[:, k] = support[i, k] (S_v,k + S_w,k x p_i)``."""
    Sv, Sw = S[:3].T, S[3:].T  # (n, 3)
    J = Sv[None, :, :] + np.cross(Sw[None, :, :], points[:, None, :])  # (N, n, 3); not on the hot path
    return np.transpose(J * support[:, :, None], (0, 2, 1))


def scale_to_velocity_limits(qd: np.ndarray, qd_max: np.ndarray) -> tuple[np.ndarray, float]:
    """``(qd * c, c)`` with the largest ``c <= 1`` such that every ``|qd_j c| <= qd_max_j``.
    One factor for all joints, so the direction of ``qd`` is kept."""
    ratio = float(np.max(np.abs(qd) / qd_max))
    if ratio <= 1.0:
        return qd, 1.0
    c = 1.0 / ratio
    return qd * c, c


def clamp_to_position_limits(
    q: np.ndarray, qd: np.ndarray, lower: np.ndarray, upper: np.ndarray, dt: float
) -> np.ndarray:
    """``qd`` clipped per joint so that ``q + qd dt`` stays in ``[lower, upper]``.

    Per joint, not one factor for all: a joint resting at its limit would otherwise freeze the
    whole arm. Clipping only shrinks components, so velocity limits keep holding.
    """
    return np.clip(qd, (lower - q) / dt, (upper - q) / dt)


def merge(qd_primary: np.ndarray, slowdown: float, qd_secondary_projected: np.ndarray) -> np.ndarray:
    """``qd = s qd_1 + N (qd_rep + qd_m + qd_c)`` (the projection is done by the caller)."""
    return slowdown * qd_primary + qd_secondary_projected


def smoothstep(u: float) -> float:
    """``3u^2 - 2u^3`` on [0, 1], 0 below, 1 above: a C1 ramp."""
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


def repulsion_rows(S: np.ndarray, points: np.ndarray, forces: np.ndarray, support: np.ndarray) -> np.ndarray:
    """``(N, n)``: row ``i`` is ``n_i^T J_i`` with ``n_i = f_i / |f_i|`` (zeros where ``f_i = 0``), the
    rate of approach of point ``i`` along its push per unit joint velocity. Formed from ``S`` like
    :func:`repulsion_joint_velocity`: ``n_i . (S_v,k + S_w,k x p_i) = S_v,k . n_i + S_w,k . (p_i x n_i)``."""
    mag = np.sqrt(np.einsum("ij,ij->i", forces, forces))
    unit = np.divide(forces, mag[:, None], out=np.zeros_like(forces), where=mag[:, None] > 0)
    wrench = np.concatenate((unit, np.cross(points, unit)), axis=1)  # (N, 6)
    return (wrench @ S) * support  # type: ignore[no-any-return]


def priority_activation(
    push: np.ndarray, position_error: float, *, speed_max: float, onset: float, full: float, fade: float
) -> np.ndarray:
    """Activations (N,) in [0, 1] of the repulsion rows from the pushes ``|f_i|`` [m/s]
    (``hierarchy="priority"``).

    ``a_i = smoothstep((|f_i| / speed_max - onset) / (full - onset)) * min(1, e_p / fade)``: 0 while
    the push is below ``onset`` times the cruising speed (the point is far from every obstacle),
    rising C1 to 1 at ``full`` times it (close to one), and fading linearly to 0 as the position
    error ``e_p`` [m] falls below ``fade`` [m], so a goal next to an obstacle stays reachable."""
    near = min(1.0, position_error / fade)
    span = full - onset
    return np.array([near * smoothstep((f / speed_max - onset) / span) for f in push])


PRIORITY_FLOOR2 = 1e-6
"""(1 mm)^2 added to ``lambda^2`` in the stacked least squares: a stack with more rows than joints
is rank-deficient in task space, so the solve is done in joint space, where the floor keeps it
defined whatever the rank (it damps only directions moved by less than ~1 mm per radian)."""


def stacked_dls(A: np.ndarray, b: np.ndarray, x: np.ndarray, damping2: float) -> np.ndarray:
    """``qd = (A^T A + mu I)^-1 (A^T b + mu x)`` with ``mu = damping2 + PRIORITY_FLOOR2`` [m^2]: the
    minimiser of ``|A qd - b|^2 + mu |qd - x|^2``.

    ``A`` (m, n) stacks the (weighted) task rows, ``b`` (m,) their targets, ``x`` (n,) the velocity
    it stays closest to where the rows leave freedom. With ``A = J`` (6 rows) and ``x`` the secondary
    velocity it is the DLS step with the null-space projection of :func:`dls_with_nullspace`, in
    joint space."""
    mu = damping2 + PRIORITY_FLOOR2
    H = A.T @ A
    H.flat[:: H.shape[0] + 1] += mu
    return np.linalg.solve(H, A.T @ b + mu * x)  # type: ignore[no-any-return]


def push_correction(
    J: np.ndarray,
    rows: np.ndarray,
    push: np.ndarray,
    activation: np.ndarray,
    qd: np.ndarray,
    *,
    weight: float,
    orientation_weight: float,
    damping2: float,
) -> np.ndarray:
    """The correction ``dq`` (n,) the ``"priority"`` hierarchy adds to the null-space step ``qd``.

    Row ``i`` (``rows[i] = n_i^T J_i``, :func:`repulsion_rows`) asks point ``i`` to move away from
    its obstacle at ``(1 - a_i) n_i^T J_i qd + a_i max(|f_i|, n_i^T J_i qd)``: at activation
    ``a_i = 0`` what the step already does, at ``a_i = 1`` at least its push ``|f_i|``. Its weight
    is ``weight * a_i``; the pose rows (weight 1, the orientation rows ``orientation_weight``) ask to
    keep the step's end-effector twist ``J qd``. One damped least squares (:func:`stacked_dls`,
    staying closest to ``qd``) in the correction ``dq``::

        min |W_p^1/2 J dq|^2 + sum_i w_i (n_i^T J_i dq - a_i max(0, |f_i| - n_i^T J_i qd))^2 + mu |dq|^2

    The result is continuous in the activations: no row changes the step while it activates, on
    any arm (on a 7-joint arm the first row alone would fill the null space and be met exactly
    whatever its weight, so the blended target, not the weight, makes the activation smooth).
    Near an obstacle the push competes with the pose task with weight ``weight`` against 1 for
    the position rows, and wins when it is larger."""
    n = J.shape[1]
    w = weight * activation
    root = np.sqrt(w)
    pose = np.sqrt([1.0, 1.0, 1.0, orientation_weight, orientation_weight, orientation_weight])
    short = np.maximum(0.0, push - rows @ qd)  # how much slower than its push each point moves away
    A = np.vstack((pose[:, None] * J, root[:, None] * rows))
    b = np.concatenate((np.zeros(6), root * activation * short))
    return stacked_dls(A, b, np.zeros(n), damping2)
