"""How a moving obstacle moves: its pose as a function of time, and a bound on its speed.

Every motion is a rigid displacement of the obstacle from the pose written in the scenario (its
``position`` and ``orientation_xyzw`` at rest). Translations add an offset ``d(t)`` [m]; a swing
rotates the obstacle about an axis through a pivot. Kinds (``"type"`` in JSON):

- ``static``: no motion.
- ``waypoints``: ``times`` [s] (strictly increasing) and ``offsets`` [m], one per time; linear in
  between, the first offset before the first time, the last after the last.
- ``velocity``: ``velocity`` [m/s] from ``start`` to ``stop`` [s] (default 0 and forever); the
  offset is ``velocity * (clip(t, start, stop) - start)``.
- ``sinusoid``: offset ``amplitude * sin(2 pi frequency t + phase)`` ([m], [Hz], [rad]).
- ``swing``: rotation by ``amplitude * sin(2 pi frequency t + phase)`` [rad] about ``axis``
  through ``pivot`` [m] (a person's forearm swinging about the elbow).

:meth:`Motion.speed_bound` bounds how fast any point of the obstacle moves [m/s]; the certified
check of a control tick widens each moving obstacle by what it may travel in the tick
(:mod:`planbench.reactive.checker`), so a collision between ticks cannot be missed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

__all__ = ["MOTIONS", "Motion"]

MOTIONS = ("static", "waypoints", "velocity", "sinusoid", "swing")

_KEYS = {
    "static": set(),
    "waypoints": {"times", "offsets"},
    "velocity": {"velocity", "start", "stop"},
    "sinusoid": {"amplitude", "frequency", "phase"},
    "swing": {"pivot", "axis", "amplitude", "frequency", "phase"},
}
_REQUIRED = {
    "static": set(),
    "waypoints": {"times", "offsets"},
    "velocity": {"velocity"},
    "sinusoid": {"amplitude", "frequency"},
    "swing": {"pivot", "axis", "amplitude", "frequency"},
}


@dataclass(frozen=True)
class Motion:
    """One motion (module docstring). Units: m, s, Hz, rad."""

    type: str = "static"
    times: tuple[float, ...] = ()
    offsets: tuple[tuple[float, float, float], ...] = ()
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start: float = 0.0
    stop: float = math.inf
    amplitude: Any = 0.0  # sinusoid: (3,) [m]; swing: a scalar [rad]
    frequency: float = 0.0
    phase: float = 0.0
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        if self.type not in MOTIONS:
            raise ValueError(f"unknown motion type {self.type!r}; use one of {MOTIONS}")
        if self.type == "waypoints":
            t = np.asarray(self.times, dtype=float)
            o = np.asarray(self.offsets, dtype=float)
            if t.ndim != 1 or len(t) < 1 or o.shape != (len(t), 3):
                raise ValueError("waypoints need 'times' (N,) and 'offsets' (N, 3) with N >= 1")
            if not (np.isfinite(t).all() and np.isfinite(o).all()):
                raise ValueError("waypoint times and offsets must be finite")
            if np.any(np.diff(t) <= 0):
                raise ValueError(f"waypoint times must be strictly increasing, got {t.tolist()}")
        if self.type == "velocity":
            _finite(self.velocity, 3, "velocity")
            if not (math.isfinite(self.start) and self.stop > self.start):
                raise ValueError(f"velocity motion needs a finite start before stop, got {self.start}, {self.stop}")
        if self.type in ("sinusoid", "swing"):
            if not (math.isfinite(self.frequency) and self.frequency >= 0 and math.isfinite(self.phase)):
                raise ValueError(f"frequency must be finite and >= 0 [Hz], phase finite [rad]: {self.frequency}")
            _finite(self.amplitude, 3 if self.type == "sinusoid" else None, "amplitude")
        if self.type == "swing":
            _finite(self.pivot, 3, "pivot")
            _finite(self.axis, 3, "axis")
            if np.linalg.norm(self.axis) < 1e-9:
                raise ValueError("swing axis must not be zero")

    # --- poses ------------------------------------------------------------------------------
    def pose(self, rest: Any, t: float) -> Any:
        """The obstacle's pose (``pinocchio.SE3``) at time ``t`` [s], from its pose at rest."""
        if self.type == "static":
            return rest
        if self.type == "swing":
            angle = float(self.amplitude) * math.sin(2 * math.pi * self.frequency * t + self.phase)
            axis = np.asarray(self.axis, dtype=float)
            R = pin.exp3(axis / np.linalg.norm(axis) * angle)
            pivot = np.asarray(self.pivot, dtype=float)
            return pin.SE3(R @ rest.rotation, pivot + R @ (rest.translation - pivot))
        return pin.SE3(rest.rotation, rest.translation + self.offset(t))

    def offset(self, t: float) -> np.ndarray:
        """The translation [m] at time ``t`` (zero for ``static`` and ``swing``)."""
        if self.type == "waypoints":
            t_arr = np.asarray(self.times, dtype=float)
            o = np.asarray(self.offsets, dtype=float)
            return np.array([np.interp(t, t_arr, o[:, a]) for a in range(3)])
        if self.type == "velocity":
            return np.asarray(self.velocity, dtype=float) * (min(max(t, self.start), self.stop) - self.start)
        if self.type == "sinusoid":
            return np.asarray(self.amplitude, dtype=float) * math.sin(2 * math.pi * self.frequency * t + self.phase)
        return np.zeros(3)

    def speed_bound(self, radius: float, rest_position: Any) -> float:
        """An upper bound [m/s] on the speed of any point of an obstacle whose points lie within
        ``radius`` [m] of its ``rest_position`` (a swing moves far points fastest)."""
        if self.type == "static":
            return 0.0
        if self.type == "waypoints":
            if len(self.times) < 2:
                return 0.0
            steps = np.diff(np.asarray(self.offsets, dtype=float), axis=0)
            return float(np.max(np.linalg.norm(steps, axis=1) / np.diff(self.times)))
        if self.type == "velocity":
            return float(np.linalg.norm(self.velocity))
        omega = 2 * math.pi * self.frequency
        if self.type == "sinusoid":
            return omega * float(np.linalg.norm(self.amplitude))
        arm = float(np.linalg.norm(np.asarray(rest_position, dtype=float) - np.asarray(self.pivot))) + radius
        return omega * abs(float(self.amplitude)) * arm

    # --- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"type": self.type}
        if self.type == "waypoints":
            d.update(times=list(self.times), offsets=[list(o) for o in self.offsets])
        elif self.type == "velocity":
            d.update(velocity=list(self.velocity), start=self.start)
            if math.isfinite(self.stop):
                d["stop"] = self.stop
        elif self.type in ("sinusoid", "swing"):
            amp = self.amplitude
            d.update(amplitude=list(amp) if self.type == "sinusoid" else float(amp))
            d.update(frequency=self.frequency, phase=self.phase)
            if self.type == "swing":
                d.update(pivot=list(self.pivot), axis=list(self.axis))
        return d

    @classmethod
    def from_dict(cls, d: Any) -> Motion:
        """A motion from its JSON object; ``ValueError`` naming what is wrong."""
        if not isinstance(d, dict):
            raise ValueError(f"a motion must be a JSON object, got {type(d).__name__}")
        kind = d.get("type")
        if kind not in MOTIONS:
            raise ValueError(f"motion 'type' must be one of {MOTIONS}, got {kind!r}")
        unknown = set(d) - _KEYS[kind] - {"type"}
        if unknown:
            raise ValueError(f"{kind} motion: unknown keys {sorted(unknown)}; allowed {sorted(_KEYS[kind])}")
        missing = _REQUIRED[kind] - set(d)
        if missing:
            raise ValueError(f"{kind} motion: missing {sorted(missing)}")
        args: dict[str, Any] = {"type": kind}
        try:
            for key in ("start", "stop", "frequency", "phase"):
                if key in d:
                    args[key] = float(d[key])
            for key in ("velocity", "pivot", "axis"):
                if key in d:
                    args[key] = tuple(float(x) for x in d[key])
            if "times" in d:
                args["times"] = tuple(float(x) for x in d["times"])
            if "offsets" in d:
                args["offsets"] = tuple(tuple(float(x) for x in o) for o in d["offsets"])
            if "amplitude" in d:
                a = d["amplitude"]
                args["amplitude"] = tuple(float(x) for x in a) if kind == "sinusoid" else float(a)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{kind} motion: numbers expected ({exc})") from None
        return cls(**args)


def _finite(v: Any, n: int | None, what: str) -> None:
    a = np.asarray(v, dtype=float)
    if n is not None and a.shape != (n,):
        raise ValueError(f"{what} must have {n} values, got {a.tolist()}")
    if n is None and a.shape != ():
        raise ValueError(f"{what} must be one number, got {a.tolist()}")
    if not np.isfinite(a).all():
        raise ValueError(f"{what} must be finite, got {a.tolist()}")
