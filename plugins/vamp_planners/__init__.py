"""VAMP (vectorised sampling-based planning, SIMD collision checks of a sphere model) as planbench
baseline: ``vamp-rrtc`` (:mod:`.planners`), scenes converted to VAMP's
primitives (:mod:`.convert`).

Needs the ``vamp`` module of the ``vamp-planner`` package: the optional extra ``planbench[vamp]``,
built from source (docs/planners.md, "VAMP"). Without it, importing this package raises
``ModuleNotFoundError`` for ``vamp``, which the registry reports with the install hint.
"""

from __future__ import annotations

import vamp  # noqa: F401  (missing: ModuleNotFoundError, reported by the registry with its hint)

from .convert import SUPPORTED_ROBOTS, UnsupportedRobotError, VampRobot, environment, vamp_robot
from .planners import VampConfig, VampPlanner, VampRRTCPlanner, own_verdict

__all__ = [
    "SUPPORTED_ROBOTS",
    "UnsupportedRobotError",
    "VampConfig",
    "VampPlanner",
    "VampRRTCPlanner",
    "VampRobot",
    "environment",
    "own_verdict",
    "vamp_robot",
]
