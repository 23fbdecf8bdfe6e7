"""Path metrics as plain functions of arrays, so each has an exact, testable definition; and the
interval of a success rate over runs."""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "densify",
    "joint_path_length",
    "polyline_length",
    "execution_duration",
    "limited_duration",
    "turning_angle",
    "wilson_interval",
]


def densify(path: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Interpolate a joint path linearly so that no joint moves more than ``resolution`` between
    consecutive configurations. Returns the dense states (M, nq) and, for each, the index of the
    path segment it lies on (waypoint ``k`` itself belongs to segment ``k - 1``, the start to 0).
    """
    path = np.asarray(path, dtype=float)
    if len(path) == 1:
        return path.copy(), np.zeros(1, dtype=int)
    steps = np.maximum(1, np.ceil(np.abs(np.diff(path, axis=0)).max(axis=1) / resolution - 1e-12)).astype(int)
    states = [path[:1]]
    segment = [np.zeros(1, dtype=int)]
    for k, n in enumerate(steps):
        s = (np.arange(1, n + 1) / n)[:, None]
        states.append(path[k] + s * (path[k + 1] - path[k]))
        segment.append(np.full(n, k))
    return np.concatenate(states), np.concatenate(segment)


def joint_path_length(path: np.ndarray) -> float:
    """Sum of Euclidean joint-space segment lengths [rad] (the L2 C-space cost OMPL reports)."""
    return polyline_length(path)


def polyline_length(points: np.ndarray) -> float:
    """Length of a polyline through the rows of ``points``."""
    points = np.asarray(points, dtype=float)
    if len(points) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def execution_duration(path: np.ndarray, velocity_limit: np.ndarray) -> float:
    """Time [s] to follow the path segment by segment in straight lines, each segment at the
    speed where its slowest joint runs at its velocity limit (infinite acceleration)."""
    path = np.asarray(path, dtype=float)
    if len(path) < 2:
        return 0.0
    return float((np.abs(np.diff(path, axis=0)) / np.asarray(velocity_limit)).max(axis=1).sum())


TIMING_SPACING = 0.02
"""[rad] Joint-space spacing at which a path is resampled before :func:`limited_duration` fits its
spline: dense enough that the spline stays within millimetres of the straight segments."""


def limited_duration(path: np.ndarray, velocity_limit: np.ndarray, acceleration_limit: np.ndarray) -> float:
    """Time [s] to follow the path under the joints' velocity and acceleration limits: toppra's
    time-optimal parameterisation (Pham and Pham, "A new approach to time-optimal path
    parameterization based on reachability analysis", IEEE T-RO 34(3), 2018) of a cubic spline
    through the path resampled every :data:`TIMING_SPACING` rad of joint-space length. NaN when an
    acceleration limit is unknown or toppra finds no parameterisation; 0 for a path that does not
    move. :func:`execution_duration` is the same figure with infinite acceleration."""
    path = np.asarray(path, dtype=float)
    amax = np.asarray(acceleration_limit, dtype=float)
    if not np.all(np.isfinite(amax)):
        return math.nan
    if len(path) < 2:
        return 0.0
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    if s[-1] <= 1e-12:
        return 0.0
    import toppra
    import toppra.algorithm
    import toppra.constraint

    keep = np.unique(np.concatenate([[0], np.flatnonzero(np.diff(np.floor(s / TIMING_SPACING)) > 0) + 1, [len(s) - 1]]))
    keep = keep[np.concatenate([[True], np.diff(s[keep]) > 1e-9])]  # strictly increasing arc length
    if len(keep) < 2:
        return 0.0
    spline = toppra.SplineInterpolator(s[keep], path[keep])
    vmax = np.asarray(velocity_limit, dtype=float)
    constraints = [
        toppra.constraint.JointVelocityConstraint(np.stack([-vmax, vmax], axis=1)),
        toppra.constraint.JointAccelerationConstraint(np.stack([-amax, amax], axis=1)),
    ]
    instance = toppra.algorithm.TOPPRA(constraints, spline, parametrizer="ParametrizeConstAccel")
    trajectory = instance.compute_trajectory()
    return math.nan if trajectory is None else float(trajectory.duration)


def turning_angle(path: np.ndarray, min_segment: float = 1e-9) -> float:
    """Smoothness: the total turning angle [rad] between consecutive joint-space segments
    (0 for a straight line; each sharp reversal adds pi). Segments shorter than ``min_segment``
    are dropped first, so repeated waypoints do not count as turns."""
    d = np.diff(np.asarray(path, dtype=float), axis=0)
    norms = np.linalg.norm(d, axis=1)
    d = d[norms > min_segment] / norms[norms > min_segment][:, None]
    if len(d) < 2:
        return 0.0
    cos = np.clip(np.einsum("ij,ij->i", d[:-1], d[1:]), -1.0, 1.0)
    return float(np.arccos(cos).sum())


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy's ``binomtest(...).proportion_ci``).

    Unlike the normal approximation it stays inside [0, 1] and is sensible at 0 or n successes.
    (NaN, NaN) without runs.
    """
    if n <= 0:
        return (math.nan, math.nan)
    from scipy.stats import binomtest  # on use: scipy.stats takes a second to import

    ci = binomtest(successes, n).proportion_ci(confidence, method="wilson")
    return (float(ci.low), float(ci.high))
