"""``matrix-field-qp`` as a controller: the matrix field of each observed grid, each step one QP.

The step is the planner's (:class:`~planbench_plugins.matrix_field_qp.MatrixFieldQPPlanner`): the
matrix-field task terms as the objective, joint position and velocity limits as hard constraints,
and (``collision_constraints``, default on) velocity dampers on coal's exact distances as hard
constraints too. Per frame (``update``):

- the field as ``matrix-field``'s controller builds it (:class:`~.matrix_field.GridField`; lazy by
  default, same measurements);
- the distances of the collision constraints to the observed geometry: the observation's exact
  ``scene`` with truth sensing, else the grid's occupied cells near the arm as one octree
  (``observed_geometry``, :mod:`.cells`).
  The robot's own pairs stay constrained whatever is observed.

A step the QP cannot solve (the constraints conflict with the joint limits) gives zero velocity
and counts as a step failure in ``info()``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.reactive.controller import ControlTask, Observation
from planbench.scene import Scene
from planbench_plugins.controllers.adapter import IKLoopController
from planbench_plugins.controllers.cells import GeometrySettings, observed_scene
from planbench_plugins.controllers.matrix_field import GridField
from planbench_plugins.controllers.unknown import UnknownSettings
from planbench_plugins.ik_loop import DistanceModel, IKLoopPlanner, Repulsion
from planbench_plugins.matrix_field_qp import MatrixFieldQPConfig, MatrixFieldQPPlanner

__all__ = ["MatrixFieldQPController", "MatrixFieldQPControllerConfig"]


@dataclass(frozen=True)
class MatrixFieldQPControllerConfig(MatrixFieldQPConfig, UnknownSettings, GeometrySettings):
    """The planner's settings (:class:`~planbench_plugins.matrix_field_qp.MatrixFieldQPConfig`)
    with the lazy field, as :class:`~.matrix_field.MatrixFieldControllerConfig` (same reasons).
    ``unknown = "occupied"`` (:class:`~.unknown.UnknownSettings`) adds the unknown cells near the
    arm to both the field's grid and the collision constraints' boxes: the velocity dampers then
    keep the links out of unseen space as out of an obstacle."""

    field_mode: str = "lazy"
    """``"lazy"``: window sums at the control points every step; ``"full"``: the whole field every frame."""

    def validate(self) -> None:
        super().validate()
        self.validate_unknown()
        self.validate_geometry()


class MatrixFieldQPController(IKLoopController):
    """``matrix-field-qp`` as a controller (module docstring). Settings:
    :class:`MatrixFieldQPControllerConfig`."""

    name = "matrix-field-qp"
    Config = MatrixFieldQPControllerConfig
    planner_class = MatrixFieldQPPlanner

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self.field = GridField(self.config)
        self.geometry = "none"
        """What the collision constraints measure against: ``"scene"``, ``"near cells"``, ``"grid cells"``, or
        ``"none"`` (no frame yet, or ``collision_constraints`` off)."""
        self._own_pairs: DistanceModel | None = None  # the robot's own pairs only (no obstacle known)

    def make_planner(self, task: ControlTask) -> IKLoopPlanner:
        """The planner, its collision constraints on the robot's own pairs (no obstacle known yet)."""
        planner = super().make_planner(task)
        assert isinstance(planner, MatrixFieldQPPlanner)
        if self.config.collision_constraints:
            planner.use_distances(DistanceModel(task.robot, Scene(name="observed"), self.config.collision_influence))
        else:
            planner.use_distances(None)
        self._own_pairs = planner.distances
        return planner

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        super().reset(q, rng)
        self._use(self._own_pairs, "none")

    def make_source(self, observation: Observation) -> Repulsion | None:
        if self.config.collision_constraints:
            assert self.task is not None
            c = self.config
            assert self.stepper is not None
            scene, where = observed_scene(observation, c.observed_geometry, self.stepper.kin.points, c.geometry_reach)
            model = DistanceModel(self.task.robot, scene, self.config.collision_influence) if len(scene) else None
            self._use(model if model is not None else self._own_pairs, where)
        return self.field.repulsion(observation.grid)

    def extra_info(self) -> dict[str, Any]:
        return {"field_mode": self.config.field_mode, "collision_geometry": self.geometry}

    def _use(self, distances: DistanceModel | None, geometry: str) -> None:
        """The collision constraints measure ``distances`` from the next step on."""
        planner = self.planner
        assert isinstance(planner, MatrixFieldQPPlanner)
        planner.use_distances(distances)
        self.geometry = geometry if self.config.collision_constraints else "none"
