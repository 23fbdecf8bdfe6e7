"""Leaving local minima: a bounded detour to a random collision-free configuration nearby.

A reactive loop stops where its pull and its push cancel (a local minimum) or where the push came
too late (the periodic check finds the arm in collision). Either way, from the same configuration
the same deterministic step repeats the same mistake. The escape changes the configuration: it
draws ``q_e = q + N(0, radius^2 I)`` (clipped to the limits) with the query's random generator
until ``q_e`` is free of collision and the straight joint-space motion to it is certified free by
the harness's own checker (so an escape never adds a collision the harness would find, even
between samples), at most ``draws`` times, and moves there at
the velocity limits; the loop then resumes from ``q_e`` (the pose task now starts elsewhere and
redundancy is resolved from elsewhere). After a collision the loop first rewinds to the last
configuration the periodic check found free. Each query allows ``escape_attempts`` escapes; the
result's ``info`` says how many fired and after what.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["escape_motion"]


def escape_motion(
    q: np.ndarray,
    rng: np.random.Generator,
    in_collision: Any,
    segment_free: Any,
    lower: np.ndarray,
    upper: np.ndarray,
    qd_max: np.ndarray,
    dt: float,
    radius: float,
    draws: int,
) -> tuple[np.ndarray | None, int]:
    """``(motion, draws used)``: the configurations (m, n) of the move from ``q`` to a random free
    configuration within about ``radius`` [rad] of it, one per step of ``dt`` [s] at the velocity
    limits ``qd_max`` [rad/s] (``q`` itself excluded, the target last), or ``None`` when none of
    ``draws`` candidates is reachable in a straight line without collision. ``in_collision(q)``
    answers for one configuration (a quick rejection), ``segment_free(a, b)`` for the motion."""
    for draw in range(1, draws + 1):
        target = np.clip(q + rng.normal(0.0, radius, size=q.shape), lower, upper)
        delta = target - q
        if in_collision(target) or not segment_free(q, target):
            continue
        steps = max(1, math.ceil(float(np.max(np.abs(delta) / (qd_max * dt)))))
        motion = np.clip(q + delta * (np.arange(1, steps + 1) / steps)[:, None], lower, upper)
        motion[-1] = target  # exactly (rounding of q + delta could step past a limit it lies on)
        return motion, draw
    return None, draws
