"""What a verdict is computed from: the problems and scenarios of a benchmark as the parent read them
before any plugin code ran.

A plugin that could rewrite a problem file between its run and its verdict would choose the
verdict (a straight line through a box becomes a success once the box is gone). The sandbox
(:mod:`planbench.bench.sandbox`) makes those files read-only to plugins; this module makes the
verdict independent of them too, where the sandbox is unavailable:

- :func:`take` (in the benchmark's process, before it starts any worker) loads each problem or
  scenario once and keeps its JSON data, with the SHA-256 of every file that data still points
  to: the robot's URDF, SRDF, settings file and collision meshes, and the scene's mesh and
  point-cloud files.
- :func:`restore` (in a validator) builds the problem or scenario from that data, never from a
  problem or scenario file, after checking that every file it points to still has its hash; a
  file changed since gives :class:`SnapshotChanged`, an ``error`` row that names the file.
"""

from __future__ import annotations

import collections
import hashlib
import json
import os
from pathlib import Path
from typing import Any

from planbench.errors import PlanbenchError

__all__ = ["SnapshotChanged", "restore", "take"]

KEPT = 8
"""Restored problems a validator keeps (what is built for one is cached on it: see
:data:`planbench.problems.datasets.LOADED_PROBLEMS_KEPT`)."""


class SnapshotChanged(PlanbenchError):
    """A file a problem points to changed after the benchmark read it."""


_HASHED: dict[tuple[str, int, int, int], str] = {}


def _sha256(path: str) -> str:
    """The file's SHA-256, hashed once per (path, inode, size, mtime) in this process."""
    st = os.stat(path)
    key = (path, st.st_ino, st.st_size, st.st_mtime_ns)
    if key not in _HASHED:
        _HASHED[key] = _hash(path)
    return _HASHED[key]


def _hash(path: str) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _paths_in(data: Any) -> set[str]:
    """Absolute paths of existing files among the strings of JSON ``data``."""
    out: set[str] = set()
    stack = [data]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, str) and item.startswith("/") and os.path.isfile(item):
            out.add(item)
    return out


def _robot_files(robot: Any) -> set[str]:
    settings = robot.settings
    files = {str(Path(settings.urdf).resolve())}
    if settings.srdf is not None:
        files.add(str(Path(settings.srdf).resolve()))
    for geometry in robot.collision_model.geometryObjects:
        mesh = getattr(geometry, "meshPath", "")
        if mesh and os.path.isfile(mesh):
            files.add(os.path.realpath(mesh))
    return files


def take(entry: str, ref: str) -> dict[str, Any]:
    """The snapshot of problem (``entry`` "planner") or scenario ("controller") ``ref``: JSON data."""
    if entry == "controller":
        from planbench.reactive.sets import load_scenario

        scenario = load_scenario(ref)
        data = scenario.to_dict()
        data["problem"] = scenario.problem.to_dict()  # the data, not a reference to re-read
        robot = scenario.problem.robot
    else:
        from planbench.problems.datasets import load_problem

        problem = load_problem(ref)
        data = problem.to_dict()
        robot = problem.robot
    files = _paths_in(data) | _robot_files(robot)
    return {"entry": entry, "ref": ref, "data": data, "files": {path: _sha256(path) for path in sorted(files)}}


_RESTORED: collections.OrderedDict[str, Any] = collections.OrderedDict()


def restore(snapshot: dict[str, Any]) -> Any:
    """The problem or scenario of ``snapshot`` (see :func:`take`); :class:`SnapshotChanged` when a
    file it points to is not what the benchmark read. Kept for the next run of the same snapshot."""
    key = hashlib.sha256(json.dumps(snapshot, sort_keys=True).encode()).hexdigest()
    if key in _RESTORED:
        _RESTORED.move_to_end(key)
        return _RESTORED[key]
    if "error" in snapshot:
        raise SnapshotChanged(f"it could not be read before the benchmark started: {snapshot['error']}")
    ref = str(snapshot["ref"])
    for path, digest in snapshot["files"].items():
        try:
            now = _hash(path)  # not the cache: a plugin could restore the size and mtime
        except OSError as exc:
            gone = f"{ref}: {path} cannot be read since the benchmark read it ({exc.strerror})"
            raise SnapshotChanged(gone) from None
        if now != digest:
            change = f"sha256 {digest[:12]} -> {now[:12]}"
            raise SnapshotChanged(f"{ref}: {path} changed after the benchmark read it ({change})")
    if snapshot["entry"] == "controller":
        from planbench.reactive.scenario import Scenario

        item: Any = Scenario.from_dict(snapshot["data"], source=ref)
    else:
        from planbench.problem import Problem

        item = Problem.from_dict(snapshot["data"], source=ref)
    _RESTORED[key] = item
    while len(_RESTORED) > KEPT:
        _RESTORED.popitem(last=False)
    return item
