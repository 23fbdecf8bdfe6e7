"""Portable bundles: problems written into one folder together with every file they need.

A bundle is a folder that loads anywhere: moved to another machine, without the original robot
files, and without example-robot-data installed::

    <folder>/
      <problem>.json                      # one per problem; "robot": "robots/<name>.toml"
      robots/<name>.toml                  # the robot's settings, paths relative to it
      robots/<name>/<urdf>, <srdf>        # the URDF (mesh references rewritten) and SRDF
      robots/<name>/meshes/...            # every mesh the URDF names (collision and visual)
      scene-files/...                     # the scenes' mesh and point-cloud files

Each mesh a URDF names is found the way pinocchio finds it for planbench's robots
(:func:`resolve_resource`): a ``package://`` or relative name in the package folders
(:func:`planbench.robot.package_dirs`: the URDF's own folder, then example-robot-data's ``share``
folder when it is installed, then ``ROS_PACKAGE_PATH``), a ``file://`` or absolute name as is. In
the copied URDF each becomes a path relative to the URDF, which is found beside the URDF first.

:func:`save_bundle` writes one problem or many (a suite's); ``planbench bundle`` is the command.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

from planbench.errors import OutputFileError, RobotFileError
from planbench.files.inputs import InputFileError, read_text
from planbench.robot import RobotSettings, package_dirs

if TYPE_CHECKING:
    from planbench.problem import Problem

__all__ = ["save_bundle", "resolve_resource", "settings_toml"]

ROBOTS_DIR = "robots"
SCENE_FILES_DIR = "scene-files"


def resolve_resource(name: str, dirs: Sequence[str | Path]) -> Path | None:
    """The file a URDF resource name (``<mesh filename=...>``) stands for, as pinocchio's
    ``retrieveResourcePath`` finds it: ``package://`` (or ``model://``) and relative names in
    ``dirs`` in order, then in ``ROS_PACKAGE_PATH``; ``file://`` and absolute names as they are.
    None when no file is found."""
    searched = [Path(d) for d in dirs] + [Path(d) for d in os.environ.get("ROS_PACKAGE_PATH", "").split(":") if d]
    scheme, sep, rest = name.partition("://")
    if sep:
        if scheme == "file":
            return Path(rest) if Path(rest).is_file() else None
        if scheme not in ("package", "model"):
            return None
    else:
        rest = name
        if Path(rest).is_absolute():
            return Path(rest) if Path(rest).is_file() else None
    for d in searched:
        if (d / rest).is_file():
            return (d / rest).resolve()
    return None


def save_bundle(problems: Problem | Iterable[Problem], folder: str | Path, names: Sequence[str] = ()) -> list[Path]:
    """Write ``problems`` (one, or a suite's) into ``folder`` as a portable bundle (module
    docstring), creating the folder and its parents; the problem files are ``<id>.json``, or
    ``names`` (file names in the folder) when given. Returns the problem files' paths.

    :class:`~planbench.errors.OutputFileError` when ``folder`` is a file (or below one) or cannot
    be written; :class:`~planbench.errors.RobotFileError` when a file the robot needs is missing.
    """
    from planbench.problem import Problem

    items = [problems] if isinstance(problems, Problem) else list(problems)
    if names and len(names) != len(items):
        raise ValueError(f"{len(names)} file names for {len(items)} problems")
    out = _make_folder(Path(folder))
    writer = _BundleWriter(out)
    paths = []
    used: set[str] = set()
    for i, problem in enumerate(items):
        name = names[i] if names else _unique(_safe_name(problem.id) + ".json", used)
        used.add(name)
        d = problem.to_dict()
        d["robot"] = writer.robot(problem.robot.settings)
        d["robot_overrides"] = {}  # every setting, fixed joints included, is in the bundled TOML
        d["scene"] = problem.scene.to_dict()
        for obstacle in d["scene"]["obstacles"]:
            if obstacle.get("path"):
                obstacle["path"] = writer.scene_file(Path(obstacle["path"]))
        path = out / name
        writer.write_text(path, json.dumps(d, indent=1))
        paths.append(path)
    return paths


def _make_folder(folder: Path) -> Path:
    if folder.exists() and not folder.is_dir():
        raise OutputFileError(folder, "is a file; a bundle is a folder: give the name of a folder (made if missing)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise OutputFileError(folder, "a part of this path is a file, not a folder; a bundle needs a folder") from None
    except OSError as exc:
        raise OutputFileError(folder, f"cannot make the bundle folder: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputFileError(folder, "the bundle folder is not writable")
    return folder


class _BundleWriter:
    """Copies files into one bundle folder, each source once, and names them relative to it."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.robots: dict[str, str] = {}  # the settings (as JSON) -> their bundled TOML
        self.robot_names: set[str] = set()
        self.scene_files: dict[Path, str] = {}

    def write_text(self, path: Path, text: str) -> None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
        except OSError as exc:
            raise OutputFileError(path, f"cannot write it: {exc.strerror or exc}") from None

    def copy(self, source: Path, dest: Path) -> None:
        try:
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, dest)
        except OSError as exc:
            raise OutputFileError(dest, f"cannot copy {source} to it: {exc.strerror or exc}") from None

    def scene_file(self, source: Path) -> str:
        """The bundle-relative name of a scene's mesh or point-cloud file, copied once."""
        source = source.resolve()
        if source not in self.scene_files:
            taken = set(self.scene_files.values())
            rel = _unique(f"{SCENE_FILES_DIR}/{_safe_name(source.name)}", taken)
            self.copy(source, self.root / rel)
            self.scene_files[source] = rel
        return self.scene_files[source]

    def robot(self, settings: RobotSettings) -> str:
        """The bundle-relative name of the robot's settings TOML, written (with its URDF, SRDF
        and meshes) the first time."""
        key = json.dumps([settings.source, settings.to_dict()], sort_keys=True)
        if key in self.robots:
            return self.robots[key]
        name = _unique(_safe_name(settings.name), self.robot_names)
        self.robot_names.add(name)
        toml_rel = f"{ROBOTS_DIR}/{name}.toml"
        files = self.root / ROBOTS_DIR / name
        urdf = files / settings.urdf.name
        self.write_text(urdf, self._urdf(settings, files, urdf))
        raw = settings.to_dict()
        raw["urdf"] = f"{name}/{urdf.name}"
        if settings.srdf is not None:
            if not settings.srdf.is_file():
                raise RobotFileError(settings.srdf, f"SRDF file not found (robot {settings.name!r})")
            self.copy(settings.srdf, files / settings.srdf.name)
            raw["srdf"] = f"{name}/{settings.srdf.name}"
        self.write_text(
            self.root / toml_rel, settings_toml(raw, f"Bundled by planbench from {Path(settings.source).name}.")
        )
        self.robots[key] = toml_rel
        return toml_rel

    def _urdf(self, settings: RobotSettings, files: Path, urdf: Path) -> str:
        """The URDF's text with every mesh copied under ``files/meshes`` and named relative to the
        bundled URDF (``urdf``)."""
        try:
            text = read_text(settings.urdf)
            root = ET.fromstring(text)
        except InputFileError as exc:
            raise RobotFileError(settings.urdf, f"{exc.problem} (robot {settings.name!r})") from None
        except ET.ParseError as exc:
            raise RobotFileError(settings.urdf, f"not valid XML: {exc}") from None
        dirs = package_dirs(settings.urdf)
        copied: dict[str, str] = {}  # reference -> its name in the bundle
        sources: dict[str, Path] = {}  # name in the bundle -> the file copied there
        for mesh in root.iter("mesh"):
            ref = mesh.get("filename")
            if not ref:
                continue
            if ref not in copied:
                source = resolve_resource(ref, dirs)
                if source is None:
                    raise RobotFileError(
                        settings.urdf, f"mesh {ref!r} not found (searched {', '.join(map(str, dirs))})"
                    )
                rel = _mesh_name(ref)
                if sources.get(rel, source) != source:  # two files, one name (a/m.stl, package://a/m.stl)
                    rel = _unique(rel, set(sources))
                sources[rel] = source
                self.copy(source, files / rel)
                copied[ref] = rel
            mesh.set("filename", copied[ref])
        return ET.tostring(root, encoding="unicode")


def _mesh_name(ref: str) -> str:
    """Where a mesh goes in the bundle's robot folder: ``meshes/`` and the reference's own path
    (scheme, leading ``/`` and ``..`` dropped), so that distinct references stay distinct."""
    _, sep, rest = ref.partition("://")
    parts = [p for p in PurePosixPath(rest if sep else ref).parts if p not in ("/", "..", ".")]
    return "/".join(["meshes", *(_safe_name(p) for p in parts)])


def _safe_name(name: str) -> str:
    """A file name made of letters, digits, ``._-`` (other characters become ``_``)."""
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return safe or "unnamed"


def _unique(name: str, taken: set[str]) -> str:
    if name not in taken:
        return name
    stem, dot, suffix = name.rpartition(".")
    if not dot or "/" in suffix:
        stem, suffix = name, ""
    k = 2
    while f"{stem}-{k}{'.' + suffix if suffix else ''}" in taken:
        k += 1
    return f"{stem}-{k}{'.' + suffix if suffix else ''}"


def settings_toml(raw: Mapping[str, Any], comment: str = "") -> str:
    """Robot settings (:meth:`RobotSettings.to_dict`'s keys) as a TOML file: scalars and lists
    first, then one table per mapping. Values are JSON-encoded, which is valid TOML for the
    strings, finite numbers and lists that settings hold."""
    lines = [f"# {line}" for line in comment.splitlines()]
    lines.append("# Robot settings: see planbench/robot.py (RobotSettings). Units: m, rad, s.")
    tables = {k: v for k, v in raw.items() if isinstance(v, Mapping)}
    for key, value in raw.items():
        if key not in tables:
            lines.append(f"{key} = {json.dumps(value)}")
    for key, table in tables.items():
        lines.append(f"\n[{key}]")
        lines.extend(f"{json.dumps(str(k))} = {json.dumps(v)}" for k, v in table.items())
    return "\n".join(lines) + "\n"
