"""Planning problems: a robot, a scene, a start configuration, a goal, and tolerances.

JSON format (``planbench-problem/1``)::

    {"format": "planbench-problem/1",
     "id": "my-problem",
     "robot": "panda",                              # a shipped robot name or a settings .toml path
     "robot_overrides": {"fixed_joints": {"panda_finger_joint1": 0.04}},   # optional
     "scene": {... a planbench-scene/1 object ...} or "scene.json" or "moveit.scene",
     "start": [q1, ..., qn],                        # [rad or m], robot.joint_names order
     "goal": {"q": [...],                           # a joint configuration, and/or
              "pose": {"frame": "panda_link8",      # an end-effector pose in the base frame
                       "position": [x, y, z], "orientation_xyzw": [x, y, z, w]}},
     "tolerances": {"position": 0.01, "orientation": 0.05, "joint": 0.01}}

When the goal is only a configuration, its pose is the forward kinematics of the robot's end
effector at it, so every problem has a goal pose that pose-driven planners can use.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.checking.collision import CollisionChecker
from planbench.errors import OutputFileError, PlanbenchError, ProblemFileError
from planbench.robot import (
    Robot,
    RobotSettings,
    load_robot,
    robot_from_settings,
    settings_from_dict,
    shipped_settings_dir,
)
from planbench.scene import Scene, read_problem_json

__all__ = ["Pose", "Goal", "Tolerances", "Problem", "ProblemCheck"]

PROBLEM_FORMAT = "planbench-problem/1"


@dataclass(frozen=True, eq=False)
class Pose:
    """A frame's pose in the robot base frame: position [m], rotation matrix (3x3)."""

    position: np.ndarray
    rotation: np.ndarray
    frame: str

    @classmethod
    def from_xyzw(cls, position: Any, orientation_xyzw: Any, frame: str) -> Pose:
        quat = np.asarray(orientation_xyzw, dtype=float)
        if quat.shape != (4,) or not np.all(np.isfinite(quat)) or abs(np.linalg.norm(quat) - 1) > 1e-6:
            raise ValueError(f"goal orientation_xyzw must be a finite unit quaternion, got {quat.tolist()}")
        return cls(np.asarray(position, dtype=float), pin.Quaternion(quat).toRotationMatrix(), frame)

    @property
    def orientation_xyzw(self) -> np.ndarray:
        q = pin.Quaternion(self.rotation).coeffs()  # x, y, z, w
        return q if q[3] >= 0 else -q  # one of the two quaternions of a rotation: w >= 0

    def se3(self) -> Any:
        return pin.SE3(self.rotation, self.position)

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame": self.frame,
            "position": self.position.tolist(),
            "orientation_xyzw": self.orientation_xyzw.tolist(),
        }


def pose_error(robot: Robot, q: np.ndarray, goal: Pose) -> tuple[float, float]:
    """Position error [m] and orientation error [rad] (angle of R_goal R^T) of ``goal.frame`` at q."""
    M = robot.frame_pose(q, goal.frame)
    pos = float(np.linalg.norm(goal.position - M.translation))
    rot = float(np.linalg.norm(pin.log3(goal.rotation @ M.rotation.T)))
    return pos, rot


@dataclass(frozen=True, eq=False)
class Goal:
    """A goal configuration ``q``, a goal ``pose``, or both. See the module docstring."""

    pose: Pose
    q: np.ndarray | None = None

    @property
    def kind(self) -> str:
        """``"configuration"`` when a joint goal is given, else ``"pose"``."""
        return "configuration" if self.q is not None else "pose"


@dataclass(frozen=True)
class Tolerances:
    """Goal tolerances: end-effector ``position`` [m], ``orientation`` [rad], ``joint`` [rad or m]
    (largest joint error, checked only for planners that claim to reach the goal configuration)."""

    position: float = 0.01
    orientation: float = 0.05
    joint: float = 0.01

    def __post_init__(self) -> None:
        for name in ("position", "orientation", "joint"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"tolerance {name} must be > 0, got {v}")


@dataclass(frozen=True)
class ProblemCheck:
    """What is wrong with a problem before any planning (empty lists: valid).

    ``goal_configuration`` problems only stop planners that drive to the goal configuration; a
    pose-driven planner may still reach the goal pose another way.
    """

    start: list[str]
    goal_pose: list[str]
    goal_configuration: list[str]

    @property
    def ok(self) -> bool:
        return not (self.start or self.goal_pose or self.goal_configuration)

    def messages(self) -> list[str]:
        return self.start + self.goal_pose + self.goal_configuration


@dataclass(frozen=True, eq=False)
class Problem:
    """One planning query. ``start`` and ``goal.q`` are read-only arrays over ``robot.joint_names``."""

    robot: Robot
    scene: Scene
    start: np.ndarray
    goal: Goal
    tolerances: Tolerances = field(default_factory=Tolerances)
    id: str = "problem"
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        start = np.array(self.start, dtype=float)
        if start.shape != (self.robot.nq,):
            raise ValueError(
                f"problem {self.id}: start has shape {start.shape}, robot "
                f"{self.robot.name!r} plans {self.robot.nq} joints"
            )
        start.setflags(write=False)
        object.__setattr__(self, "start", start)
        if self.goal.q is not None:
            gq = np.array(self.goal.q, dtype=float)
            if gq.shape != (self.robot.nq,):
                raise ValueError(f"problem {self.id}: goal q has shape {gq.shape}, robot plans {self.robot.nq} joints")
            gq.setflags(write=False)
            object.__setattr__(self, "goal", Goal(self.goal.pose, gq))

    @classmethod
    def create(
        cls,
        robot: Robot,
        scene: Scene,
        start: Any,
        goal_q: Any = None,
        goal_pose: Pose | None = None,
        tolerances: Tolerances | None = None,
        id: str = "problem",
        metadata: Mapping[str, Any] | None = None,
    ) -> Problem:
        """Build a problem; with only ``goal_q`` the goal pose is its FK at the end effector."""
        if goal_q is None and goal_pose is None:
            raise ValueError("a goal needs a configuration (goal_q), a pose (goal_pose), or both")
        if goal_pose is None:
            gq = np.asarray(goal_q, dtype=float)
            if gq.shape == (robot.nq,) and np.all(np.isfinite(gq)):
                M = robot.frame_pose(gq)
                goal_pose = Pose(M.translation.copy(), M.rotation.copy(), robot.settings.ee_frame)
            else:  # keep the bad goal so that check() can say what is wrong with it
                goal_pose = Pose(np.full(3, np.nan), np.eye(3), robot.settings.ee_frame)
        return cls(robot, scene, start, Goal(goal_pose, goal_q), tolerances or Tolerances(), id, dict(metadata or {}))

    # --- validity of start and goal ---------------------------------------------------------
    def check(self) -> ProblemCheck:
        """Say what makes the start or goal unusable: NaN, outside joint limits, in collision."""
        checker = CollisionChecker.for_problem(self)
        start = _check_q(self.robot, checker, self.start, "start")
        goal_q = []
        if self.goal.q is not None:
            goal_q = _check_q(self.robot, checker, self.goal.q, "goal configuration")
        goal: list[str] = []
        p = self.goal.pose
        if not (np.all(np.isfinite(p.position)) and np.all(np.isfinite(p.rotation))):
            goal.append("goal pose contains NaN or infinite values")
        elif not self.robot.model.existFrame(p.frame):
            goal.append(f"goal pose frame {p.frame!r} is not a frame of robot {self.robot.name!r}")
        else:
            reach = self.robot.reach(p.frame)
            dist = float(np.linalg.norm(p.position))
            if dist > reach:
                goal.append(
                    f"goal pose is out of reach: {dist:.3f} m from the base, the arm reaches at most {reach:.3f} m"
                )
        return ProblemCheck(start, goal, goal_q)

    # --- JSON -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        goal: dict[str, Any] = {"pose": self.goal.pose.to_dict()}
        if self.goal.q is not None:
            goal["q"] = self.goal.q.tolist()
        s = self.robot.settings
        overrides = {"fixed_joints": dict(s.fixed_joints)} if s.fixed_joints else {}
        return {
            "format": PROBLEM_FORMAT,
            "id": self.id,
            "robot": _robot_ref(s),
            "robot_overrides": overrides,
            "scene": self.scene.to_dict(),
            "start": self.start.tolist(),
            "goal": goal,
            "tolerances": {
                "position": self.tolerances.position,
                "orientation": self.tolerances.orientation,
                "joint": self.tolerances.joint,
            },
            "metadata": dict(self.metadata),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "<dict>", base_dir: Path | None = None) -> Problem:
        """A problem from its JSON object; any wrong field raises :class:`ProblemFileError` naming
        ``source`` and the field, before anything is built from it."""
        if not isinstance(d, Mapping):
            raise ProblemFileError(source, "a problem must be a JSON object")
        fmt = d.get("format", PROBLEM_FORMAT)
        if fmt != PROBLEM_FORMAT:
            raise ProblemFileError(source, f"unsupported problem format {fmt!r}; expected {PROBLEM_FORMAT!r}")
        for key in ("robot", "scene", "start", "goal"):
            if key not in d:
                raise ProblemFileError(source, f"missing required key {key!r}")
        _check_fields(d, source)
        robot = _load_problem_robot(d["robot"], dict(d.get("robot_overrides", {})), source, base_dir)
        scene_d = d["scene"]
        if isinstance(scene_d, str):
            scene = Scene.load((base_dir or Path.cwd()) / scene_d)
        else:
            scene = Scene.from_dict(scene_d, source, base_dir)
        g = d["goal"]
        try:
            pose = None
            if "pose" in g:
                pd = g["pose"]
                pose = Pose.from_xyzw(pd["position"], pd["orientation_xyzw"], pd.get("frame", robot.settings.ee_frame))
            tol = Tolerances(**d.get("tolerances", {}))
            return cls.create(
                robot,
                scene,
                d["start"],
                g.get("q"),
                pose,
                tol,
                str(d.get("id", Path(source).stem)),
                d.get("metadata", {}),
            )
        except (ValueError, TypeError, KeyError) as exc:
            raise ProblemFileError(source, str(exc)) from exc

    def save(self, path: str | Path) -> Path:
        """Write the problem as JSON at ``path``, creating missing folders; returns ``path``.

        Without ``bundle``, a robot settings file outside planbench's own and the scene's mesh and
        point-cloud files are named relative to the problem file (so that they can move together)
        but stay where they are; a shipped robot is named (``"panda"``); a folder that loads
        anywhere, with the robot's files and the scene's copied in, is a bundle
        (:func:`planbench.problems.bundle.save_bundle`). :class:`~planbench.errors.OutputFileError`
        when ``path`` is a folder or cannot be written.
        """
        out = Path(path)
        if out.is_dir():
            raise OutputFileError(out, "is a folder; give the problem file's name (e.g. problem.json)")
        d = self.to_dict()
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            folder = out.resolve().parent
            d["scene"] = self.scene.to_dict(relative_to=folder)
            if isinstance(d["robot"], str) and d["robot"].endswith(".toml") and Path(d["robot"]).is_absolute():
                d["robot"] = os.path.relpath(d["robot"], folder)
            out.write_text(json.dumps(d, indent=1))
        except OSError as exc:
            raise OutputFileError(out, f"cannot write the problem file: {exc.strerror or exc}") from None
        return out

    @classmethod
    def load(cls, path: str | Path) -> Problem:
        p = Path(path)
        return cls.from_dict(read_problem_json(p), str(p), p.parent)

    def __repr__(self) -> str:
        return f"Problem({self.id!r}, robot={self.robot.name!r}, obstacles={len(self.scene)}, goal={self.goal.kind})"


_OBJECT, _TEXT = "a JSON object", "a string"
_FIELD_TYPES: dict[str, tuple[tuple[type, ...], str]] = {
    "format": ((str,), _TEXT),
    "id": ((str,), _TEXT),
    "robot": ((str, Mapping), "a robot name, a settings .toml path, or the robot's settings (an object)"),
    "robot_overrides": ((Mapping,), _OBJECT),
    "scene": ((Mapping, str), "a scene object, or the path of a scene .json or MoveIt .scene file"),
    "goal": ((Mapping,), "an object with 'q' and/or 'pose'"),
    "tolerances": ((Mapping,), _OBJECT),
    "metadata": ((Mapping,), _OBJECT),
}
_TOLERANCES = ("position", "orientation", "joint")
_NAME_TO_NUMBER = ("fixed_joints", "velocity_limits", "acceleration_limits")


def _short(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, (list, dict, str, int, float, bool, type(None))) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _wrong(source: str, field: str, want: str, value: Any) -> ProblemFileError:
    return ProblemFileError(source, f"field {field!r} must be {want}, got {_short(value)}")


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _check_numbers(value: Any, field: str, source: str, length: int | None = None) -> None:
    want = f"a list of {length} numbers" if length else "a list of numbers"
    if not (isinstance(value, list) and all(_is_number(v) for v in value)) or (length and len(value) != length):
        raise _wrong(source, field, want, value)


def _check_fields(d: Mapping[str, Any], source: str) -> None:
    """Every field of a problem object has its JSON type (see the module docstring); raises
    ProblemFileError naming the field, so that a typo never surfaces as a traceback deep inside."""
    for key, (types, want) in _FIELD_TYPES.items():
        if key in d and not isinstance(d[key], types):
            raise _wrong(source, key, want, d[key])
    _check_numbers(d["start"], "start", source)
    goal = d["goal"]
    if not ({"q", "pose"} & set(goal)):
        raise ProblemFileError(source, "goal must be an object with 'q' and/or 'pose'")
    if "q" in goal:
        _check_numbers(goal["q"], "goal.q", source)
    if "pose" in goal:
        pose = goal["pose"]
        if not isinstance(pose, Mapping):
            raise _wrong(source, "goal.pose", "an object with position, orientation_xyzw and frame", pose)
        for key in ("position", "orientation_xyzw"):
            if key not in pose:
                raise ProblemFileError(source, f"goal.pose is missing {key!r}")
        _check_numbers(pose["position"], "goal.pose.position", source, 3)
        _check_numbers(pose["orientation_xyzw"], "goal.pose.orientation_xyzw", source, 4)
        if not isinstance(pose.get("frame", ""), str):
            raise _wrong(source, "goal.pose.frame", "a frame name (a string)", pose["frame"])
    for key, value in d.get("tolerances", {}).items():
        if key not in _TOLERANCES:
            raise ProblemFileError(source, f"tolerances has unknown key {key!r}; known: {', '.join(_TOLERANCES)}")
        if not _is_number(value):
            raise _wrong(source, f"tolerances.{key}", "a number", value)
    _check_overrides(d.get("robot_overrides", {}), source)


def _check_overrides(overrides: Mapping[str, Any], source: str) -> None:
    for key in _NAME_TO_NUMBER:
        value = overrides.get(key, {})
        if not (isinstance(value, Mapping) and all(_is_number(v) for v in value.values())):
            raise _wrong(source, f"robot_overrides.{key}", "an object of joint name: number", value)
    limits = overrides.get("position_limits", {})
    if not isinstance(limits, Mapping):
        raise _wrong(source, "robot_overrides.position_limits", "an object of joint name: [lower, upper]", limits)
    for name, pair in limits.items():
        _check_numbers(pair, f"robot_overrides.position_limits.{name}", source, 2)
    if overrides.get("home") is not None:
        _check_numbers(overrides["home"], "robot_overrides.home", source)


def _robot_ref(s: RobotSettings) -> Any:
    """How a problem file names its robot: a shipped robot by name, another settings file by its
    path, a robot built from arguments (no file) by its settings themselves."""
    if Path(s.source).resolve().parent == shipped_settings_dir().resolve():
        return s.name
    if s.source.endswith(".toml") and Path(s.source).is_file():
        return s.source
    return s.to_dict()


def _load_problem_robot(name: Any, overrides: dict[str, Any], source: str, base_dir: Path | None = None) -> Robot:
    """The problem's robot (a name, a settings file relative to the problem file, or the settings
    themselves); its errors name the problem file (the robot's own file is not at fault)."""
    try:
        if isinstance(name, Mapping):
            settings = settings_from_dict(name, f"{source}: robot", base_dir)
            return robot_from_settings(settings.replace(**overrides) if overrides else settings)
        if base_dir is not None and name.endswith(".toml") and not Path(name).is_absolute():
            if (base_dir / name).exists():  # a FIFO or a folder too: load_robot names what it is
                name = str(base_dir / name)
        return load_robot(name, **overrides)
    except PlanbenchError as exc:
        raise ProblemFileError(source, f"robot {name!r}: {exc}") from exc
    except (TypeError, ValueError, KeyError, AttributeError) as exc:
        raise ProblemFileError(source, f"robot_overrides: {type(exc).__name__}: {exc}") from exc


def _check_q(robot: Robot, checker: Any, q: np.ndarray, what: str) -> list[str]:
    if not np.all(np.isfinite(q)):
        return [f"{what} contains NaN or infinite values: {np.asarray(q).tolist()}"]
    problems = [f"{what} outside joint limits: {v}" for v in robot.limit_violations(q)]
    hits = checker.collisions(q)
    if hits:
        problems.append(f"{what} in collision: " + ", ".join(f"{a} with {b}" for a, b in hits[:5]))
    return problems
