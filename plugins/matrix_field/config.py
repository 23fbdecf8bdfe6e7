"""Settings of the matrix-field planner: the IK loop's (:class:`~planbench_plugins.ik_loop.IKLoopConfig`)
plus the field's (:class:`~planbench.field.scene_field.FieldSettings`).

Units: metres, radians, seconds. Field values are dimensionless sums of occupancy times kernel
weight; the gain derived from the stand-off (times ``repulsion_gain``) turns them into a speed [m/s].
"""

from __future__ import annotations

from dataclasses import dataclass

from planbench.field.scene_field import FIELD_MODES, FieldSettings
from planbench_plugins.ik_loop import IKLoopConfig

__all__ = ["MatrixFieldConfig", "FIELD_MODES"]


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
    """

    def validate(self) -> None:
        IKLoopConfig.validate(self)
        self.validate_field()
