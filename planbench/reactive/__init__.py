"""The reactive benchmark: scenes that change over time, sensed grids, closed-loop control.

- :mod:`.motion`, :mod:`.scenario`: the scenario format (``planbench-scenario/1``).
- :mod:`.sensing`: what the controller observes (``truth`` voxelised, or simulated depth cameras).
- :mod:`.controller`: the controller interface (entry-point group ``planbench.controllers``).
- :mod:`.checker`: certified collision checking of a control tick against moving obstacles.
- :mod:`.runner`: the closed loop at a fixed control rate, with compute time charged.
- :mod:`.remote`, :mod:`.isolation`, :mod:`.isolated`: the loop across a process boundary, the
  controller's process confined, its CPU time charged from outside (as the benchmark runs it).
- :mod:`.control_model`: the rules a run's record must keep (what the validator checks first).
"""

from typing import TYPE_CHECKING, Any

from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.reactive.motion import Motion
from planbench.reactive.scenario import CameraSettings, MovingObstacle, Scenario, SensingSettings

if TYPE_CHECKING:
    from planbench.reactive.isolated import run_isolated


def __getattr__(name: str) -> Any:
    """``run_isolated`` on first use: it brings the closed loop, the sensing and trimesh (0.3-0.8 s),
    which the scenario format and the command line's parser do not need."""
    if name == "run_isolated":
        from planbench.reactive.isolated import run_isolated

        return run_isolated
    raise AttributeError(f"module 'planbench.reactive' has no attribute {name!r}")


__all__ = [
    "CameraSettings",
    "ControlTask",
    "Controller",
    "Motion",
    "MovingObstacle",
    "Observation",
    "Scenario",
    "SensingSettings",
    "run_isolated",
]
