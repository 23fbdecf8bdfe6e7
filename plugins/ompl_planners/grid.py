"""Collision checking against an occupancy grid instead of the scene's primitives.

The planner can be given the same voxel information the matrix-field planner sees: the scene is
voxelized with :meth:`planbench.occupancy.OccupancyGrid.from_scene` (rule ``"any"``: a cell is
occupied when any part of it overlaps an obstacle, so obstacles grow by at most one cell and never
shrink), and the occupied cells become coal geometry in a :class:`~planbench.collision.CollisionChecker`
(so robot self-collision, the ignore list and the broadphase are the same as in the exact mode):

- ``"octree"``: one ``coal.OcTree`` holding the occupied cells. The grid's origin is snapped to a
  multiple of the resolution, so the octree's cells are exactly the grid's cells. Collision queries
  against it are fine (~30-40 us per robot); coal's octree *distance* queries are very slow, which is
  why nothing here asks for them.
- ``"boxes"``: one ``coal.Box`` per run of occupied cells along z (the union of the cells, exactly).

A cell value is occupied when it is ``>= threshold`` (the grid may be probabilistic).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.collision import CollisionChecker
from planbench.occupancy import OccupancyGrid
from planbench.robot import Robot
from planbench.scene import Scene

__all__ = ["GRID_GEOMETRIES", "grid_for_scene", "grid_checker"]

GRID_GEOMETRIES = ("octree", "boxes")


@dataclass(frozen=True)
class _GeometryObstacle:
    """What CollisionChecker reads from an obstacle: a name, a placement and a coal geometry."""

    name: str
    geometry: Any
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def placement(self) -> Any:
        import pinocchio as pin

        return pin.SE3(np.eye(3), np.array(self.position))

    def collision_geometry(self) -> Any:
        return self.geometry


@dataclass(frozen=True)
class _GeometryScene:
    obstacles: tuple[_GeometryObstacle, ...]
    name: str = "occupancy-grid"


def grid_for_scene(scene: Scene, resolution: float, padding: float = 0.0) -> OccupancyGrid:
    """The scene voxelized with the ``"any"`` rule on cells aligned to multiples of ``resolution``
    [m] (bounds: the scene's bounding box grown by ``padding`` [m], rounded out to whole cells)."""
    lo, hi = scene.aabb()
    lower = np.floor((np.asarray(lo) - padding) / resolution) * resolution
    upper = np.ceil((np.asarray(hi) + padding) / resolution) * resolution
    upper = np.maximum(upper, lower + resolution)
    return OccupancyGrid.from_scene(scene, resolution, bounds=(lower, upper), rule="any")


def occupied_centres(grid: OccupancyGrid, threshold: float = 0.5) -> np.ndarray:
    """(N, 3) centres [m] of the cells whose occupancy is ``>= threshold``."""
    idx = np.argwhere(grid.data >= threshold)
    return grid.origin + (idx + 0.5) * grid.resolution


def grid_checker(
    robot: Robot, grid: OccupancyGrid, geometry: str = "octree", threshold: float = 0.5
) -> CollisionChecker:
    """A CollisionChecker of ``robot`` against the occupied cells of ``grid`` (see module docstring)."""
    import coal

    if geometry not in GRID_GEOMETRIES:
        raise ValueError(f"unknown grid geometry {geometry!r}; use one of {GRID_GEOMETRIES}")
    res = grid.resolution
    obstacles: list[_GeometryObstacle] = []
    if geometry == "octree":
        offset = grid.origin / res
        if not np.allclose(offset, np.round(offset), atol=1e-6):
            raise ValueError(
                f"an octree needs a grid origin on a multiple of the resolution ({res} m), got {grid.origin}; "
                "build the grid with grid_for_scene() or use geometry='boxes'"
            )
        centres = occupied_centres(grid, threshold)
        if len(centres):
            obstacles.append(_GeometryObstacle("occupancy-octree", coal.makeOctree(centres, res)))
    else:
        occupied = grid.data >= threshold
        nx, ny, nz = occupied.shape
        for i in range(nx):
            for j in range(ny):
                column = occupied[i, j]
                if not column.any():
                    continue
                # runs of occupied cells along z: starts where a cell is occupied and the one below not
                padded = np.concatenate([[False], column, [False]])
                edges = np.flatnonzero(padded[1:] != padded[:-1])
                for k0, k1 in zip(edges[::2], edges[1::2], strict=True):
                    lo = grid.origin + np.array([i, j, k0]) * res
                    size = np.array([res, res, (k1 - k0) * res])
                    centre = tuple(float(x) for x in lo + 0.5 * size)
                    obstacles.append(_GeometryObstacle(f"cells-{i}-{j}-{k0}", coal.Box(*size), centre))  # type: ignore[arg-type]
    return CollisionChecker(robot, _GeometryScene(tuple(obstacles)))  # type: ignore[arg-type]
