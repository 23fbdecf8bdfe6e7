"""OMPL sampling-based planners as planbench baselines (see :mod:`.base` for how a query runs), and
an RRT-Connect query advanced in slices of collision checks for control loops (:mod:`.sliced`).

Needs the ``ompl`` package (2.x Python bindings, ``pip install ompl``).
"""

from __future__ import annotations

try:
    import ompl  # noqa: F401
except ImportError as exc:  # pragma: no cover
    raise ImportError("the OMPL planners need the 'ompl' package: pip install ompl") from exc

from .base import OMPLAnyConfig, OMPLConfig, OMPLPlanner, geometric_planners, planner_parameters
from .grid import cells_checker, cells_octree, pieces_checker, pieces_checker_in_steps
from .planners import BITstarPlanner, KPIECEPlanner, PRMstarPlanner, RRTConnectPlanner, RRTstarPlanner
from .sliced import SlicedRRTConnect

__all__ = [
    "OMPLConfig",
    "OMPLAnyConfig",
    "OMPLPlanner",
    "RRTConnectPlanner",
    "RRTstarPlanner",
    "BITstarPlanner",
    "PRMstarPlanner",
    "KPIECEPlanner",
    "geometric_planners",
    "planner_parameters",
    "cells_checker",
    "cells_octree",
    "pieces_checker",
    "pieces_checker_in_steps",
    "SlicedRRTConnect",
]
