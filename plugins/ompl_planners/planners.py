"""The named OMPL baselines: one class per planner, each fixing the OMPL planner it runs.

All share :class:`~.base.OMPLConfig` (``params`` passes the planner's own parameters through).
Papers:

- RRT-Connect: J. J. Kuffner, S. M. LaValle, "RRT-Connect: An efficient approach to single-query
  path planning", ICRA 2000.
- RRT*: S. Karaman, E. Frazzoli, "Sampling-based algorithms for optimal motion planning", IJRR 30(7),
  2011 (also PRM*).
- BIT*: J. D. Gammell, S. S. Srinivasa, T. D. Barfoot, "Batch Informed Trees (BIT*)", ICRA 2015.
- KPIECE: I. A. Sucan, L. E. Kavraki, "Kinodynamic motion planning by interior-exterior cell
  exploration", WAFR 2008.
"""

from __future__ import annotations

from .base import OMPLConfig, OMPLPlanner

__all__ = ["RRTConnectPlanner", "RRTstarPlanner", "BITstarPlanner", "PRMstarPlanner", "KPIECEPlanner"]


class RRTConnectPlanner(OMPLPlanner):
    """OMPL ``RRTConnect``: two trees grown towards each other.

    Default ``range`` 0.5 rad (the longest extension, Euclidean in joint space) instead of OMPL's
    0.2 x the joint space's extent (2.6 rad on the Panda): with motions checked every 0.01 rad, long
    extensions into clutter cost many checks. On MotionBenchMaker ``*/0001-0010``, seed 0, 5 s limit,
    range 0.5 solved 70/70 (median 0.33 s), OMPL's default 64/70 (median 0.41 s; 6 time-outs)
    (``python benchmarks/ompl_checks.py sweep --ranges 0,0.5``)."""

    name = "ompl-rrtconnect"
    Config = OMPLConfig
    ompl_planner = "RRTConnect"
    default_params = {"range": 0.5}


class RRTstarPlanner(OMPLPlanner):
    """OMPL ``RRTstar`` (stops at its first solution unless ``optimize=True``)."""

    name = "ompl-rrtstar"
    Config = OMPLConfig
    ompl_planner = "RRTstar"


class BITstarPlanner(OMPLPlanner):
    """OMPL ``BITstar`` (stops at its first solution unless ``optimize=True``)."""

    name = "ompl-bitstar"
    Config = OMPLConfig
    ompl_planner = "BITstar"


class PRMstarPlanner(OMPLPlanner):
    """OMPL ``PRMstar``. Not exactly reproducible: OMPL searches the roadmap in a second thread."""

    name = "ompl-prmstar"
    Config = OMPLConfig
    ompl_planner = "PRMstar"


class KPIECEPlanner(OMPLPlanner):
    """OMPL ``KPIECE1`` on OMPL's default projection of the joint space."""

    name = "ompl-kpiece"
    Config = OMPLConfig
    ompl_planner = "KPIECE1"
