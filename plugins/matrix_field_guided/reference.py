"""The global path as a reference trajectory, and how far a tracked path departs from it.

The waypoints are joined by straight joint-space segments, each timed by its slowest joint at a
fraction of the velocity limits, so the reference ``q_ref(t)`` is piecewise linear with a
piecewise-constant velocity (the feed-forward term of the tracking).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Reference", "departure"]


class Reference:
    """``waypoints`` (K, n) [rad] timed at ``speed`` (n,) [rad/s] per joint."""

    def __init__(self, waypoints: np.ndarray, speed: np.ndarray) -> None:
        self.waypoints = w = np.asarray(waypoints, dtype=float)
        delta = np.diff(w, axis=0)
        self.durations = np.max(np.abs(delta) / speed, axis=1) if len(w) > 1 else np.zeros(0)  # [s]
        keep = self.durations > 0  # repeated waypoints take no time
        self._start = w[:-1][keep]
        self._velocity = delta[keep] / self.durations[keep, None]
        self._t0 = np.concatenate(([0.0], np.cumsum(self.durations[keep])))
        self.duration = float(self._t0[-1])
        lengths = np.linalg.norm(delta, axis=1)
        self._remaining = np.concatenate((np.cumsum(lengths[::-1])[::-1], [0.0]))[:-1][keep]
        self._lengths = lengths[keep]
        self.end = w[-1]

    def next_time(self, t: float, dt: float) -> float:
        """``t + dt``, or the first waypoint's time after ``t`` when that comes sooner: a tracking
        step then ends on the corner instead of cutting it (and never past the end)."""
        i = int(np.searchsorted(self._t0, t, side="right"))
        return min(t + dt, float(self._t0[i])) if i < len(self._t0) else self.duration

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, float]:
        """``(q_ref, qd_ref, remaining)`` at time ``t`` [s]: the reference configuration, its
        velocity (0 once the reference has arrived) and the joint path length [rad] left to the
        end."""
        if t >= self.duration or not len(self._start):
            return self.end, np.zeros_like(self.end), 0.0
        i = int(np.searchsorted(self._t0, t, side="right")) - 1
        u = t - self._t0[i]
        frac = u / (self._t0[i + 1] - self._t0[i])
        remaining = self._remaining[i] - frac * self._lengths[i]
        return self._start[i] + self._velocity[i] * u, self._velocity[i], float(remaining)


def departure(path: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Distance [rad] (Euclidean in joint space) from each configuration of ``path`` (N, n) to the
    polyline through ``waypoints`` (K, n)."""
    path = np.asarray(path, dtype=float)
    w = np.asarray(waypoints, dtype=float)
    if len(w) == 1:
        return np.linalg.norm(path - w[0], axis=1)
    a, d = w[:-1], np.diff(w, axis=0)  # (S, n)
    dd = np.einsum("sj,sj->s", d, d)
    rel = path[:, None, :] - a[None]  # (N, S, n)
    u = np.clip(np.einsum("nsj,sj->ns", rel, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    closest = a[None] + u[..., None] * d[None]
    return np.min(np.linalg.norm(path[:, None, :] - closest, axis=2), axis=1)
