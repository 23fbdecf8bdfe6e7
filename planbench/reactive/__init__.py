"""The reactive benchmark: scenes that change over time, sensed grids, closed-loop control.

- :mod:`.motion`, :mod:`.scenario`: the scenario format (``planbench-scenario/1``).
- :mod:`.sensing`: what the controller observes (``truth`` voxelised, or simulated depth cameras).
- :mod:`.controller`: the controller interface (entry-point group ``planbench.controllers``).
- :mod:`.checker`: certified collision checking of a control tick against moving obstacles.
- :mod:`.runner`: the closed loop at a fixed control rate, with compute time charged.
"""

from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.reactive.motion import Motion
from planbench.reactive.scenario import CameraSettings, MovingObstacle, Scenario, SensingSettings

__all__ = [
    "CameraSettings",
    "ControlTask",
    "Controller",
    "Motion",
    "MovingObstacle",
    "Observation",
    "Scenario",
    "SensingSettings",
]
