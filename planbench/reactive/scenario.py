"""Scenarios: a problem whose scene changes over time, how it is sensed, and how fast it is controlled.

JSON format (``planbench-scenario/1``)::

    {"format": "planbench-scenario/1", "name": "crossing-box-fast",
     "problem": {... a planbench-problem/1 object: robot, static scene, start, goal ...},
                                          # or a reference to one: "gen:panda_pillars/0001", a .json
     "moving_obstacles": [
       {"name": "box", "type": "box", "size": [0.1, 0.1, 0.1],       # any scene obstacle shape
        "position": [0.5, -0.6, 0.4], "orientation_xyzw": [0, 0, 0, 1], # its pose at rest
        "motion": {"type": "velocity", "velocity": [0, 0.4, 0]},         # planbench.reactive.motion
        "appear": 0.0, "disappear": 6.0}                                 # [s]; null: never
     ],
     "sensing": {"model": "depth", "rate": 30, "resolution": 0.02,
                 "cameras": [{"position": [1.6, 0, 0.8], "look_at": [0.4, 0, 0.3], ...}]},
     "control_rate": 100, "horizon": 10.0, "metadata": {},
     "certificate": {...}}                # optional: a trajectory that solves it (below)

``control_rate`` [Hz] is the rate at which the controller is asked for joint velocities (default
100); ``horizon`` [s] the time by which the goal must be reached. Sensing settings are documented
on :class:`SensingSettings` and :class:`CameraSettings`; ``certificate`` (optional) on
:mod:`planbench.reactive.certificate`: it is read, not judged, when the scenario loads. Every wrong field raises
:class:`~planbench.errors.ScenarioFileError` naming the file and the field.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from planbench.errors import PlanbenchError, ProblemFileError, ResourceLimitError, ScenarioFileError
from planbench.files.inputs import InputFileError, read_json
from planbench.geometry.occupancy_map import MapSettings
from planbench.problem import Problem
from planbench.problems.datasets import load_problem
from planbench.reactive.certificate import Certificate
from planbench.reactive.motion import Motion
from planbench.scene import Obstacle, Scene

__all__ = ["CameraSettings", "MovingObstacle", "Scenario", "SensingSettings", "SENSING_MODELS", "default_bounds"]

SCENARIO_FORMAT = "planbench-scenario/1"
SENSING_MODELS = ("truth", "depth")
MEMORIES = ("map", "frame")
BOUNDS_PADDING = 0.1
"""Padding of the default sensing grid around the robot's reach [m]."""


def default_bounds(robot: Any, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The cube of half side ``robot.reach() + BOUNDS_PADDING`` [m] around the base, corners
    rounded out to multiples of ``resolution`` [m]: nothing farther can touch the arm (the sensing
    grid's default bounds)."""
    half = robot.reach() + BOUNDS_PADDING
    lower = np.full(3, math.floor(-half / resolution) * resolution)
    upper = np.full(3, math.ceil(half / resolution) * resolution)
    return lower, upper


MAX_TICKS = 1_000_000
"""The most control ticks, and the most sensor frames, of one run (100 Hz for 2.8 hours; the shipped
scenarios have 2000): a run allocates its path and commands for every tick before it starts, and
captures every frame due at a tick (a 1e12 Hz sensor filled 7.7 GB before the run's time limit)."""
MAX_CAMERA_PIXELS = 1 << 22
"""The most pixels of one simulated depth camera (4 million, 2048 x 2048): each frame casts one ray per pixel."""


@dataclass(frozen=True)
class CameraSettings:
    """One simulated depth camera (pinhole). Lengths in m, times in s, rates in Hz."""

    position: tuple[float, float, float] = (1.5, 0.0, 0.8)
    """Optical centre in the robot's base frame [m]."""
    look_at: tuple[float, float, float] = (0.4, 0.0, 0.3)
    """The point the optical axis passes through [m]."""
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """World direction that appears up in the image."""
    width: int = 160
    """Image width [pixels]."""
    height: int = 120
    """Image height [pixels]."""
    fov: float = 60.0
    """Vertical field of view [deg]; square pixels."""
    max_range: float = 3.0
    """Depth beyond which a pixel returns nothing [m]."""
    noise_std: float = 0.0
    """Standard deviation of Gaussian noise on each pixel's range, along its ray [m]."""
    dropout: float = 0.0
    """Fraction of pixels that return nothing, drawn independently each frame [0, 1)."""

    def __post_init__(self) -> None:
        for name in ("position", "look_at", "up"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise ValueError(f"camera {name} must be 3 finite numbers [m], got {getattr(self, name)}")
        axis = np.asarray(self.look_at, dtype=float) - np.asarray(self.position, dtype=float)
        if np.linalg.norm(axis) < 1e-9:
            raise ValueError("camera look_at must differ from its position")
        if np.linalg.norm(np.cross(axis, np.asarray(self.up, dtype=float))) < 1e-9:
            raise ValueError("camera up must not be parallel to its viewing direction")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"camera {name} must be a whole number of pixels, got {v!r}")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"camera image must be at least 1x1 pixels, got {self.width}x{self.height}")
        if int(self.width) * int(self.height) > MAX_CAMERA_PIXELS:
            raise ValueError(
                f"camera image of {self.width}x{self.height} pixels is more than the {MAX_CAMERA_PIXELS:,} "
                "planbench simulates (planbench.reactive.scenario.MAX_CAMERA_PIXELS)"
            )
        if not 0 < self.fov < 180:
            raise ValueError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        if not (math.isfinite(self.max_range) and self.max_range > 0):
            raise ValueError(f"camera max_range must be > 0 [m], got {self.max_range}")
        if not (math.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValueError(f"camera noise_std must be >= 0 [m], got {self.noise_std}")
        if not 0 <= self.dropout < 1:
            raise ValueError(f"camera dropout must be in [0, 1), got {self.dropout}")


@dataclass(frozen=True)
class SensingSettings:
    """What the controller observes. ``truth``: the exact scene voxelised each sensor frame;
    ``depth``: the grid of the points the cameras see (front surfaces only)."""

    model: str = "truth"
    """``"truth"`` or ``"depth"``."""
    rate: float = 30.0
    """Sensor frames per second [Hz]; the grid changes at this rate, not at the control rate."""
    latency: float = 0.0
    """Time from a frame's capture to its delivery to the controller [s]."""
    resolution: float = 0.02
    """Cell size of the observed occupancy grid [m]."""
    robot_margin: float = 0.03
    """Depth points closer than this to the robot's own collision geometry are removed [m]."""
    cameras: tuple[CameraSettings, ...] = ()
    """The depth cameras (``depth`` only; one default camera when empty)."""
    memory: str = ""
    """What an observation holds (``depth`` only): ``"map"`` (the default), every frame so far fused
    into a persistent occupancy map (:mod:`planbench.geometry.occupancy_map`); ``"frame"``, the
    latest frame alone. Truth sensing observes the whole scene at every frame: ``"frame"``."""
    map: MapSettings = field(default_factory=MapSettings)
    """The map's sensor model (``memory="map"``)."""

    def __post_init__(self) -> None:
        if self.model not in SENSING_MODELS:
            raise ValueError(f"sensing model must be one of {SENSING_MODELS}, got {self.model!r}")
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"sensing rate must be > 0 [Hz], got {self.rate}")
        if not (math.isfinite(self.latency) and self.latency >= 0):
            raise ValueError(f"sensing latency must be >= 0 [s], got {self.latency}")
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"sensing resolution must be > 0 [m], got {self.resolution}")
        if not (math.isfinite(self.robot_margin) and self.robot_margin >= 0):
            raise ValueError(f"robot_margin must be >= 0 [m], got {self.robot_margin}")
        if self.model == "depth" and not self.cameras:
            object.__setattr__(self, "cameras", (CameraSettings(),))
        if not self.memory:
            object.__setattr__(self, "memory", "map" if self.model == "depth" else "frame")
        if self.memory not in MEMORIES:
            raise ValueError(f"sensing memory must be one of {MEMORIES}, got {self.memory!r}")
        if self.model == "truth" and self.memory != "frame":
            raise ValueError(
                "sensing memory 'map' applies to depth sensing; truth sensing observes the whole scene at "
                "every frame (leave memory out or use 'frame')"
            )
        if not isinstance(self.map, MapSettings):
            raise ValueError(f"sensing map must be map settings, got {type(self.map).__name__}")

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("cameras", "map")}
        if self.model == "depth":
            d["cameras"] = [_dataclass_dict(c) for c in self.cameras]
        if self.memory == "map":
            d["map"] = _dataclass_dict(self.map)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> SensingSettings:
        if not isinstance(d, dict):
            raise ValueError(f"'sensing' must be a JSON object, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        _no_unknown(d, known, "sensing")
        args = {k: v for k, v in d.items() if k not in ("cameras", "map")}
        if "map" in d:
            if not isinstance(d["map"], dict):
                raise ValueError("sensing 'map' must be a JSON object")
            _no_unknown(d["map"], {f.name for f in fields(MapSettings)}, "sensing map")
            args["map"] = MapSettings(**d["map"])
        cams = d.get("cameras", [])
        if not isinstance(cams, list):
            raise ValueError("sensing 'cameras' must be a list of camera objects")
        cameras = []
        for k, c in enumerate(cams):
            if not isinstance(c, dict):
                raise ValueError(f"camera #{k} must be a JSON object")
            _no_unknown(c, {f.name for f in fields(CameraSettings)}, f"camera #{k}")
            cameras.append(CameraSettings(**{key: _tuple_or(v) for key, v in c.items()}))
        return cls(**args, cameras=tuple(cameras))


@dataclass(frozen=True)
class MovingObstacle:
    """An obstacle with a motion, present from ``appear`` until ``disappear`` [s] (None: never)."""

    obstacle: Obstacle
    motion: Motion = field(default_factory=Motion)
    appear: float = 0.0
    disappear: float | None = None

    def __post_init__(self) -> None:
        if self.obstacle.type in ("mesh", "pointcloud"):
            raise ValueError(
                f"moving obstacle {self.obstacle.name!r}: a {self.obstacle.type} cannot move (use a primitive)"
            )
        if not math.isfinite(self.appear):
            raise ValueError(f"moving obstacle {self.obstacle.name!r}: appear must be finite [s]")
        if self.disappear is not None and not self.disappear > self.appear:
            raise ValueError(f"moving obstacle {self.obstacle.name!r}: disappear must come after appear")

    @property
    def name(self) -> str:
        return self.obstacle.name

    def present(self, t0: float, t1: float | None = None) -> bool:
        """Whether the obstacle exists at any time in ``[t0, t1]`` (``t1`` defaults to ``t0``)."""
        t1 = t0 if t1 is None else t1
        return self.appear <= t1 and (self.disappear is None or t0 < self.disappear)

    def at(self, t: float) -> Obstacle:
        """The obstacle placed where it is at time ``t`` [s]."""
        rest = self.obstacle.placement()
        M = self.motion.pose(rest, t)
        quat = _xyzw(M.rotation)
        return replace(self.obstacle, position=tuple(M.translation.tolist()), orientation_xyzw=quat)

    def speed_bound(self) -> float:
        """Upper bound [m/s] on the speed of any of its points (:meth:`Motion.speed_bound`)."""
        radius = float(np.linalg.norm(self.obstacle.local_half_extents()))
        return self.motion.speed_bound(radius, self.obstacle.position)

    def to_dict(self) -> dict[str, Any]:
        d = self.obstacle.to_dict()
        d.update(motion=self.motion.to_dict(), appear=self.appear, disappear=self.disappear)
        return d

    @classmethod
    def from_dict(cls, d: Any) -> MovingObstacle:
        if not isinstance(d, dict):
            raise ValueError(f"a moving obstacle must be a JSON object, got {type(d).__name__}")
        rest = {k: v for k, v in d.items() if k not in ("motion", "appear", "disappear")}
        obstacle = Obstacle.from_dict(rest)
        motion = Motion.from_dict(d.get("motion", {"type": "static"}))
        disappear = d.get("disappear")
        return cls(obstacle, motion, float(d.get("appear", 0.0)), None if disappear is None else float(disappear))


@dataclass(frozen=True, eq=False)
class Scenario:
    """A problem (robot, static scene, start, goal, tolerances) plus obstacles that move, how the
    scene is sensed, the control rate [Hz] and the time horizon [s]."""

    problem: Problem
    moving: tuple[MovingObstacle, ...] = ()
    sensing: SensingSettings = field(default_factory=SensingSettings)
    control_rate: float = 100.0
    horizon: float = 10.0
    name: str = "scenario"
    metadata: dict[str, Any] = field(default_factory=dict)
    problem_ref: str | None = None
    """Where ``problem`` came from (``"gen:ur5_pillars/0002"``), written instead of the problem
    itself when the scenario is saved; None: the problem is written out whole."""
    certificate: Certificate | None = None
    """A trajectory claimed to solve the scenario (None: none). Only its form is checked here:
    :func:`planbench.reactive.solvability.verify_certificate` judges it (a scenario changed with
    ``dataclasses.replace`` keeps it, judged against the new geometry)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.control_rate) and self.control_rate > 0):
            raise ValueError(f"control_rate must be > 0 [Hz], got {self.control_rate}")
        if not (math.isfinite(self.horizon) and self.horizon > 0):
            raise ValueError(f"horizon must be > 0 [s], got {self.horizon}")
        for what, rate in (("control ticks", self.control_rate), ("sensor frames", self.sensing.rate)):
            if self.horizon * rate > MAX_TICKS:
                raise ResourceLimitError(
                    f"a horizon of {self.horizon:g} s at {rate:g} Hz is {self.horizon * rate:.3g} {what}, more than "
                    f"the {MAX_TICKS:,} of a run (planbench.reactive.scenario.MAX_TICKS)"
                )
        from planbench.geometry.occupancy import grid_shape

        grid_shape(*default_bounds(self.problem.robot, self.sensing.resolution), self.sensing.resolution)
        names = [o.name for o in self.problem.scene.obstacles] + [m.name for m in self.moving]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"scenario {self.name!r}: obstacle names must be unique, repeated: {dupes}")
        if self.certificate is not None and self.certificate.nq != self.problem.robot.nq:
            raise ValueError(
                f"certificate: 'path' configurations have {self.certificate.nq} joint values, the robot "
                f"{self.problem.robot.name!r} has {self.problem.robot.nq}"
            )

    @property
    def period(self) -> float:
        """The control period [s]."""
        return 1.0 / self.control_rate

    @property
    def id(self) -> str:
        return self.name

    def scene_at(self, t: float) -> Scene:
        """The true scene at time ``t`` [s]: the static obstacles and the moving ones present then."""
        moving = tuple(m.at(t) for m in self.moving if m.present(t))
        return Scene(tuple(self.problem.scene.obstacles) + moving, self.problem.scene.name)

    def speed_bound(self) -> float:
        """The fastest any obstacle point moves [m/s] (0 in a static scenario)."""
        return max((m.speed_bound() for m in self.moving), default=0.0)

    # --- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = {
            "format": SCENARIO_FORMAT,
            "name": self.name,
            "problem": self.problem_ref if self.problem_ref is not None else self.problem.to_dict(),
            "moving_obstacles": [m.to_dict() for m in self.moving],
            "sensing": self.sensing.to_dict(),
            "control_rate": self.control_rate,
            "horizon": self.horizon,
            "metadata": dict(self.metadata),
        }
        if self.certificate is not None:
            d["certificate"] = self.certificate.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "<dict>", base_dir: Path | None = None) -> Scenario:
        """A scenario from its JSON object; raises :class:`ScenarioFileError` naming ``source``."""
        if not isinstance(d, dict):
            raise ScenarioFileError(source, "a scenario must be a JSON object")
        fmt = d.get("format", SCENARIO_FORMAT)
        if fmt != SCENARIO_FORMAT:
            raise ScenarioFileError(source, f"unsupported scenario format {fmt!r}; expected {SCENARIO_FORMAT!r}")
        known = {"format", "name", "problem", "moving_obstacles", "sensing", "control_rate", "horizon"}
        known |= {"metadata", "certificate"}
        try:
            _no_unknown(d, known, "scenario")
        except ValueError as exc:
            raise ScenarioFileError(source, str(exc)) from None
        if "problem" not in d:
            raise ScenarioFileError(source, "missing required key 'problem' (a planbench-problem/1 object)")
        ref = d["problem"] if isinstance(d["problem"], str) else None
        try:
            if ref is not None:
                problem = load_problem(ref if base_dir is None or ":" in ref else str(base_dir / ref))
            else:
                problem = Problem.from_dict(d["problem"], f"{source}: problem", base_dir)
        except ProblemFileError as exc:
            raise ScenarioFileError(source, f"problem: {exc.problem}") from None
        except PlanbenchError as exc:
            raise ScenarioFileError(source, f"problem {ref!r}: {exc}") from None
        items = d.get("moving_obstacles", [])
        if not isinstance(items, list):
            raise ScenarioFileError(source, "'moving_obstacles' must be a list")
        moving = []
        for k, item in enumerate(items):
            try:
                moving.append(MovingObstacle.from_dict(item))
            except (ValueError, TypeError, KeyError) as exc:
                raise ScenarioFileError(source, f"moving obstacle #{k}: {exc}") from None
        try:
            sensing = SensingSettings.from_dict(d.get("sensing", {}))
        except (ValueError, TypeError) as exc:
            raise ScenarioFileError(source, f"sensing: {exc}") from None
        metadata = d.get("metadata", {})
        if not isinstance(metadata, dict):
            raise ScenarioFileError(source, "'metadata' must be a JSON object")
        certificate = None
        if d.get("certificate") is not None:
            try:
                certificate = Certificate.from_dict(d["certificate"])
            except ValueError as exc:
                raise ScenarioFileError(source, f"certificate: {exc}") from None
        try:
            return cls(
                problem,
                tuple(moving),
                sensing,
                float(d.get("control_rate", 100.0)),
                float(d.get("horizon", 10.0)),
                str(d.get("name", Path(source).stem)),
                dict(metadata),
                ref,
                certificate,
            )
        except (ValueError, TypeError) as exc:
            raise ScenarioFileError(source, str(exc)) from None

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> Scenario:
        p = Path(path)
        try:
            data = read_json(p)
        except InputFileError as exc:
            raise ScenarioFileError(p, exc.problem) from None
        return cls.from_dict(data, str(p), p.parent)

    def __repr__(self) -> str:
        return (
            f"Scenario({self.name!r}, robot={self.problem.robot.name!r}, moving={len(self.moving)}, "
            f"sensing={self.sensing.model!r}, {self.control_rate:g} Hz, {self.horizon:g} s)"
        )


def _no_unknown(d: dict[str, Any], known: set[str], what: str) -> None:
    unknown = set(d) - known
    if unknown:
        raise ValueError(f"{what}: unknown keys {sorted(unknown)}; allowed {sorted(known)}")


def _tuple_or(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


def _dataclass_dict(obj: Any) -> dict[str, Any]:
    return {f.name: (list(v) if isinstance(v := getattr(obj, f.name), tuple) else v) for f in fields(obj)}


def _xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    import pinocchio as pin

    q = pin.Quaternion(R)
    q.normalize()
    return (float(q.x), float(q.y), float(q.z), float(q.w))
