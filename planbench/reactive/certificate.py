"""A scenario's solvability certificate: a timed joint trajectory that solves it.

Stored in the scenario's JSON under ``"certificate"`` (optional)::

    "certificate": {"planner": "spacetime", "time_to_goal": 2.41, "times": [0, 0.5, ...],
                    "path": [[q1, ..., qn], ...], "budget": 30, "planning_time": 1.8}

``times`` [s] (starting at 0, strictly increasing) and ``path`` [rad], one configuration per
time: the arm moves linearly between knots and holds the last configuration after the last. The
certificate proves the scenario can be solved only once it is re-judged
(:func:`planbench.reactive.solvability.verify_certificate`): sampled at the control ticks, it must
start at the problem's start, stay within the velocity and joint limits, pass every tick's
certified check against the moving geometry and end within the goal's tolerances, exactly as a
controller's run. Loading a scenario checks only the certificate's form (the judgement takes
seconds); ``planner``, ``budget`` [s] and ``planning_time`` [s] say how it was found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Certificate"]

_KEYS = {"planner", "time_to_goal", "times", "path", "budget", "planning_time"}
TIME_DECIMALS = 6
"""Knot times are written to the microsecond [s]."""
ANGLE_DECIMALS = 6
"""Knot configurations are written to the microradian [rad] (the first, the start, whole)."""


@dataclass(frozen=True, eq=False)
class Certificate:
    """A timed trajectory that solves a scenario (module docstring). Times in s, angles in rad."""

    times: np.ndarray
    """(m,) knot times [s]: 0 first, strictly increasing."""
    path: np.ndarray
    """(m, nq) knot configurations [rad]."""
    time_to_goal: float
    """When the end effector is first within the goal's tolerances at a control tick [s]."""
    planner: str = "spacetime"
    budget: float = math.nan
    """The search's time budget [s] (NaN: not recorded)."""
    planning_time: float = math.nan
    """How long the search took [s] (NaN: not recorded)."""

    def __post_init__(self) -> None:
        times = np.array(self.times, dtype=float)
        path = np.array(self.path, dtype=float)
        if times.ndim != 1 or len(times) < 1:
            raise ValueError("'times' must be a list of at least one number [s]")
        if path.ndim != 2 or path.shape[0] != len(times) or path.shape[1] < 1:
            raise ValueError(f"'path' must hold one configuration per time ({len(times)} lists of joint values)")
        if not (np.isfinite(times).all() and np.isfinite(path).all()):
            raise ValueError("'times' and 'path' must be finite numbers")
        if times[0] != 0 or np.any(np.diff(times) <= 0):
            raise ValueError("'times' must start at 0 and increase strictly [s]")
        if not (math.isfinite(self.time_to_goal) and self.time_to_goal >= 0):
            raise ValueError(f"'time_to_goal' must be a finite number >= 0 [s], got {self.time_to_goal!r}")
        for name in ("budget", "planning_time"):
            v = getattr(self, name)
            if not (math.isnan(v) or v >= 0):
                raise ValueError(f"{name!r} must be a number >= 0 [s], got {v!r}")
        times.flags.writeable = False
        path.flags.writeable = False
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "path", path)

    @property
    def nq(self) -> int:
        return int(self.path.shape[1])

    def at(self, t: np.ndarray) -> np.ndarray:
        """The configurations at times ``t`` [s] (linear between knots, the last held after it)."""
        t = np.asarray(t, dtype=float)
        return np.stack([np.interp(t, self.times, self.path[:, j]) for j in range(self.nq)], axis=-1)

    def rounded(self) -> Certificate:
        """This certificate with its numbers rounded as they are written (the first knot, the
        problem's start, kept whole): what a file holds, and what must be judged again."""
        path = np.round(self.path, ANGLE_DECIMALS)
        path[0] = self.path[0]
        return Certificate(
            np.round(self.times, TIME_DECIMALS),
            path,
            round(self.time_to_goal, TIME_DECIMALS),
            self.planner,
            round(self.budget, 3) if math.isfinite(self.budget) else self.budget,
            round(self.planning_time, 3) if math.isfinite(self.planning_time) else self.planning_time,
        )

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "planner": self.planner,
            "time_to_goal": self.time_to_goal,
            "times": self.times.tolist(),
            "path": self.path.tolist(),
        }
        for name in ("budget", "planning_time"):
            if math.isfinite(getattr(self, name)):
                d[name] = getattr(self, name)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> Certificate:
        """A certificate from its JSON object; ``ValueError`` naming the field that is wrong."""
        if not isinstance(d, dict):
            raise ValueError(f"must be a JSON object, got {type(d).__name__}")
        unknown = set(d) - _KEYS
        if unknown:
            raise ValueError(f"unknown keys {sorted(unknown)}; allowed {sorted(_KEYS)}")
        missing = {"times", "path", "time_to_goal"} - set(d)
        if missing:
            raise ValueError(f"missing {sorted(missing)}")
        planner = d.get("planner", "spacetime")
        if not isinstance(planner, str):
            raise ValueError(f"'planner' must be a name, got {planner!r}")
        args = {}
        for name in ("times", "path"):
            try:
                args[name] = np.array(d[name], dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{name!r} must be a list of numbers (path: of joint-value lists)") from None
        numbers = {}
        for name in ("time_to_goal", "budget", "planning_time"):
            v = d.get(name, math.nan)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{name!r} must be a number [s], got {v!r}")
            numbers[name] = float(v)
        return cls(args["times"], args["path"], planner=planner, **numbers)
