"""``matrix-field`` as a controller: the matrix field of each observed grid, pushing the IK loop.

Per frame (``update``), the observed grid's surface cells (``surface_only``, as
:func:`~planbench.field.scene_field.build_scene_field` keeps them) with the kernels built at the
grid's own resolution, and the gain from the stand-off on those kernels
(:func:`~planbench.field.scene_field.standoff_gain`, as the planner derives it). ``field_mode``:

- ``"lazy"`` (the controller's default): nothing more per frame; each step takes window sums of
  the grid at the control points only, each occupied cell read through the surface pass
  (``lazy_field(..., surface=True)``; a depth sensor's grid, whose observation has ``points``,
  holds surfaces already and is read as it is). Nothing is done per frame.
- ``"full"``: the whole field is recomputed per frame and sampled per step.

``field_kind = "calibrated"`` (or the preset ``matrix-field:calibrated``): the calibrated distance
of each observed grid pushes instead (:mod:`planbench_plugins.matrix_field.calibrated`), read on
the grid as observed (no surface pass); ``"lazy"`` evaluates it at the control points every step,
``"full"`` at every cell of the occupied part every frame. A depth sensor's grid holds surfaces
only, one cell thick: its distance is over-estimated like an obstacle thinner than ``sigma``
(docs/method.md, section 8).

``prediction = "swept"`` (the default, :mod:`.prediction`): the cells the moving clusters of the
frames will sweep push too, their own field added to the grid's.

Both work on the block of the grid that holds occupied cells (:mod:`.crop`: the same field).
Measured (Panda, the first problem of each MotionBenchMaker family seen by the benchmark's truth
and depth sensors at 2 cm, one numba thread, the shared 2-core machine; docs/writing-a-controller.md
has the table and the command): ``"full"`` costs 1.5-13.7 ms per frame and 6 us per step,
``"lazy"`` 1.1-4.8 ms per frame (the surface pass) and 16-57 us per step. At 30 frames/s and 100
ticks/s that is 47-411 ms of compute per second of motion for ``"full"`` against 35-149 ms for
``"lazy"`` (1.3-2.8 times less; 1.3-2.2 with numba's two threads), and only the lazy frames fit
a 10 ms tick with room to spare: hence its default here. Both give the same field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.field.full import full_field
from planbench.field.kernels import Kernels, KernelSpec
from planbench.field.scene_field import FieldRepulsion, standoff_gain
from planbench.field.surface import surface_grid
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.controller import ControlTask, Observation
from planbench_plugins.controllers.adapter import IKLoopController
from planbench_plugins.controllers.crop import occupied_part
from planbench_plugins.controllers.prediction import (
    MotionPredictor,
    Prediction,
    PredictionSettings,
    SummedRepulsion,
    describe,
    predicted_grid,
    warm_up,
)
from planbench_plugins.controllers.unknown import UnknownSettings
from planbench_plugins.ik_loop import IKLoopPlanner, Repulsion
from planbench_plugins.matrix_field import CalibratedRepulsion, MatrixFieldConfig, MatrixFieldPlanner, grid_repulsion

__all__ = ["GridField", "MatrixFieldController", "MatrixFieldControllerConfig"]


@dataclass(frozen=True)
class MatrixFieldControllerConfig(MatrixFieldConfig, UnknownSettings, PredictionSettings):
    """The planner's settings (:class:`~planbench_plugins.matrix_field.MatrixFieldConfig`), with the
    cheaper field mode for a grid that changes every frame (module docstring), and how unknown
    cells are read (:class:`~.unknown.UnknownSettings`): ``unknown = "occupied"`` adds the unknown
    cells near the arm to the grid whose field pushes, so the arm keeps the stand-off from space
    no camera saw as from an obstacle's surface (the surface pass keeps their boundary).
    ``prediction = "swept"`` (:class:`~.prediction.PredictionSettings`): the cells the moving
    clusters of the frames sweep over the horizon push too (their own field, through the surface
    pass, added to the grid's).

    ``grid_resolution`` is not used: the kernels are built at the resolution of the grid observed.
    ``dt``, ``escape_attempts``, ``collision_check_every`` and ``verify_path`` are planning settings
    the controller overrides (:mod:`.adapter`)."""

    field_mode: str = "lazy"
    """``"lazy"``: window sums at the control points every step (default: measured cheaper for a
    grid observed at 30 frames/s, module docstring); ``"full"``: the whole field every frame."""
    prediction: str = "swept"
    """``"swept"`` (default here, chosen on ``dynamic-tune``'s fast crossing, swinging and pair depth
    scenarios: 4 of 9 solved against 0 with ``"none"``, docs/reactive.md, "Prediction") or ``"none"``."""

    def validate(self) -> None:
        super().validate()
        self.validate_unknown()
        self.validate_prediction()
        if self.field_push != "linear":  # the planner's setting only (issue 32: measured there, not kept)
            raise InvalidConfigError(
                f"field_push {self.field_push!r} is a setting of the matrix-field planner; the controller "
                'pushes with the field as specified ("linear")'
            )


class GridField:
    """The matrix-field repulsion of observed grids for field settings ``config``
    (:class:`~planbench.field.scene_field.FieldSettings` plus the loop's ``speed_max``,
    ``standoff`` and ``repulsion_gain``); kernels and gain are built once per grid resolution."""

    def __init__(self, config: Any) -> None:
        self.config = config
        self._kernels: dict[float, tuple[Kernels, float]] = {}

    def kernels(self, resolution: float) -> tuple[Kernels, float]:
        """The kernels at ``resolution`` [m] and the gain [m/s per field unit] derived from the stand-off."""
        if resolution not in self._kernels:
            c = self.config
            kernels = KernelSpec(reach=c.kernel_reach, profile=c.kernel_profile, taper=c.kernel_taper).build(resolution)
            self._kernels[resolution] = kernels, c.repulsion_gain * standoff_gain(kernels, c.speed_max, c.standoff)
        return self._kernels[resolution]

    def repulsion(self, grid: OccupancyGrid, surfaces: bool = False) -> FieldRepulsion | CalibratedRepulsion | None:
        """The push of ``grid`` (None when nothing is occupied, or the gain is zero), computed on
        the part of it that holds occupied cells (:func:`.crop.occupied_part`: the same field).

        ``surfaces``: the grid holds surfaces already (a depth sensor's: the surface pass would
        only erase noisy inner cells, :mod:`planbench.field.surface`). In lazy mode the grid is
        used as it is: the per-frame work is nothing, every step reads its windows, through the
        surface pass cell by cell where one is due (``lazy_field(..., surface=True)``); the cut
        to the occupied part would save a lazy step nothing and cost a pass over the grid."""
        if getattr(self.config, "field_kind", "matrix") == "calibrated":  # the QP controller has no such setting
            margin = math.ceil(self.config.kernel_reach / grid.resolution) + 2  # beyond it no push
            part = grid if self.config.field_mode == "lazy" else occupied_part(grid, margin)
            return None if part is None else grid_repulsion(part, self.config, self.config.field_mode)
        kernels, gain = self.kernels(grid.resolution)
        if gain <= 0:
            return None
        if self.config.field_mode == "lazy":  # the grid as it is; the surface pass cell by cell
            return FieldRepulsion(grid, kernels, None, gain, surface=self.config.surface_only and not surfaces)
        part = occupied_part(grid)
        if part is None:
            return None
        grid = part
        if self.config.surface_only and not surfaces:
            grid = surface_grid(grid)
        field = full_field(grid, kernels, dtype=np.float64) if self.config.field_mode == "full" else None
        return FieldRepulsion(grid, kernels, field, gain)


class MatrixFieldController(IKLoopController):
    """``matrix-field`` as a controller: the planner's step with the matrix field of each observed
    grid (module docstring). Settings: :class:`MatrixFieldControllerConfig`."""

    name = "matrix-field"
    Config = MatrixFieldControllerConfig
    planner_class = MatrixFieldPlanner
    presets = MatrixFieldPlanner.presets
    """``matrix-field:paper``: the method as specified (the planner's preset)."""

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self.field = GridField(self.config)
        self.predictor = MotionPredictor(self.config) if self.config.prediction != "none" else None
        self.prediction: Prediction | None = None  # the latest frame's

    def setup(self, task: ControlTask) -> None:
        """The loop for ``task``, then the predictor's warm-up (:func:`.prediction.warm_up`)."""
        super().setup(task)
        if self.predictor is not None:
            stepper = self._require()
            warm_up(self.config, lambda block: self._warm_push(block, stepper.kin))

    def _warm_push(self, block: OccupancyGrid, kin: Any) -> None:
        source = self.field.repulsion(block, surfaces=False)
        if source is not None:
            source.forces(kin)

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        super().reset(q, rng)
        if self.predictor is not None:
            self.predictor.reset()
        self.prediction = None

    def update(self, observation: Observation) -> None:
        """The frame's prediction first (from the frame as delivered: its points), then its field."""
        if self.predictor is not None:
            self.prediction = self.predictor.observe(observation)
        super().update(observation)

    def make_planner(self, task: ControlTask) -> IKLoopPlanner:
        """The planner, with the priority rows on a redundant arm for the matrix field (the
        controller's choice, kept when the planner's changed to the null space: issue 32 measured
        only the planner)."""
        planner = super().make_planner(task)
        if getattr(planner.config, "field_kind", "matrix") == "matrix":
            planner.auto_hierarchy_redundant = "priority"
        return planner

    def make_source(self, observation: Observation) -> Repulsion | None:
        base = self.field.repulsion(observation.grid, surfaces=observation.points is not None)
        if self.prediction is None:
            return base
        block = predicted_grid(observation.grid, self.prediction.cells)
        extra = None if block is None else self.field.repulsion(block, surfaces=False)
        return base if extra is None else SummedRepulsion(base, extra)

    def extra_info(self) -> dict[str, Any]:
        out = {"field_mode": self.config.field_mode, "field_kind": getattr(self.config, "field_kind", "matrix")}
        if self.prediction is not None:
            out["prediction"] = describe(self.prediction)
        return out
