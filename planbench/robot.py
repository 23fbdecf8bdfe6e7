"""Robots: a pinocchio model, its collision geometry, and the settings a planner needs.

A robot's settings live in one small TOML file under ``robots/`` (installed as the package
``planbench_robots``); URDF and meshes come from the ``example-robot-data`` package. Joints that are
not planned (the Panda's fingers) are locked at fixed values with ``pinocchio.buildReducedModel``, so
every planner sees exactly the planned joints: ``robot.nq`` of them, in ``robot.joint_names`` order.

Settings file keys (units: m, rad, s)::

    name = "panda"                       # required
    urdf = "panda_description/urdf/panda.urdf"   # required
    srdf = "panda_description/srdf/panda.srdf"   # optional: its disable_collisions pairs are ignored
    ee_frame = "panda_link8"             # required: end-effector frame of pose goals
    home = [...]                         # optional: a configuration of the planned joints
    ignore_collision_pairs = [["a", "b"]]  # optional: more link pairs never checked for self-collision
    [fixed_joints]      name = value     # optional: joints held fixed [rad or m]
    [position_limits]   name = [lo, hi]  # optional: override the URDF's [rad or m]; a continuous
                                         # joint without one gets CONTINUOUS_RANGE, [-pi, pi]
    [velocity_limits]   name = value     # optional: override the URDF's [rad/s or m/s]
    [acceleration_limits] name = value   # optional: [rad/s^2 or m/s^2] (URDFs have none); without
                                         # them the time-parameterised duration is not reported
    [control_points]    link = [[x, y, z], ...]  # optional: where field planners sample their
                                         # repulsion on that link, in the link frame [m]; replaces
                                         # the automatic placement for that link ([] = none)

Relative file paths are looked up beside the settings file first, then in example-robot-data's
``robots/`` folder (found through the installed distribution, never a machine path).

A continuous joint (URDF ``type="continuous"``, which pinocchio would model as a unit circle, two
coordinates for one velocity) is planned as a revolute joint over its ``[position_limits]`` entry,
or over :data:`CONTINUOUS_RANGE` (one full turn, ``[-pi, pi]``) without one; a URDF's own
lower/upper on a continuous joint are ignored, as the URDF specification says.
``planbench robot add`` writes that range into the settings file it makes.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import math
import sys
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

import planbench_robots
from planbench.errors import RobotFileError, UnknownNameError
from planbench.files.inputs import MAX_TEXT_BYTES, InputFileError, read_text, regular_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "CONTINUOUS_RANGE",
    "RobotSettings",
    "Robot",
    "link_of",
    "load_robot",
    "robot_names",
    "example_robot_data_dir",
    "package_dirs",
]

CONTINUOUS_RANGE = (-math.pi, math.pi)
"""[rad] The range a continuous joint is planned over when the settings give it no
``[position_limits]`` entry: one full turn."""


@functools.cache
def example_robot_data_dir() -> Path:
    """The installed ``share/example-robot-data`` folder (holds ``robots/<name>_description``)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:
        raise RobotFileError(
            "example-robot-data", "the package is not installed: pip install example-robot-data"
        ) from exc
    for f in dist.files or ():
        parts = Path(str(f)).parts
        if "example-robot-data" in parts and "robots" in parts:
            i = parts.index("example-robot-data")
            return Path(str(dist.locate_file(Path(*parts[: i + 1])))).resolve()
    raise RobotFileError("example-robot-data", "installed, but no robots/ folder found in it")


def package_dirs(urdf: Path) -> list[str]:
    """The folders pinocchio searches for a URDF's ``package://`` and relative mesh names, in
    order: the URDF's own folder, then example-robot-data's ``share`` folder (when installed), so a
    robot whose meshes lie beside its URDF (a bundle: :mod:`planbench.problems.bundle`) needs no package."""
    dirs = [str(Path(urdf).parent)]
    try:
        dirs.append(str(example_robot_data_dir().parent))
    except RobotFileError:
        pass  # not installed: only robots that need none of its files load
    return dirs


def shipped_settings_dir() -> Path:
    """The folder of the robots shipped with planbench (``robots/<name>.toml``)."""
    return _settings_dir()


def _settings_dir() -> Path:
    return planbench_robots.ROBOTS_DIR


def robot_names() -> list[str]:
    """Names of the robots shipped with planbench (one ``robots/<name>.toml`` each)."""
    return sorted(p.stem for p in _settings_dir().glob("*.toml"))


@dataclass(frozen=True)
class RobotSettings:
    """Everything about a robot that is not in its URDF. Units: m, rad, s."""

    name: str
    urdf: Path
    ee_frame: str
    srdf: Path | None = None
    home: tuple[float, ...] | None = None
    fixed_joints: Mapping[str, float] = field(default_factory=dict)
    position_limits: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    velocity_limits: Mapping[str, float] = field(default_factory=dict)
    acceleration_limits: Mapping[str, float] = field(default_factory=dict)
    """Per planned joint [rad/s^2 or m/s^2]; a joint without one has no acceleration limit known."""
    ignore_collision_pairs: tuple[tuple[str, str], ...] = ()
    control_points: Mapping[str, tuple[tuple[float, float, float], ...]] = field(default_factory=dict)
    """Per link, points [m] in the link frame where field planners sample their repulsion,
    replacing their automatic placement on that link (an empty list: no point on the link)."""
    description: str = ""
    source: str = "arguments"  # the settings file, for error messages and provenance

    def __post_init__(self) -> None:
        object.__setattr__(self, "urdf", Path(self.urdf))  # a str is welcome: it is a path
        if self.srdf is not None:
            object.__setattr__(self, "srdf", Path(self.srdf))

    def to_dict(self) -> dict[str, Any]:
        """The settings as JSON data (the TOML's keys; paths absolute), for a problem file that
        must carry a robot that has no settings file."""
        d: dict[str, Any] = {"name": self.name, "urdf": str(Path(self.urdf).resolve()), "ee_frame": self.ee_frame}
        if self.srdf is not None:
            d["srdf"] = str(Path(self.srdf).resolve())
        if self.home is not None:
            d["home"] = list(self.home)
        for key in ("fixed_joints", "velocity_limits", "acceleration_limits"):
            if getattr(self, key):
                d[key] = dict(getattr(self, key))
        if self.position_limits:
            d["position_limits"] = {k: list(v) for k, v in self.position_limits.items()}
        if self.ignore_collision_pairs:
            d["ignore_collision_pairs"] = [list(p) for p in self.ignore_collision_pairs]
        if self.control_points:
            d["control_points"] = {k: [list(p) for p in v] for k, v in self.control_points.items()}
        if self.description:
            d["description"] = self.description
        return d

    def replace(self, **changes: Any) -> RobotSettings:
        return dataclasses.replace(self, **changes)


def _resolve(path: str | Path, base: Path | None) -> Path:
    p = Path(path).expanduser()
    if p.is_absolute():
        return p
    candidates = ([base / p] if base is not None else []) + [Path.cwd() / p]
    for c in candidates:
        if c.exists():
            return c.resolve()
    # not beside the settings: example-robot-data's (its error says to install it when it is not)
    c = example_robot_data_dir() / "robots" / p
    return c.resolve() if c.exists() else c


def _point3(p: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in p)
    return x, y, z


def _read_settings(path: Path) -> RobotSettings:
    try:
        raw = tomllib.loads(read_text(path))
    except InputFileError as exc:
        raise RobotFileError(path, exc.problem) from None
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(path, f"not valid TOML: {exc}") from exc
    return settings_from_dict(raw, str(path), path.parent)


def settings_from_dict(raw: Mapping[str, Any], source: str, base: Path | None = None) -> RobotSettings:
    """Robot settings from a TOML table or a JSON object (relative paths from ``base``);
    :class:`RobotFileError` naming ``source`` and the key at fault."""
    allowed = {f.name for f in dataclasses.fields(RobotSettings)} - {"source"}
    unknown = set(raw) - allowed
    if unknown:
        raise RobotFileError(source, f"unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}")
    for key in ("name", "urdf", "ee_frame"):
        if key not in raw:
            raise RobotFileError(source, f"missing required key {key!r}")
    try:
        return RobotSettings(
            name=str(raw["name"]),
            urdf=_resolve(raw["urdf"], base),
            srdf=_resolve(raw["srdf"], base) if raw.get("srdf") else None,
            ee_frame=str(raw["ee_frame"]),
            home=tuple(float(x) for x in raw["home"]) if "home" in raw else None,
            fixed_joints={k: float(v) for k, v in raw.get("fixed_joints", {}).items()},
            position_limits={k: (float(v[0]), float(v[1])) for k, v in raw.get("position_limits", {}).items()},
            velocity_limits={k: float(v) for k, v in raw.get("velocity_limits", {}).items()},
            acceleration_limits={k: float(v) for k, v in raw.get("acceleration_limits", {}).items()},
            ignore_collision_pairs=tuple((str(a), str(b)) for a, b in raw.get("ignore_collision_pairs", [])),
            control_points={
                str(link): tuple(_point3(p) for p in pts) for link, pts in raw.get("control_points", {}).items()
            },
            description=str(raw.get("description", "")),
            source=source,
        )
    except (TypeError, ValueError, IndexError, AttributeError) as exc:
        raise RobotFileError(source, f"a value has the wrong type or shape: {exc}") from exc


def robot_from_settings(settings: RobotSettings) -> Robot:
    """The robot of ``settings``, cached like :func:`load_robot`'s."""
    return _cached_robot(_hashable(settings))


class Robot:
    """A manipulator ready for planning: reduced pinocchio model + self-collision geometry.

    Attributes are read-only numpy arrays over the planned joints: ``lower``, ``upper`` [rad or m],
    ``velocity_limit`` [rad/s or m/s], ``home``. ``collision_model`` is a ``pinocchio.GeometryModel``
    whose collision pairs are the robot's self-collision pairs (SRDF and extra ignores removed).
    """

    def __init__(self, settings: RobotSettings) -> None:
        self.settings = settings
        src = settings.source
        try:
            regular_file(settings.urdf, MAX_TEXT_BYTES)
        except InputFileError as exc:
            why = "URDF file not found" if exc.problem.endswith("no such file") else f"URDF file: {exc.problem}"
            raise RobotFileError(settings.urdf, f"{why} (robot {settings.name!r})") from None
        dirs = package_dirs(settings.urdf)
        xml, self.continuous_joints = _revolute_urdf(settings.urdf, settings.position_limits)
        """Names of the URDF's continuous joints, planned as revolute ones (module docstring)."""
        try:
            if xml is None:
                full, geom = pin.buildModelsFromUrdf(
                    str(settings.urdf), package_dirs=dirs, geometry_types=pin.GeometryType.COLLISION
                )
            else:
                full = pin.buildModelFromXML(xml)
                geom = pin.buildGeomFromUrdfString(full, xml, pin.GeometryType.COLLISION, package_dirs=dirs)
        except (RuntimeError, ValueError) as exc:
            raise RobotFileError(settings.urdf, f"pinocchio cannot parse it: {exc}") from exc
        if geom.ngeoms == 0:
            raise RobotFileError(settings.urdf, "it has no <collision> geometry to check paths with")
        geom.addAllCollisionPairs()
        if settings.srdf is not None:
            if not settings.srdf.is_file():
                raise RobotFileError(settings.srdf, "SRDF file not found")
            try:
                pin.removeCollisionPairs(full, geom, str(settings.srdf))
            except (RuntimeError, ValueError) as exc:
                raise RobotFileError(settings.srdf, f"pinocchio cannot parse it: {exc}") from exc
        self._remove_pairs(geom, settings.ignore_collision_pairs, src)

        names = list(full.names)
        q_ref = pin.neutral(full)
        locked = []
        for jname, value in settings.fixed_joints.items():
            if jname not in names:
                raise RobotFileError(src, f"fixed joint {jname!r} is not a joint of {settings.urdf.name}")
            jid = full.getJointId(jname)
            if full.joints[jid].nq != 1:
                raise RobotFileError(src, f"fixed joint {jname!r} is not a 1-dof joint")
            if not np.isfinite(value):
                raise RobotFileError(src, f"fixed joint {jname!r} must be held at a finite value, got {value}")
            q_ref[full.joints[jid].idx_q] = value
            locked.append(jid)
        if locked:
            model, (geom,) = pin.buildReducedModel(full, [geom], sorted(locked), q_ref)
        else:
            model = full
        if model.nq != model.nv:
            raise RobotFileError(
                settings.urdf,
                "it has multi-dof joints (floating or planar, nq != nv); planbench plans revolute, "
                "continuous and prismatic joints only: list the others under [fixed_joints]",
            )
        self.model = model
        self.collision_model = geom
        self.joint_names: tuple[str, ...] = tuple(model.names[1:])

        lower = model.lowerPositionLimit.copy()
        upper = model.upperPositionLimit.copy()
        vmax = model.velocityLimit.copy()
        for jname, (lo, hi) in settings.position_limits.items():
            i = self._index(jname, src)
            lower[i], upper[i] = lo, hi
        for jname, v in settings.velocity_limits.items():
            vmax[self._index(jname, src)] = v
        if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.all(lower < upper)):
            raise RobotFileError(src, f"position limits must be finite with lower < upper: {lower}, {upper}")
        if not (np.all(np.isfinite(vmax)) and np.all(vmax > 0)):
            raise RobotFileError(src, f"velocity limits must be finite and > 0 [rad/s]: {vmax}")
        model.lowerPositionLimit = lower
        model.upperPositionLimit = upper
        model.velocityLimit = vmax
        self.lower = _frozen(lower)
        self.upper = _frozen(upper)
        self.velocity_limit = _frozen(vmax)
        amax = np.full(model.nv, np.nan)
        for jname, a in settings.acceleration_limits.items():
            amax[self._index(jname, src)] = a
        if np.any(amax <= 0) or np.any(np.isinf(amax)):
            raise RobotFileError(src, f"acceleration limits must be finite and > 0 [rad/s^2]: {amax}")
        self.acceleration_limit = _frozen(amax)
        """[rad/s^2 or m/s^2] per planned joint; NaN where the settings give none."""

        if not model.existFrame(settings.ee_frame):
            frames = [f.name for f in model.frames]
            raise UnknownNameError(f"end-effector frame of robot {settings.name!r}", settings.ee_frame, frames)
        self.ee_frame_id = model.getFrameId(settings.ee_frame)
        for link in settings.control_points:
            if not model.existFrame(link):
                raise UnknownNameError(
                    f"link of control_points of robot {settings.name!r}", link, [f.name for f in model.frames]
                )
        if settings.home is not None:
            if len(settings.home) != self.nq:
                raise RobotFileError(src, f"home has {len(settings.home)} values, the robot plans {self.nq} joints")
            self.home = _frozen(np.array(settings.home, dtype=float))
        else:
            self.home = _frozen(0.5 * (lower + upper))
        self._data = model.createData()

    @property
    def name(self) -> str:
        return self.settings.name

    @property
    def nq(self) -> int:
        return int(self.model.nq)

    def _index(self, joint_name: str, src: str) -> int:
        if joint_name not in self.joint_names:
            raise UnknownNameError(f"planned joint (in {src})", joint_name, self.joint_names)
        return self.joint_names.index(joint_name)

    @staticmethod
    def _remove_pairs(geom: Any, pairs: Sequence[tuple[str, str]], src: str) -> None:
        links: dict[str, list[int]] = {}
        for i, g in enumerate(geom.geometryObjects):
            links.setdefault(link_of(g.name), []).append(i)
        for a, b in pairs:
            for link in (a, b):
                if link not in links:
                    raise UnknownNameError(f"link with collision geometry (in {src})", link, list(links))
            for i in links[a]:
                for j in links[b]:
                    geom.removeCollisionPair(pin.CollisionPair(min(i, j), max(i, j)))

    def limit_violations(self, q: np.ndarray, tol: float = 1e-9) -> list[str]:
        """Human-readable joint-limit violations of one configuration (empty when inside)."""
        out = []
        for i in np.flatnonzero((q < self.lower - tol) | (q > self.upper + tol)):
            out.append(f"{self.joint_names[i]}={q[i]:.4f} outside [{self.lower[i]:.4f}, {self.upper[i]:.4f}]")
        return out

    def frame_pose(self, q: np.ndarray, frame: str | None = None) -> Any:
        """World pose (``pinocchio.SE3``) of ``frame`` (default: the end effector) at ``q``."""
        fid = self.ee_frame_id if frame is None else self.frame_id(frame)
        pin.framesForwardKinematics(self.model, self._data, np.asarray(q, dtype=float))
        return pin.SE3(self._data.oMf[fid])

    def reach(self, frame: str | None = None) -> float:
        """An upper bound [m] on the distance from the base origin to ``frame`` over all
        configurations: the lengths of the kinematic chain's links (plus prismatic travel)."""
        fr = self.model.frames[self.ee_frame_id if frame is None else self.frame_id(frame)]
        total = float(np.linalg.norm(fr.placement.translation))
        jid = fr.parentJoint
        while jid > 0:
            total += float(np.linalg.norm(self.model.jointPlacements[jid].translation))
            if self.model.joints[jid].shortname().startswith("JointModelP"):  # prismatic
                i = self.model.joints[jid].idx_q
                total += float(max(abs(self.lower[i]), abs(self.upper[i])))
            jid = self.model.parents[jid]
        return total

    def frame_id(self, frame: str) -> int:
        if not self.model.existFrame(frame):
            raise UnknownNameError(f"frame of robot {self.name!r}", frame, [f.name for f in self.model.frames])
        return int(self.model.getFrameId(frame))

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, nq={self.nq}, ee_frame={self.settings.ee_frame!r})"


def _revolute_urdf(
    urdf: Path, position_limits: Mapping[str, tuple[float, float]]
) -> tuple[str | None, tuple[str, ...]]:
    """The URDF's text with each continuous joint made revolute over its range (``position_limits``
    or :data:`CONTINUOUS_RANGE`), and those joints' names; ``(None, ())`` when it has none."""
    text = read_text(urdf)
    if "continuous" not in text:
        return None, ()
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return None, ()  # pinocchio's parser says what is wrong with it
    names = []
    for joint in root.findall("joint"):
        if joint.get("type") != "continuous":
            continue
        name = str(joint.get("name"))
        lo, hi = position_limits.get(name, CONTINUOUS_RANGE)
        limit = joint.find("limit")
        if limit is None:
            limit = ET.SubElement(joint, "limit", effort="0", velocity="0")
        joint.set("type", "revolute")
        limit.set("lower", repr(float(lo)))
        limit.set("upper", repr(float(hi)))
        for key in ("effort", "velocity"):
            limit.set(key, limit.get(key, "0"))
        names.append(name)
    if not names:
        return None, ()
    return ET.tostring(root, encoding="unicode"), tuple(names)


def link_of(geometry_name: str) -> str:
    """pinocchio names collision geometries ``<link>_<k>``; recover the link name."""
    base, _, idx = geometry_name.rpartition("_")
    return base if base and idx.isdigit() else geometry_name


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@functools.lru_cache(maxsize=16)
def _cached_robot(settings: RobotSettings) -> Robot:
    return Robot(settings)


def load_robot(name_or_path: str | Path, **overrides: Any) -> Robot:
    """Load a shipped robot by name (``"panda"``, ``"ur5"``) or a settings TOML file by path.

    Keyword arguments override settings, e.g. ``load_robot("panda", fixed_joints={...})``. Robots
    are cached per settings (they are immutable after loading), so loading is cheap after the first.

    To load any URDF without a settings file, build ``RobotSettings(name=..., urdf=..., ee_frame=...)``
    and call ``Robot(settings)``.
    """
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.is_file():
        settings = _read_settings(path.resolve())
    else:
        candidate = _settings_dir() / f"{name_or_path}.toml"
        if not candidate.is_file():
            raise UnknownNameError("robot", str(name_or_path), robot_names())
        settings = _read_settings(candidate)
    if overrides:
        if "urdf" in overrides:
            overrides["urdf"] = _resolve(overrides["urdf"], None)
        if overrides.get("srdf"):
            overrides["srdf"] = _resolve(overrides["srdf"], None)
        for key in ("fixed_joints", "position_limits", "velocity_limits", "acceleration_limits"):
            if key in overrides:
                overrides[key] = {**getattr(settings, key), **overrides[key]}
        try:
            settings = settings.replace(**overrides)
        except TypeError as exc:
            allowed = [f.name for f in dataclasses.fields(RobotSettings)]
            raise RobotFileError(settings.source, f"bad override: {exc}; allowed: {allowed}") from exc
    return _cached_robot(_hashable(settings))


def _hashable(s: RobotSettings) -> RobotSettings:
    """Settings hold dicts; freeze them so the robot cache can key on them."""
    return s.replace(
        fixed_joints=_FrozenDict(s.fixed_joints),
        position_limits=_FrozenDict({k: tuple(v) for k, v in s.position_limits.items()}),
        velocity_limits=_FrozenDict(s.velocity_limits),
        acceleration_limits=_FrozenDict(s.acceleration_limits),
        control_points=_FrozenDict(
            {k: tuple(tuple(float(x) for x in p) for p in v) for k, v in s.control_points.items()}
        ),
    )


class _FrozenDict(dict):  # type: ignore[type-arg]
    def __hash__(self) -> int:  # type: ignore[override]
        return hash(tuple(sorted(self.items())))
