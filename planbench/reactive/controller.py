"""The controller interface: what a reactive method implements to run in the closed-loop benchmark.

A controller is a class with a kebab-case ``name`` and a frozen ``Config`` dataclass, like a
planner, registered under the entry-point group ``planbench.controllers``. The runner
(:mod:`planbench.reactive.runner`) calls, in this order:

- ``setup(task)`` once per scenario, untimed: the robot, start, goal, tolerances and control
  period are known; the scene is **not** (the controller sees obstacles only through observations).
- ``reset(q, rng)`` at the start of each run, untimed.
- ``update(observation)`` on the first control tick after a new sensor frame is delivered. Timed:
  reported as ``field_update_time`` and charged to that tick's compute time.
- ``step(t, q, observation, goal)`` every control tick, timed: joint velocities [rad/s] (nq,).
  ``observation`` is the latest delivered frame (``None`` before the first).
- ``info()`` after the run: JSON-friendly diagnostics (optional).

A controller that raises, or returns velocities of the wrong shape or with NaN, ends its run as an
``error`` row; it never takes the benchmark down. Randomness comes only from the ``rng`` of
``reset``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from planbench.planner import EmptyConfig, build_config

if TYPE_CHECKING:
    from planbench.geometry.occupancy import OccupancyGrid
    from planbench.problem import Goal, Tolerances
    from planbench.reactive.scenario import CameraSettings
    from planbench.robot import Robot
    from planbench.scene import Scene

__all__ = ["BadCommand", "ControlTask", "Controller", "Observation", "as_command"]


@dataclass(frozen=True, eq=False)
class ControlTask:
    """What a controller knows before it runs: the robot, its start and goal, the tolerances of
    success, the control period [s] and, with depth sensing, where its cameras are."""

    robot: Robot
    start: np.ndarray
    goal: Goal
    tolerances: Tolerances
    period: float
    id: str = "task"
    cameras: tuple[CameraSettings, ...] = ()
    """The depth cameras (pose in the robot's base frame and image model, as a robot's transform
    tree and camera info give them; empty with truth sensing): what hides an unknown cell can be
    told from them (:mod:`planbench.reactive.shadows`)."""
    robot_margin: float = 0.0
    """[m] Depth sensing: how far from the arm's surface the sensor's robot filter removes points
    (every ray stops this short of the arm)."""


@dataclass(frozen=True, eq=False)
class Observation:
    """One sensor frame as delivered to the controller.

    ``grid``: the observed occupancy grid (robot base frame; ``grid.known``: the cells the frame
    observed, None when all were, docs/sensing.md); ``time``: when the frame was captured
    [s] (delivered ``latency`` later); ``points``: the (N, 3) point cloud it was built from
    (``depth`` sensing, float32 as depth drivers deliver it; None for ``truth``); ``scene``: the
    exact geometry at capture time (``truth`` sensing only, for controllers that measure distances
    to geometry; None otherwise).
    ``frame``: the frame's number, counting from 0.
    """

    time: float
    grid: OccupancyGrid
    frame: int = 0
    points: np.ndarray | None = None
    scene: Scene | None = None


class Controller:
    """Base class of controllers (the protocol in the module docstring is what matters)."""

    name: ClassVar[str] = ""
    Config: ClassVar[type] = EmptyConfig
    warm_up: ClassVar[bool] = True
    """Before each run, in the run's own process, the benchmark puts two frames of a scene of its
    own (nothing of the scenario) and 40 steps through a first instance, untimed, then builds the
    instance that runs: first-use costs (numba compiling, lazy imports, a planner's first objects)
    are then no run's charge. Every controller gets it unless it sets this to False (then it is
    charged those costs in its run: ``ompl-replan`` was charged 0.5-1.2 s at its first plan when
    the warm-up was asked for by name)."""

    def __init__(self, config: Any = None, **settings: Any) -> None:
        self.config = build_config(self.Config, config, settings)

    def setup(self, task: ControlTask) -> None:
        """Untimed preparation for ``task`` (kinematics, compiled code)."""

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        """The start of a run from configuration ``q`` (untimed)."""

    def update(self, observation: Observation) -> None:
        """A new sensor frame (timed as ``field_update_time``)."""

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        """Joint velocities [rad/s] for the tick at time ``t`` [s] from configuration ``q``."""
        raise NotImplementedError

    def info(self) -> dict[str, Any]:
        """Diagnostics of the run just finished (JSON-friendly values)."""
        return {}


class BadCommand(ValueError):
    """What a controller's ``step`` returned is not ``nq`` finite real joint velocities."""


def as_command(qd: Any, nq: int) -> np.ndarray:
    """``qd`` as ``nq`` finite float64 joint velocities [rad/s]; :class:`BadCommand` naming what is
    wrong otherwise (complex numbers are refused, not cut to their real part)."""
    try:
        arr = np.asarray(qd)
        if arr.dtype.kind not in "fiub":
            raise BadCommand(f"step returned {type(qd).__name__} of {arr.dtype}, not real joint velocities")
        arr = arr.astype(float)
    except BadCommand:
        raise
    except Exception as exc:
        raise BadCommand(f"step returned {type(qd).__name__}, not joint velocities ({type(exc).__name__})") from None
    if arr.shape != (nq,):
        raise BadCommand(f"step returned shape {arr.shape}, expected ({nq},) joint velocities")
    if not np.isfinite(arr).all():
        raise BadCommand(f"step returned non-finite joint velocities {arr.tolist()}")
    return arr
