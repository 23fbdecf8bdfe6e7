"""``distance-field`` as a controller: Khatib repulsion from coal's distances to the observed geometry.

Per frame (``update``), :class:`~planbench_plugins.potential_fields.DistanceFieldRepulsion` between
the robot's links (convex hulls) and the observed geometry: the observation's exact ``scene`` with
truth sensing, else the grid's occupied cells near the arm as one octree (``observed_geometry``,
:mod:`.cells`). Each step asks
coal for every link's nearest obstacle, as the planner does with the true scene. The gain is the
planner's (:func:`~planbench_plugins.potential_fields.khatib_gain` from the stand-off).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from planbench.reactive.controller import Observation
from planbench_plugins.controllers.adapter import IKLoopController
from planbench_plugins.controllers.cells import GeometrySettings, observed_scene
from planbench_plugins.controllers.unknown import UnknownSettings
from planbench_plugins.ik_loop import Repulsion
from planbench_plugins.potential_fields import (
    DistanceFieldConfig,
    DistanceFieldPlanner,
    DistanceFieldRepulsion,
    khatib_gain,
)

__all__ = ["DistanceFieldController", "DistanceFieldControllerConfig"]


@dataclass(frozen=True)
class DistanceFieldControllerConfig(DistanceFieldConfig, UnknownSettings, GeometrySettings):
    """The planner's settings (:class:`~planbench_plugins.potential_fields.DistanceFieldConfig`) and
    how unknown cells are read (:class:`~.unknown.UnknownSettings`): ``unknown = "occupied"`` adds
    the unknown cells near the arm, merged into boxes with the occupied ones (:mod:`.cells`), to
    the geometry coal measures the links' distances to. ``observed_geometry`` and
    ``geometry_reach`` (:class:`~.cells.GeometrySettings`): how a depth grid's cells become that
    geometry."""

    def validate(self) -> None:
        super().validate()
        self.validate_unknown()
        self.validate_geometry()


class DistanceFieldController(IKLoopController):
    """``distance-field`` as a controller (module docstring). Settings:
    :class:`DistanceFieldControllerConfig`."""

    name = "distance-field"
    Config = DistanceFieldControllerConfig
    planner_class = DistanceFieldPlanner

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self.geometry = ""
        """Where the last frame's geometry came from: ``"scene"``, ``"near cells"`` or ``"grid cells"``."""

    def make_source(self, observation: Observation) -> Repulsion | None:
        c = self.config
        assert self.task is not None
        assert self.stepper is not None
        scene, self.geometry = observed_scene(
            observation, c.observed_geometry, self.stepper.kin.points, c.geometry_reach
        )
        gain = c.repulsion_gain * khatib_gain(c.speed_max, c.standoff, c.influence_distance)
        if len(scene) == 0 or gain <= 0:
            return None
        return DistanceFieldRepulsion(self.task.robot, scene, gain, c.influence_distance, c.distance_floor)

    def extra_info(self) -> dict[str, Any]:
        return {"geometry": self.geometry}
