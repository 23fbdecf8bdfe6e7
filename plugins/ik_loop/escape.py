"""Leaving local minima: a bounded detour to a collision-free configuration nearby.

A reactive loop stops where its pull and its push cancel (a local minimum) or where the push came
too late (the periodic check finds the arm in collision). Either way, from the same configuration
the same deterministic step repeats the same mistake. The escape changes the configuration: it
draws a target ``q_e = c + N(0, radius^2 I)`` (clipped to the limits) with the query's random
generator, centred ``c = q`` (a random detour) or, when the problem gives a goal configuration
``q_g`` and ``toward_goal`` is set, on every other draw from the first, ``c = q + u (q_g - q)``
with ``u ~ U(0.2, 1)`` (part of the way to the goal configuration, so the pose task resumes in the
goal's own IK branch: on an arm without redundancy a Jacobian step never crosses from one branch
to another). A target is taken when it is free of collision and the straight joint-space motion to
it is certified free by the harness's own checker (so an escape never adds a collision the harness
would find, even between samples), at most ``draws`` draws; the arm moves there at the velocity
limits and the loop resumes. After a collision the loop first rewinds to the last configuration
the periodic check found free. Each query allows ``escape_attempts`` escapes; the result's
``info`` says how many fired, after what, and toward what.
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
    goal: np.ndarray | None = None,
    toward_goal: bool = False,
    scales: int = 1,
) -> tuple[np.ndarray | None, int, bool]:
    """``(motion, draws used, toward the goal)``: the configurations (m, n) of the move from ``q``
    to a free target drawn as in the module docstring (``radius`` [rad]; ``goal`` the goal
    configuration or None, ``toward_goal``: every other draw centred towards it), one per step of
    ``dt`` [s] at the velocity limits ``qd_max`` [rad/s] (``q`` itself excluded, the target last),
    or ``None`` when none of ``draws`` candidates is reachable in a straight line without
    collision. ``in_collision(q)`` answers for one configuration (a quick rejection),
    ``segment_free(a, b)`` for the motion. ``scales`` > 1 cycles the radius through ``radius``,
    ``radius / 2``, ... ``radius / 2**(scales - 1)`` from one draw to the next, so that in clutter,
    where a long straight move rarely stays free, shorter detours are tried too."""
    for draw in range(1, draws + 1):
        toward = toward_goal and goal is not None and draw % 2 == 1
        centre = q + rng.uniform(0.2, 1.0) * (goal - q) if toward and goal is not None else q
        scale = 0.5 ** (((draw - 1) // 2) % scales)  # both kinds of draw see every scale
        target = np.clip(centre + rng.normal(0.0, radius * scale, size=q.shape), lower, upper)
        delta = target - q
        if in_collision(target) or not segment_free(q, target):
            continue
        steps = max(1, math.ceil(float(np.max(np.abs(delta) / (qd_max * dt)))))
        motion = np.clip(q + delta * (np.arange(1, steps + 1) / steps)[:, None], lower, upper)
        motion[-1] = target  # exactly (rounding of q + delta could step past a limit it lies on)
        return motion, draw, toward
    return None, draws, False
