"""Triangle meshes of what the simulated depth cameras see: obstacles and the robot's own geometry.

Shapes are triangulated with ``trimesh.creation``: spheres, cylinders and capsules inscribed, their
surface within 0.5 % of the radius of the true one. Each shape is triangulated once (cached per
shape, not per pose) and placed at its pose.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import trimesh

from planbench.scene import Obstacle

__all__ = [
    "ROUND_SECTIONS",
    "SPHERE_SUBDIVISIONS",
    "Triangles",
    "geometry_triangles",
    "obstacle_triangles",
    "placed",
    "stack",
]

SPHERE_SUBDIVISIONS = 3
"""Icosphere subdivisions of sphere obstacles (1,280 triangles, surface within 0.5 % of r)."""
ROUND_SECTIONS = 64
"""Sections around cylinders and capsules (surface within 0.12 % of r)."""

Triangles = tuple[np.ndarray, np.ndarray]
"""(vertices (V, 3) [m], faces (F, 3) int) of a triangle mesh."""


# --- shapes ---------------------------------------------------------------------------------------
def shape_key(o: Obstacle) -> tuple[Any, ...]:
    return (o.type, o.size, o.radius, o.length, o.path, o.scale)


@functools.lru_cache(maxsize=256)
def shape_triangles(key: tuple[Any, ...]) -> Triangles:
    """Triangles of an obstacle's shape in its local frame (cached per shape, not per pose)."""
    kind, size, radius, length, path, scale = key
    if kind == "box":
        mesh = trimesh.creation.box(extents=size)
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=radius)
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=radius, height=length, sections=ROUND_SECTIONS)
    elif kind == "capsule":
        mesh = _capsule(radius, length)
    elif kind == "pointcloud":
        raise ValueError(
            "a pointcloud obstacle has no surface for the simulated depth cameras; "
            "use sensing model 'truth', or give the scene as primitives or meshes"
        )
    else:
        mesh = _load_mesh(path, scale)
    return _frozen(mesh.vertices), _frozen(mesh.faces.astype(np.int64))


def _capsule(radius: float, length: float) -> trimesh.Trimesh:
    """A capsule centred on its segment along local z (trimesh's docstring and code disagree on
    where it puts the segment, so centre it here)."""
    mesh = trimesh.creation.capsule(height=length, radius=radius, count=[ROUND_SECTIONS, ROUND_SECTIONS // 2])
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def _load_mesh(path: str, scale: Any) -> trimesh.Trimesh:
    mesh = trimesh.load(str(path), force="mesh")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"mesh file {path} holds no triangles")
    mesh.apply_scale(np.asarray(scale, dtype=float))
    return mesh


def placed(tri: Triangles, R: np.ndarray, p: np.ndarray) -> Triangles:
    return tri[0] @ R.T + p, tri[1]


def obstacle_triangles(o: Obstacle) -> Triangles:
    """An obstacle's triangles in the scene frame."""
    return placed(shape_triangles(shape_key(o)), o.rotation, np.asarray(o.position, dtype=float))


def stack(parts: list[Triangles]) -> Triangles:
    """One mesh from many: vertices concatenated, faces offset to match."""
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    return np.concatenate([v for v, _ in parts]), np.concatenate(
        [f + k for (_, f), k in zip(parts, offsets, strict=True)]
    )


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


def geometry_triangles(obj: Any) -> Triangles:
    """Triangles of a pinocchio ``GeometryObject`` in its frame: its mesh file (scaled) or primitive."""
    import coal

    g = obj.geometry
    if isinstance(g, coal.Box):
        mesh = trimesh.creation.box(extents=2.0 * np.asarray(g.halfSide))
    elif isinstance(g, coal.Sphere):
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=g.radius)
    elif isinstance(g, coal.Cylinder):
        mesh = trimesh.creation.cylinder(radius=g.radius, height=2.0 * g.halfLength, sections=ROUND_SECTIONS)
    elif isinstance(g, coal.Capsule):
        mesh = _capsule(g.radius, 2.0 * g.halfLength)
    elif obj.meshPath and obj.meshPath not in ("BOX", "SPHERE", "CYLINDER", "CAPSULE"):
        mesh = _load_mesh(obj.meshPath, obj.meshScale)
    else:
        raise ValueError(f"robot collision geometry {obj.name!r}: unsupported shape {type(g).__name__}")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
