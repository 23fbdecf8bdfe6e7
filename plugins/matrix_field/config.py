"""Settings of the matrix-field planner: the IK loop's (:class:`~planbench_plugins.ik_loop.IKLoopConfig`)
plus the field's (:class:`~planbench.field.scene_field.FieldSettings`) and which field pushes
(``field_kind``: the matrix field as specified, or the calibrated distance of docs/method.md, section 8).

Units: metres, radians, seconds. Field values are dimensionless sums of occupancy times kernel
weight; the gain derived from the stand-off (times ``repulsion_gain``) turns them into a speed [m/s].
The calibrated field is a distance [m], turned into a speed by Khatib's profile.
"""

from __future__ import annotations

from dataclasses import dataclass

from planbench.errors import InvalidConfigError
from planbench.field.scene_field import FIELD_MODES, FieldSettings
from planbench_plugins.ik_loop import IKLoopConfig, check_number

__all__ = ["MatrixFieldConfig", "FIELD_KINDS", "FIELD_MODES", "FIELD_PUSHES"]

FIELD_KINDS = ("matrix", "calibrated")
FIELD_PUSHES = ("linear", "khatib", "khatib-hand", "contact")


@dataclass(frozen=True)
class MatrixFieldConfig(FieldSettings, IKLoopConfig):
    """Settings of :class:`~planbench_plugins.matrix_field.MatrixFieldPlanner`: the loop's
    (:class:`~planbench_plugins.ik_loop.IKLoopConfig`) plus the grid and the kernels
    (:class:`~planbench.field.scene_field.FieldSettings`).

    Stand-off: the field is exactly zero farther than ``kernel_reach`` from every occupied cell,
    so nothing pushes a control point beyond that distance. Closer in, ``standoff`` fixes the gain:
    ``k_rep = repulsion_gain * speed_max / F_wall(standoff)`` [m/s per field unit], where ``F_wall(d)`` is
    the field of a flat, one-cell-thick wall at distance ``d`` (computed from the kernels
    themselves). Control points sit on the link axes, so the link *surface* keeps about
    ``standoff`` minus the link radius (~0.05-0.09 m on the Panda).

    ``field_kind="calibrated"``: the push is Khatib's ``k (1/d - 1/d0) / d^2`` along the gradient
    of the calibrated distance ``d`` (:mod:`planbench.field.calibrated`), ``d0 = kernel_reach``,
    ``k`` from the same stand-off (``edt-field``'s push, on the matrix field's kernels).
    """

    field_kind: str = "matrix"
    """``"matrix"``: the directional kernels (docs/method.md, sections 2-3; the method as
    specified); ``"calibrated"``: the smooth signed distance [m] of separable Gaussian kernels
    (section 8), read on the solid grid (``surface_only``, ``kernel_profile`` and ``kernel_taper``
    are not used)."""
    field_sigma: float = 0.02
    """``field_kind="calibrated"``: the Gaussian's standard deviation [m]: the distance is exact at
    a flat face, up to ``0.67 sigma`` too large at a convex edge and ``1.15 sigma`` at a corner."""
    distance_floor: float = 0.01
    """``field_kind="calibrated"`` and ``field_push="khatib"``: the distance is floored here [m] so
    that the push stays finite in contact (``edt-field``'s setting)."""
    field_push: str = "linear"
    """``field_kind="matrix"``: ``"linear"``, the push ``k_rep F`` (the method as specified);
    ``"khatib"``, the same direction with the magnitude of Khatib's profile at the distance of a
    flat wall giving that field (:mod:`planbench_plugins.matrix_field.wall_push`); ``"khatib-hand"``,
    that only at the points the arm's last joint carries (the hand and fingers); ``"contact"``, the
    larger of the two magnitudes (linear beyond the stand-off at a flat wall, Khatib's inside it)."""

    def validate(self) -> None:
        IKLoopConfig.validate(self)
        self.validate_field()
        if self.field_kind not in FIELD_KINDS:
            raise InvalidConfigError(f"field_kind must be one of {FIELD_KINDS}, got {self.field_kind!r}")
        if self.field_push not in FIELD_PUSHES:
            raise InvalidConfigError(f"field_push must be one of {FIELD_PUSHES}, got {self.field_push!r}")
        for name in ("field_sigma", "distance_floor"):
            check_number(self, name, lambda v: v > 0, "finite and > 0")
        if (self.field_kind == "calibrated" or self.field_push != "linear") and self.distance_floor >= self.standoff:
            raise InvalidConfigError(
                f"distance_floor {self.distance_floor} m must be below standoff {self.standoff} m "
                "(it only keeps the push finite at contact); use e.g. 0.01"
            )
