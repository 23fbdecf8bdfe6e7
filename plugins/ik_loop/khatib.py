"""Khatib's repulsive profile and the gain that makes it comparable with the matrix field: part
of the loop, since every distance-based push on it (``edt-field``, ``distance-field``, the
calibrated matrix field) uses the same profile.

Khatib (1986), "Real-time obstacle avoidance for manipulators and mobile robots": a point at
distance ``d`` from an obstacle is pushed away with magnitude

    |f|(d) = k (1/d - 1/d0) / d^2    for d < d0,    0 for d >= d0,

the negative gradient of the potential ``k/2 (1/d - 1/d0)^2``; ``d0`` is the influence distance.
Here ``|f|`` is a speed [m/s] (the loop maps it through the point's Jacobian like the matrix
field's ``k_rep F``), so ``k`` is in [m^2/s].

Gain from the stand-off ``s`` (shared with every loop planner, :class:`IKLoopConfig`): the push
equals the attraction's cruising speed ``speed_max`` at ``d = s``, hence
``k = speed_max s^2 / (1/s - 1/d0)``.

Distance floor: ``d`` is replaced by ``max(d, d_floor)`` so the push stays finite when a point
touches or enters an obstacle (``d <= 0``); the direction still comes from the geometry (coal's
separating normal, or the signed distance's gradient), so it keeps pointing outwards.
"""

from __future__ import annotations

import numpy as np

__all__ = ["khatib_gain", "khatib_magnitude"]


def khatib_gain(speed_max: float, standoff: float, influence_distance: float) -> float:
    """``k`` [m^2/s] such that ``khatib_magnitude(standoff) == speed_max``; needs ``standoff < d0``."""
    if not 0 < standoff < influence_distance:
        raise ValueError(f"standoff {standoff} m must be in (0, influence_distance = {influence_distance} m)")
    return speed_max * standoff**2 / (1.0 / standoff - 1.0 / influence_distance)


def khatib_magnitude(d: np.ndarray, gain: float, influence_distance: float, floor: float) -> np.ndarray:
    """``k (1/d - 1/d0) / d^2`` [m/s] with ``d`` floored at ``floor`` [m]; 0 where ``d >= d0``."""
    dd = np.maximum(np.asarray(d, dtype=float), floor)
    out = gain * (1.0 / dd - 1.0 / influence_distance) / (dd * dd)
    return np.where(dd < influence_distance, out, 0.0)
