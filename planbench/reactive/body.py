"""The cells of a grid that the arm's own body fills at a configuration.

A depth camera sees the arm's surface and the self filter removes it, so the cells the arm fills
are never seen free by a ray; yet they are known: the robot is there, so no obstacle is. The
sensor marks them known (keeping whatever occupancy evidence they had), and the
``unobserved_motion`` metric asks the opposite question of the arm at a later configuration: does
any of its cells lie where the controller's latest observation knows nothing?

The body is a set of sample points per collision object, in the object's frame, built once per
robot and spacing ``s`` (the grid's resolution): the points of an ``s / 2`` lattice inside the
object's mesh and the vertices of the mesh subdivided until no edge is longer than ``s``, one point
kept per ``s / 4`` cube. A cell counts as filled when a sample point lies in it. Every cell the
body covers whole holds one, however the link is turned: a cube of side ``s`` holds a ball of
radius ``s / 2``, more than the ``s / 2`` lattice's covering radius (``s sqrt(3) / 4``). A cell
the body only clips may be missed.
"""

from __future__ import annotations

import functools

import numpy as np
import pinocchio as pin
import trimesh

from planbench.geometry.part_cells import PartPoints
from planbench.robot import Robot

__all__ = ["ArmBody", "body_points"]


@functools.lru_cache(maxsize=8)
def body_points(robot: Robot, spacing: float) -> tuple[np.ndarray, ...]:
    """Sample points (N_i, 3) [m] of each collision object of ``robot`` in its own frame, in
    ``collision_model`` order (module docstring)."""
    from planbench.reactive.meshes import geometry_triangles

    out = []
    for obj in robot.collision_model.geometryObjects:
        vertices, faces = geometry_triangles(obj)
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        step = spacing / 2  # any cube of side `spacing` holds a point of this lattice, however rotated
        axes = [np.arange(lo[i] + step / 2, hi[i], step) for i in range(3)]
        lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        inside = lattice[mesh.contains(lattice)] if len(lattice) and mesh.is_watertight else lattice[:0]
        surface, _ = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=spacing, max_iter=20)
        points = np.concatenate([inside, np.asarray(surface, dtype=float)])
        _, first = np.unique(np.floor(points / (spacing / 4)).astype(np.int64), axis=0, return_index=True)
        kept = np.ascontiguousarray(points[np.sort(first)])
        kept.setflags(write=False)
        out.append(kept)
    return tuple(out)


class ArmBody:
    """The cells of one grid (``lower`` corner [m], ``shape``, ``resolution`` [m]) that the arm
    fills at a configuration."""

    def __init__(self, robot: Robot, lower: np.ndarray, shape: tuple[int, int, int], resolution: float) -> None:
        self.robot = robot
        self.lower = np.asarray(lower, dtype=float)
        self.shape = tuple(int(n) for n in shape)
        self.resolution = float(resolution)
        self._points = PartPoints(body_points(robot, self.resolution))
        self._data = robot.model.createData()
        self._geometry_data = pin.GeometryData(robot.collision_model)

    def _placements(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pin.updateGeometryPlacements(self.robot.model, self._data, self.robot.collision_model, self._geometry_data, q)
        placements = self._geometry_data.oMg
        return np.array([M.rotation for M in placements]), np.array([M.translation for M in placements])

    def mark(self, out: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Set the cells of ``out`` (bool, the grid's shape) that the arm fills at ``q`` [rad]."""
        return self._points.mark(out, self.lower, self.resolution, *self._placements(q))

    def cells(self, q: np.ndarray) -> np.ndarray:
        """Flat indices (sorted) of the cells the arm fills at ``q`` [rad]: those :meth:`mark` sets."""
        return self._points.cells(self.shape, self.lower, self.resolution, *self._placements(q))

    def in_unknown(self, q: np.ndarray, known: np.ndarray | None) -> bool:
        """Whether any cell the arm fills at ``q`` is unknown in the mask ``known`` (None: all known)."""
        if known is None:
            return False
        return self._points.any_outside(known, self.lower, self.resolution, *self._placements(q))
