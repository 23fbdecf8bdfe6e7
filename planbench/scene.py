"""Scenes: obstacle geometry as primitives (and meshes) with poses, in the robot's base frame.

JSON format (``planbench-scene/1``; the same obstacle conventions as the MotionBenchMaker data,
which are those of ``shape_msgs/SolidPrimitive``, URDF and coal)::

    {"format": "planbench-scene/1", "name": "my-scene",
     "obstacles": [
       {"name": "table", "type": "box", "size": [1.0, 0.6, 0.04],        # full edge lengths [m]
        "position": [0.5, 0.0, -0.02], "orientation_xyzw": [0, 0, 0, 1]},
       {"name": "can", "type": "cylinder", "radius": 0.03, "length": 0.14, # along local z [m]
        "position": [...], "orientation_xyzw": [...]},
       {"name": "ball", "type": "sphere", "radius": 0.05, "position": [...]},
       {"name": "forearm", "type": "capsule", "radius": 0.05, "length": 0.3, # segment along local z [m]
        "position": [...], "orientation_xyzw": [...]},
       {"name": "bowl", "type": "mesh", "path": "bowl.stl", "scale": [1, 1, 1], "position": [...]},
       {"name": "camera", "type": "pointcloud", "path": "cloud.npz", "radius": 0.005} # .npz or .ply
     ]}

``orientation_xyzw`` is a unit quaternion, scalar last, mapping the obstacle's local axes into the
scene frame (``p_scene = R p_local + position``); it defaults to the identity. A mesh or point
cloud path is relative to the JSON file. A point cloud's geometry is the union of the cubes of edge
``2 radius`` on a lattice that hold a point (its octree's leaves): :mod:`planbench.geometry.pointcloud`.

:meth:`Scene.load` and :meth:`Scene.save` also read and write MoveIt's text scenes (a ``.scene``
path): :mod:`planbench.geometry.moveit_scene`.
"""

from __future__ import annotations

import functools
import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.errors import ProblemFileError
from planbench.files.inputs import InputFileError, read_json, regular_file
from planbench.geometry import moveit_scene
from planbench.geometry.pointcloud import VoxelCloud, load_cloud

__all__ = ["Obstacle", "Scene", "SHAPES", "read_problem_json"]

SHAPES = ("box", "sphere", "cylinder", "capsule", "mesh", "pointcloud")
SCENE_FORMAT = "planbench-scene/1"


@dataclass(frozen=True)
class Obstacle:
    """One rigid obstacle. Units: metres; quaternion ``[x, y, z, w]``."""

    name: str
    type: str
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    size: tuple[float, float, float] | None = None  # box: full edge lengths [m]
    radius: float | None = None  # sphere, cylinder, capsule; pointcloud: point radius, cubes of edge 2 radius [m]
    length: float | None = None  # cylinder: full height along local z; capsule: its segment's length [m]
    path: str | None = None  # mesh or point-cloud file (absolute, or relative to the working directory)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)  # mesh scale

    def __post_init__(self) -> None:
        where = f"obstacle {self.name!r}"
        if self.type not in SHAPES:
            raise ValueError(f"{where}: unknown type {self.type!r}; use one of {SHAPES}")
        _check_vector(self.position, 3, f"{where}: position")
        _check_vector(self.orientation_xyzw, 4, f"{where}: orientation_xyzw")
        norm = math.sqrt(sum(x * x for x in self.orientation_xyzw))
        if abs(norm - 1.0) > 1e-6:
            raise ValueError(f"{where}: orientation_xyzw must be a unit quaternion (norm {norm:.6g})")
        if self.type == "box":
            if self.size is None:
                raise ValueError(f"{where}: a box needs 'size' = [x, y, z] full edge lengths [m]")
            _check_vector(self.size, 3, f"{where}: size")
            if min(self.size) <= 0:
                raise ValueError(f"{where}: box size must be > 0, got {list(self.size)}")
        if self.type in ("sphere", "cylinder", "capsule", "pointcloud"):
            if self.radius is None or not math.isfinite(self.radius) or self.radius <= 0:
                raise ValueError(f"{where}: a {self.type} needs 'radius' > 0 [m], got {self.radius}")
        if self.type == "cylinder":
            if self.length is None or not math.isfinite(self.length) or self.length <= 0:
                raise ValueError(f"{where}: a cylinder needs 'length' > 0 [m], got {self.length}")
        if self.type == "capsule":
            if self.length is None or not math.isfinite(self.length) or self.length < 0:
                raise ValueError(f"{where}: a capsule needs 'length' >= 0 [m] (its segment), got {self.length}")
        if self.type == "mesh":
            if not self.path:
                raise ValueError(f"{where}: a mesh needs 'path'")
            _check_vector(self.scale, 3, f"{where}: scale")
            if min(abs(x) for x in self.scale) == 0:
                raise ValueError(f"{where}: mesh scale must be non-zero on every axis, got {list(self.scale)}")
            try:
                st = regular_file(self.path, MAX_MESH_BYTES)
            except InputFileError as exc:
                if exc.problem.endswith("no such file"):
                    raise ValueError(f"{where}: mesh file not found: {self.path}") from None
                raise ValueError(f"{where}: mesh file {exc}") from None
            problem = _mesh_problem(str(Path(self.path).resolve()), st.st_mtime_ns, st.st_size)
            if problem:
                raise ValueError(f"{where}: mesh file {self.path}: {problem}")
        if self.type == "pointcloud":
            if not self.path:
                raise ValueError(f"{where}: a pointcloud needs 'path' (a .npz with array 'points' or a .ply)")
            self.cloud()  # read now: a bad file is an error of the scene file, not of a later query

    # --- geometry -------------------------------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation matrix of the obstacle's local axes in the scene frame."""
        return pin.Quaternion(np.asarray(self.orientation_xyzw, dtype=float)).normalized().toRotationMatrix()

    def placement(self) -> Any:
        """The pose as a ``pinocchio.SE3``."""
        return pin.SE3(self.rotation, np.array(self.position, dtype=float))

    def cloud(self) -> VoxelCloud:
        """A pointcloud's voxel geometry (read once per file and radius, then cached)."""
        if self.type != "pointcloud":
            raise ValueError(f"obstacle {self.name!r} is a {self.type}, not a pointcloud")
        return load_cloud(str(self.path), float(self.radius))  # type: ignore[arg-type]

    def collision_geometry(self) -> Any:
        """A coal collision geometry in the obstacle's local frame (a pointcloud: its octree)."""
        import coal

        if self.type == "pointcloud":
            return self.cloud().octree()
        if self.type == "box":
            return coal.Box(*self.size)  # type: ignore[misc]
        if self.type == "sphere":
            return coal.Sphere(self.radius)
        if self.type == "cylinder":
            return coal.Cylinder(self.radius, self.length)
        if self.type == "capsule":
            return coal.Capsule(self.radius, self.length)
        loader = coal.MeshLoader()
        return loader.load(str(self.path), np.array(self.scale, dtype=float))

    def local_half_extents(self) -> np.ndarray:
        """Half extents of the obstacle's bounding box in its local frame [m]."""
        if self.type == "box":
            return 0.5 * np.array(self.size, dtype=float)
        if self.type == "sphere":
            return np.full(3, float(self.radius))  # type: ignore[arg-type]
        if self.type == "cylinder":
            return np.array([self.radius, self.radius, 0.5 * self.length], dtype=float)  # type: ignore[operator]
        if self.type == "capsule":
            r = float(self.radius)  # type: ignore[arg-type]
            return np.array([r, r, 0.5 * self.length + r], dtype=float)  # type: ignore[operator]
        if self.type == "pointcloud":
            lo, hi = self.cloud().bounds()
            return np.maximum(np.abs(lo), np.abs(hi))
        geom = self.collision_geometry()
        geom.computeLocalAABB()
        aabb = geom.aabb_local
        lo, hi = np.array(aabb.min_), np.array(aabb.max_)
        return np.maximum(np.abs(lo), np.abs(hi))

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box in the scene frame, as (lower corner, upper corner) [m]."""
        if self.type == "pointcloud":  # not centred on its frame's origin: box its own bounds
            lo, hi = self.cloud().bounds()
            half = np.abs(self.rotation) @ (0.5 * (hi - lo))
            c = self.rotation @ (0.5 * (lo + hi)) + np.array(self.position, dtype=float)
            return c - half, c + half
        half = np.abs(self.rotation) @ self.local_half_extents()
        c = np.array(self.position, dtype=float)
        return c - half, c + half

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Exact signed distance [m] from each of the (N, 3) points to the obstacle's surface:
        negative inside. Primitives and point clouds (meshes are handled by coal).
        """
        local = (np.asarray(points, dtype=float) - np.array(self.position)) @ self.rotation
        if self.type == "pointcloud":
            return self.cloud().signed_distance(local)
        if self.type == "box":
            q = np.abs(local) - 0.5 * np.array(self.size)
        elif self.type == "sphere":
            return np.linalg.norm(local, axis=1) - self.radius  # type: ignore[operator]
        elif self.type == "capsule":  # distance to the segment along local z, minus the radius
            h = 0.5 * self.length  # type: ignore[operator]
            nearest = np.zeros_like(local)
            nearest[:, 2] = np.clip(local[:, 2], -h, h)
            return np.linalg.norm(local - nearest, axis=1) - self.radius  # type: ignore[operator]
        elif self.type == "cylinder":
            q = np.stack(
                [
                    np.hypot(local[:, 0], local[:, 1]) - self.radius,  # type: ignore[operator]
                    np.abs(local[:, 2]) - 0.5 * self.length,  # type: ignore[operator]
                ],
                axis=1,
            )  # type: ignore[operator]
        else:
            raise NotImplementedError("mesh obstacles have no signed distance here; use coal")
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Boolean mask: which of the (N, 3) points lie inside (or on) the obstacle."""
        return self.signed_distance(points) <= 0.0

    # --- JSON -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "type": self.type}
        if self.type == "box":
            d["size"] = list(self.size)  # type: ignore[arg-type]
        if self.type in ("sphere", "cylinder", "capsule", "pointcloud"):
            d["radius"] = self.radius
        if self.type in ("cylinder", "capsule"):
            d["length"] = self.length
        if self.type in ("mesh", "pointcloud"):
            d["path"] = self.path
        if self.type == "mesh":
            d["scale"] = list(self.scale)
        d["position"] = list(self.position)
        d["orientation_xyzw"] = list(self.orientation_xyzw)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], base_dir: Path | None = None) -> Obstacle:
        known = {"name", "type", "position", "orientation_xyzw", "size", "radius", "length", "path", "scale"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"obstacle {d.get('name')!r}: unknown keys {sorted(unknown)}; allowed {sorted(known)}")
        if "type" not in d:
            raise ValueError(f"obstacle {d.get('name')!r}: missing 'type' (one of {SHAPES})")
        path = d.get("path")
        if path is not None and base_dir is not None and not Path(path).is_absolute():
            path = str(base_dir / path)
        return cls(
            name=str(d.get("name", d["type"])),
            type=str(d["type"]),
            position=_tuple(d.get("position", (0.0, 0.0, 0.0))),  # type: ignore[arg-type]
            orientation_xyzw=_tuple(d.get("orientation_xyzw", (0.0, 0.0, 0.0, 1.0))),  # type: ignore[arg-type]
            size=_tuple(d["size"]) if "size" in d else None,  # type: ignore[arg-type]
            radius=float(d["radius"]) if "radius" in d else None,
            length=float(d["length"]) if "length" in d else None,
            path=path,
            scale=_tuple(d.get("scale", (1.0, 1.0, 1.0))),  # type: ignore[arg-type]
        )


@dataclass(frozen=True)
class Scene:
    """A named set of obstacles, all in the robot's base frame."""

    obstacles: tuple[Obstacle, ...] = ()
    name: str = "scene"
    metadata: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        names = [o.name for o in self.obstacles]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"scene {self.name!r}: obstacle names must be unique, repeated: {dupes}")

    def __len__(self) -> int:
        return len(self.obstacles)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box of all obstacles [m]; raises on an empty scene."""
        if not self.obstacles:
            raise ValueError(f"scene {self.name!r} has no obstacles, so no bounding box")
        boxes = [o.aabb() for o in self.obstacles]
        return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)

    def with_obstacles(self, obstacles: Iterable[Obstacle]) -> Scene:
        return Scene(tuple(self.obstacles) + tuple(obstacles), self.name, dict(self.metadata))

    def to_dict(self, relative_to: Path | None = None) -> dict[str, Any]:
        """The scene as JSON; with ``relative_to`` (the folder of the file it goes into) the meshes'
        and clouds' file paths are written relative to it, so the files can move together."""
        obstacles = [o.to_dict() for o in self.obstacles]
        if relative_to is not None:
            for d in obstacles:
                if "path" in d and Path(d["path"]).is_absolute():
                    d["path"] = os.path.relpath(d["path"], Path(relative_to).resolve())
        return {"format": SCENE_FORMAT, "name": self.name, "obstacles": obstacles}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<dict>", base_dir: Path | None = None) -> Scene:
        if not isinstance(d, dict):
            raise ProblemFileError(source, f"a scene must be a JSON object, got {type(d).__name__}")
        fmt = d.get("format", SCENE_FORMAT)
        if fmt != SCENE_FORMAT:
            raise ProblemFileError(source, f"unsupported scene format {fmt!r}; expected {SCENE_FORMAT!r}")
        items = d.get("obstacles", [])
        if not isinstance(items, list):
            raise ProblemFileError(source, "'obstacles' must be a list")
        obstacles = []
        for k, item in enumerate(items):
            try:
                if not isinstance(item, dict):
                    raise ValueError("must be a JSON object")
                obstacles.append(Obstacle.from_dict(item, base_dir))
            except (ValueError, TypeError, KeyError) as exc:
                raise ProblemFileError(source, f"obstacle #{k}: {exc}") from exc
        try:
            return cls(tuple(obstacles), str(d.get("name", "scene")))
        except ValueError as exc:
            raise ProblemFileError(source, str(exc)) from exc

    def save(self, path: str | Path) -> None:
        """Write the scene as JSON, file paths relative to its folder (:meth:`to_dict`); a path
        ending in ``.scene``: as MoveIt's text scene (:mod:`planbench.geometry.moveit_scene`)."""
        if Path(path).suffix.lower() == moveit_scene.SUFFIX:
            moveit_scene.write_moveit_scene(self.to_dict(), path)
            return
        Path(path).write_text(json.dumps(self.to_dict(relative_to=Path(path).resolve().parent), indent=1))

    @classmethod
    def load(cls, path: str | Path, mesh_dir: str | Path | None = None) -> Scene:
        """A scene file: planbench's JSON, or by its suffix a MoveIt ``.scene`` file, whose meshes
        are written as OBJ files into ``mesh_dir`` (default: the user's cache,
        :func:`planbench.geometry.moveit_scene.default_mesh_dir`)."""
        p = Path(path)
        if p.suffix.lower() == moveit_scene.SUFFIX:
            return cls.from_dict(moveit_scene.read_moveit_scene(p, mesh_dir), str(p))
        return cls.from_dict(read_problem_json(p), str(p), p.parent)


MAX_MESH_BYTES = 256 << 20
"""[B] The largest mesh file read (256 MiB; the shipped robots' meshes are under 1 MB each)."""


@functools.lru_cache(maxsize=64)
def _mesh_problem(path: str, mtime_ns: int, size: int) -> str:
    """Why coal cannot load the mesh file (its first line), or "" when it can (checked once per
    file version and process: a scene names a bad mesh at load, not at its first collision query)."""
    import coal

    try:
        geometry = coal.MeshLoader().load(path, np.ones(3))
    except (ValueError, RuntimeError) as exc:
        lines = [x.strip() for x in str(exc).splitlines() if x.strip()]
        detail = [x for x in lines if not x.startswith(("From file", "in function", "at line", "Hint"))]
        return "coal cannot load it: " + " ".join(detail)[:300].replace("message: ", "")
    if geometry.num_tris == 0:
        return "it holds no triangles"
    return ""


def read_problem_json(path: Path) -> Any:
    """The JSON in a problem or scene file (a regular file of at most
    :data:`planbench.files.inputs.MAX_TEXT_BYTES`); :class:`ProblemFileError` naming it otherwise."""
    try:
        return read_json(path)
    except InputFileError as exc:
        raise ProblemFileError(path, exc.problem) from None


def _tuple(v: Sequence[Any]) -> tuple[float, ...]:
    return tuple(float(x) for x in v)


def _check_vector(v: Sequence[float], n: int, what: str) -> None:
    if len(v) != n:
        raise ValueError(f"{what} must have {n} values, got {len(v)}")
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"{what} contains NaN or infinite values: {list(v)}")
