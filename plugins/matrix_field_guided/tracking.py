"""The tracking law of ``matrix-field-guided``, one step of it: shared by the planner, which
integrates it at ``dt``, and the controller, which runs it once per control tick.

    qd = (r_next - r) / dt + K (r - q) + w sum_i J_i^T f_i

The feed-forward moves with the reference, the feedback ``K (r - q)`` pulls the arm back onto it,
and the push ``w sum_i J_i^T f_i`` (the matrix field at the control points) moves it clear of what
it passes, weighted by :func:`push_weight`. Then the velocity limits (one factor for every joint:
the direction is kept) and the joint limits.
"""

from __future__ import annotations

import numpy as np

from planbench_plugins.ik_loop import tasks as T

__all__ = ["push_weight", "tracking_velocity"]


def push_weight(lag: float, max_lag: float, remaining: float, goal_fade: float) -> float:
    """The push's weight ``w`` in [0, 1]: a smoothstep of ``1 - lag / max_lag`` (``lag`` [rad]
    the largest joint error from the reference: the push fades as it pulls the arm away, so the
    tracking wins in the end) times, when ``goal_fade`` [rad] > 0, a smoothstep of ``remaining /
    goal_fade`` (``remaining`` the joint path length [rad] left: goals next to obstacles are
    reached as planned)."""
    w = T.smoothstep(1.0 - lag / max_lag)
    if goal_fade > 0:
        w *= T.smoothstep(remaining / goal_fade)
    return w


def tracking_velocity(
    q: np.ndarray,
    r: np.ndarray,
    r_next: np.ndarray,
    dt: float,
    gain: float,
    push: np.ndarray | None,
    qd_max: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:
    """The joint velocity [rad/s] from ``q`` of the module's law: ``r``, ``r_next`` the reference
    now and one step ``dt`` [s] later, ``gain`` ``K`` [1/s], ``push`` the weighted push [rad/s]
    (None: none); scaled into ``qd_max`` [rad/s] (one factor) and clamped so that ``q + qd dt``
    stays within ``lower`` and ``upper`` [rad]."""
    qd = (r_next - r) / dt + gain * (r - q)
    if push is not None:
        qd = qd + push
    qd, _ = T.scale_to_velocity_limits(qd, qd_max)
    return T.clamp_to_position_limits(q, qd, lower, upper, dt)
