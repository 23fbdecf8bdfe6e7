"""Settings of the potential-field baselines: the IK loop's (shared with ``matrix-field``) plus
the Khatib profile (:mod:`planbench_plugins.ik_loop.khatib`) and, for ``edt-field``, the grid.

Only the repulsion source differs from ``matrix-field``; every other setting (attraction,
damping, secondary tasks, slow-down, limits, endings, dense path check) has the same name,
meaning and default, so a comparison with the same settings compares the fields.
"""

from __future__ import annotations

from dataclasses import dataclass

from planbench.errors import InvalidConfigError
from planbench_plugins.ik_loop import IKLoopConfig, check_number

__all__ = ["PotentialFieldConfig", "DistanceFieldConfig", "EDTFieldConfig"]


@dataclass(frozen=True)
class PotentialFieldConfig(IKLoopConfig):
    """The loop's settings plus Khatib's profile ``|f| = k (1/d - 1/d0) / d^2`` [m/s].

    Gain ``k`` [m^2/s] from the loop's ``standoff``, so that the push equals ``speed_max`` at
    ``d = standoff``: ``k = speed_max standoff^2 / (1/standoff - 1/influence_distance)``, times
    ``repulsion_gain`` [-].
    """

    influence_distance: float = 0.15
    """``d0`` [m]: no push at or beyond it (0.15 m: the matrix field's ``kernel_reach``, for parity)."""
    distance_floor: float = 0.01
    """``d`` is floored here [m] so that contact and penetration give a finite, outward push
    (the push at the floor is the largest, ~2800x ``speed_max`` with the defaults)."""

    def validate(self) -> None:
        super().validate()
        for name in ("influence_distance", "distance_floor"):
            check_number(self, name, lambda v: v > 0, "finite and > 0")
        if self.standoff >= self.influence_distance:
            raise InvalidConfigError(
                f"standoff {self.standoff} m must be below influence_distance {self.influence_distance} m: "
                "the push is zero beyond the influence distance, so no gain can push there"
            )
        if self.distance_floor >= self.standoff:
            raise InvalidConfigError(
                f"distance_floor {self.distance_floor} m must be below standoff {self.standoff} m "
                "(it only keeps the push finite at contact); use e.g. 0.01"
            )


@dataclass(frozen=True)
class DistanceFieldConfig(PotentialFieldConfig):
    """Settings of ``distance-field``: ``d`` is coal's exact distance between a robot link's
    collision geometry (its convex hull) and an obstacle, so ``standoff`` and
    ``influence_distance`` are measured from the link *surface* (the grid fields measure them
    from control points on the link axes, 0.05-0.09 m inside the surface on the Panda)."""


@dataclass(frozen=True)
class EDTFieldConfig(PotentialFieldConfig):
    """Settings of ``edt-field``: ``d`` is the signed Euclidean distance transform of the scene's
    occupancy grid, sampled at the matrix field's control points (on the link axes)."""

    grid_resolution: float = 0.02
    """Occupancy grid cell size [m] (the matrix field's)."""

    def validate(self) -> None:
        super().validate()
        check_number(self, "grid_resolution", lambda v: v > 0, "finite and > 0")
