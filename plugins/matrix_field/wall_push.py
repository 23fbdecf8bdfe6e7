"""The matrix field's push read as a wall distance (``field_push="khatib"``, issue 32).

The directional kernels' push ``k_rep |F|`` is bounded: with the linear profile a point touching a
flat wall is pushed at about twice the push at the stand-off, a thin bar or a post at less than
the stand-off's (docs/planners.md, "Contact: the matrix field's push near obstacles"). The
distance baselines push with Khatib's profile, which grows like ``1/d^3`` close in; on the Panda
that push, through the loop's slow-down and velocity scaling, holds the hand back before its
fingers reach an obstacle where the matrix field lets the pull carry them in.

Here the field keeps its direction and its sense of proximity, and only the magnitude is mapped:
``|F|`` is read as the distance ``d_w`` at which a flat, one-cell-thick wall gives that field
(:func:`~planbench.field.scene_field.wall_field`, the curve the stand-off gain is derived from), and
the push is Khatib's at that distance, ``|f| = k (1/d_w - 1/d0) / d_w^2``, with ``k`` from the same
stand-off, ``d0 = kernel_reach`` and ``d_w`` floored at ``distance_floor`` (``edt-field``'s profile
and settings). At a flat wall the push is therefore ``edt-field``'s; a field above the wall
curve's maximum (a thick or nearby block) continues the curve's first slope down to the floor.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planbench.field.kernels import Kernels
from planbench.field.scene_field import wall_field
from planbench_plugins.ik_loop import ArmKinematics, Repulsion, khatib_gain, khatib_magnitude

__all__ = ["WallKhatibRepulsion", "wall_curve"]


def wall_curve(kernels: Kernels, gain: float) -> tuple[np.ndarray, np.ndarray]:
    """``(push, distance)``: the push ``gain * F_wall(d)`` [m/s] of a flat wall at distances ``d``
    [m] from a quarter cell up to the kernel's reach plus a cell, kept from its maximum on (where
    it falls with the distance) and made non-increasing; the last entry is ``(0, reach + cell)``.
    Both arrays increase with the push (for ``np.interp``)."""
    r = kernels.resolution
    d = np.arange(0.25 * r, kernels.reach + r, 0.25 * r)
    push = gain * np.array([wall_field(kernels, float(x)) for x in d])
    top = int(np.argmax(push))
    d, push = d[top:], np.minimum.accumulate(push[top:])
    d, push = np.append(d, kernels.reach + r), np.append(push, 0.0)
    return push[::-1].copy(), d[::-1].copy()


class WallKhatibRepulsion:
    """``inner``'s matrix-field push with its magnitude mapped to Khatib's at the wall distance
    (module docstring), into a buffer of its own (the loop's compiled step stays bound to it)."""

    def __init__(
        self,
        inner: Repulsion,
        kernels: Kernels,
        speed_max: float,
        standoff: float,
        reach: float,
        floor: float,
        hand_only: bool = False,
        at_least_linear: bool = False,
    ) -> None:
        self.inner, self.hand_only, self.at_least_linear = inner, bool(hand_only), bool(at_least_linear)
        self.d0, self.floor = float(reach), float(floor)
        self.khatib = (
            float(inner.gain) / self_gain(kernels, speed_max, standoff) * khatib_gain(speed_max, standoff, self.d0)
        )  # repulsion_gain carried over from the inner gain
        self.push, self.distance = wall_curve(kernels, float(inner.gain))
        top_push, top_d = self.push[-1], self.distance[-1]
        i = max(0, len(self.push) - 2)
        slope = (self.distance[i] - top_d) / (top_push - self.push[i]) if top_push > self.push[i] else 0.0
        self.top_push, self.top_d, self.slope = float(top_push), float(top_d), float(slope)  # m per m/s
        self._F = np.zeros((0, 3))

    @property
    def gain(self) -> float:
        return float(self.inner.gain)

    def restart(self) -> None:
        restart = getattr(self.inner, "restart", None)
        if callable(restart):
            restart()

    def field_at(self, points: np.ndarray) -> np.ndarray:
        """The matrix field (N, 3) at world points, in field units (before the gain and the map)."""
        return self.inner.field_at(points)  # type: ignore[attr-defined,no-any-return]

    def wall_distance(self, push: np.ndarray) -> np.ndarray:
        """The distance [m] of a flat wall pushing at ``push`` [m/s] (floored at ``distance_floor``)."""
        d = np.interp(push, self.push, self.distance)
        above = push > self.top_push
        if above.any():
            d = np.where(above, self.top_d - (push - self.top_push) * self.slope, d)
        return np.maximum(d, self.floor)

    def map(self, F: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Pushes ``F`` (N, 3) [m/s] with their magnitudes mapped (module docstring), into ``out``."""
        u = np.sqrt(np.einsum("ij,ij->i", F, F))
        mag = khatib_magnitude(self.wall_distance(u), self.khatib, self.d0, self.floor)
        if self.at_least_linear:  # the linear push where it is the larger (beyond the stand-off at a wall)
            mag = np.maximum(mag, u)
        scale = np.divide(mag, u, out=np.zeros_like(u), where=u > 0)
        np.multiply(F, scale[:, None], out=out)
        return out

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        points, F, support, joint = self.inner.forces(kin)
        if self._F.shape != F.shape:
            self._F = np.empty_like(F)
        if self.hand_only:  # the points the arm's last joint carries (hand, fingers) mapped, the rest as they are
            self._F[:] = F
            last = joint == joint.max()
            self._F[last] = self.map(F[last], np.empty((int(last.sum()), 3)))
        else:
            self.map(F, self._F)
        return points, self._F, support, joint


def self_gain(kernels: Kernels, speed_max: float, standoff: float) -> float:
    """The matrix field's gain from the stand-off alone (``repulsion_gain`` 1)."""
    f = wall_field(kernels, standoff)
    return speed_max / f if f > 0 else 1.0


def wall_khatib(inner: Repulsion, config: Any) -> WallKhatibRepulsion:
    """``inner`` (the matrix field's push for ``config``) mapped as in the module docstring."""
    return WallKhatibRepulsion(
        inner,
        config.kernels(),
        config.speed_max,
        config.standoff,
        config.kernel_reach,
        config.distance_floor,
        hand_only=config.field_push == "khatib-hand",
        at_least_linear=config.field_push == "contact",
    )
