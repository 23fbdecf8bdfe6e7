"""Closed-loop controllers (entry-point group ``planbench.controllers``): the field planners'
steps run at the control rate on observed occupancy grids (docs/writing-a-controller.md).

Modules: ``adapter`` (:class:`IKLoopController`: an IK-loop planner's step as a controller),
``live`` (the repulsion whose source each frame replaces), ``crop`` (the block of a grid that holds
its occupied cells), ``cells`` (occupied cells as box obstacles), ``observed`` (what a planning
controller leaves out where the arm touches obstacles), and one module per controller:
``matrix_field``, ``matrix_field_qp``, ``edt_field``, ``distance_field``, ``ompl_replan``,
``matrix_field_guided`` (the last two import OMPL: their entry points name their modules),
``mppi`` (a sampling model-predictive controller, its kernels in ``_mppi_compiled``; its entry
point names its module);
``unknown`` (which unknown cells a controller reads as occupied, the ``unknown`` setting of every one);
``prediction`` (obstacle motion from the frames, the ``prediction`` setting of ``matrix-field`` and
``matrix-field-guided``).
"""

from planbench_plugins.controllers.adapter import PLANNING_ONLY, IKLoopController
from planbench_plugins.controllers.cells import cell_scene, observed_scene
from planbench_plugins.controllers.distance_field import DistanceFieldController, DistanceFieldControllerConfig
from planbench_plugins.controllers.edt_field import EDTFieldController, EDTFieldControllerConfig
from planbench_plugins.controllers.live import LiveRepulsion
from planbench_plugins.controllers.matrix_field import GridField, MatrixFieldController, MatrixFieldControllerConfig
from planbench_plugins.controllers.matrix_field_qp import MatrixFieldQPController, MatrixFieldQPControllerConfig
from planbench_plugins.controllers.unknown import UNKNOWN_MODES, UnknownSettings

__all__ = [
    "PLANNING_ONLY",
    "DistanceFieldController",
    "DistanceFieldControllerConfig",
    "EDTFieldController",
    "EDTFieldControllerConfig",
    "GridField",
    "IKLoopController",
    "LiveRepulsion",
    "MatrixFieldController",
    "MatrixFieldControllerConfig",
    "MatrixFieldQPController",
    "MatrixFieldQPControllerConfig",
    "UNKNOWN_MODES",
    "UnknownSettings",
    "cell_scene",
    "observed_scene",
]
