"""``edt-field`` as a controller: Khatib repulsion along the distance transform of each observed grid.

Per frame (``update``), :class:`~planbench_plugins.potential_fields.EDTFieldRepulsion` of the
observed grid: its signed distance transform (scipy), the gradient and the deficit, then sampled
at the control points every step, as the planner does with the grid of the true scene. Like the
planner's grid, the transform covers the occupied cells grown by the influence distance (and two
cells; :func:`.crop.occupied_part`), not the whole observed grid: beyond that the push is zero. The
gain is the planner's (:func:`~planbench_plugins.potential_fields.khatib_gain` from the stand-off).
``grid_resolution`` is not used: the transform works at the resolution of the grid observed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from planbench.reactive.controller import Observation
from planbench_plugins.controllers.adapter import IKLoopController
from planbench_plugins.controllers.crop import occupied_part
from planbench_plugins.controllers.unknown import UnknownSettings
from planbench_plugins.ik_loop import Repulsion
from planbench_plugins.potential_fields import EDTFieldConfig, EDTFieldPlanner, EDTFieldRepulsion, khatib_gain

__all__ = ["EDTFieldController", "EDTFieldControllerConfig"]


@dataclass(frozen=True)
class EDTFieldControllerConfig(EDTFieldConfig, UnknownSettings):
    """The planner's settings (:class:`~planbench_plugins.potential_fields.EDTFieldConfig`) and how
    unknown cells are read (:class:`~.unknown.UnknownSettings`): ``unknown = "occupied"`` adds the
    unknown cells near the arm to the grid whose distance transform pushes, so the distance a
    control point keeps is to the nearest obstacle or unseen cell."""

    def validate(self) -> None:
        super().validate()
        self.validate_unknown()


class EDTFieldController(IKLoopController):
    """``edt-field`` as a controller (module docstring). Settings: :class:`EDTFieldControllerConfig`."""

    name = "edt-field"
    Config = EDTFieldControllerConfig
    planner_class = EDTFieldPlanner

    def make_source(self, observation: Observation) -> Repulsion | None:
        c = self.config
        gain = c.repulsion_gain * khatib_gain(c.speed_max, c.standoff, c.influence_distance)
        grid = observation.grid
        margin = math.ceil(c.influence_distance / grid.resolution) + 2  # beyond it the push is zero
        part = occupied_part(grid, margin) if gain > 0 else None
        if part is None:
            return None
        return EDTFieldRepulsion(part, gain, c.influence_distance, c.distance_floor)

    def extra_info(self) -> dict[str, Any]:
        return {"influence_distance": self.config.influence_distance}
