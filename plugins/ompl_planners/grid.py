"""Collision checking against an occupancy grid instead of the scene's primitives.

The planner can be given the same voxel information the matrix-field planner sees: the scene is
voxelized with :meth:`planbench.geometry.occupancy.OccupancyGrid.from_scene` (rule ``"any"``: a cell is
occupied when any part of it overlaps an obstacle, so obstacles grow by at most one cell and never
shrink), and the occupied cells become coal geometry in a :class:`~planbench.checking.collision.CollisionChecker`
(so robot self-collision, the ignore list and the broadphase are the same as in the exact mode):

- ``"octree"``: one ``coal.OcTree`` holding the occupied cells. The grid's origin is snapped to a
  multiple of the resolution, so the octree's cells are exactly the grid's cells. Collision queries
  against it are fine (~30-40 us per robot); coal's octree *distance* queries are very slow, which is
  why nothing here asks for them.
- ``"boxes"``: the occupied cells merged greedily into boxes (:func:`merge_cells`: runs along z,
  then equal runs along y, then equal rectangles along x), one ``coal.Box`` each: the union of the
  cells, exactly, in few objects (a voxelized box scene gives about one box per obstacle). One box per
  cell or per z-run would be thousands of objects, and the broadphase updates every object's
  bounding box on every query (~5 ms per check before merging).

A cell value is occupied when it is ``>= threshold`` (the grid may be probabilistic).
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

import coal
import numpy as np
import pinocchio as pin

from planbench.checking.collision import CollisionChecker
from planbench.geometry.occupancy import OccupancyGrid, merge_cells, scene_grid
from planbench.robot import Robot
from planbench.scene import Scene

__all__ = [
    "GRID_GEOMETRIES",
    "cells_checker",
    "cells_octree",
    "grid_checker",
    "grid_for_scene",
    "pieces_checker",
    "pieces_checker_in_steps",
]

GRID_GEOMETRIES = ("octree", "boxes")


@dataclass(frozen=True)
class _GeometryObstacle:
    """What CollisionChecker reads from an obstacle: a name, a placement and a coal geometry."""

    name: str
    geometry: Any
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def placement(self) -> Any:

        return pin.SE3(np.eye(3), np.array(self.position))

    def collision_geometry(self) -> Any:
        return self.geometry


@dataclass(frozen=True)
class _GeometryScene:
    obstacles: tuple[_GeometryObstacle, ...]
    name: str = "occupancy-grid"


def grid_for_scene(scene: Scene, resolution: float, padding: float = 0.0) -> OccupancyGrid:
    """The scene voxelized (:func:`planbench.geometry.occupancy.scene_grid`, rule ``"any"``) on cells aligned
    to multiples of ``resolution`` [m], as an octree needs (bounds: the scene's bounding box grown by
    ``padding`` [m], rounded out to whole cells)."""
    grid = scene_grid(scene, resolution, padding, aligned=True)
    if grid is None:
        raise ValueError("an empty scene has no grid")
    return grid


def occupied_centres(grid: OccupancyGrid, threshold: float = 0.5) -> np.ndarray:
    """(N, 3) centres [m] of the cells whose occupancy is ``>= threshold``."""
    idx = np.argwhere(grid.data >= threshold)
    return grid.origin + (idx + 0.5) * grid.resolution


def grid_checker(
    robot: Robot, grid: OccupancyGrid, geometry: str = "octree", threshold: float = 0.5
) -> CollisionChecker:
    """A CollisionChecker of ``robot`` against the occupied cells of ``grid`` (see module docstring)."""

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
        for k, (lo_idx, hi_idx) in enumerate(merge_cells(grid.data >= threshold)):
            lo = grid.origin + np.asarray(lo_idx) * res
            size = (np.asarray(hi_idx) - np.asarray(lo_idx)) * res
            centre = tuple(float(x) for x in lo + 0.5 * size)
            obstacles.append(_GeometryObstacle(f"cells-{k}", coal.Box(*size), centre))  # type: ignore[arg-type]
    return CollisionChecker(robot, _GeometryScene(tuple(obstacles)))  # type: ignore[arg-type]


def cells_checker(robot: Robot, grid: OccupancyGrid, cells: np.ndarray) -> CollisionChecker:
    """A CollisionChecker of ``robot`` against the cells of ``grid`` with the flat indices ``cells``
    (``np.ravel_multi_index`` order), as one ``coal.OcTree`` placed at the grid's corner: its cells
    are the grid's whatever the origin (the octree's own cells lie on multiples of the resolution
    from its frame's origin). Building it costs about 10 ms for 3,000 cells, where the same cells
    merged into 700 boxes cost 0.2-1 s (a geometry object and collision pairs per box)."""
    cells = np.asarray(cells, dtype=np.intp)
    return pieces_checker(robot, [cells_octree(grid, cells)] if len(cells) else [])


def cells_octree(grid: OccupancyGrid, cells: np.ndarray, name: str = "occupancy-octree") -> Any:
    """One obstacle for :func:`pieces_checker`: the cells of ``grid`` with the flat indices ``cells``
    (at least one) as a ``coal.OcTree`` placed at the grid's corner (as :func:`cells_checker`'s).
    A controller builds a large grid's cells as several of these, one per control tick, where one
    octree of 15,000 cells costs 7-17 ms at once."""
    res = grid.resolution
    idx = np.column_stack(np.unravel_index(np.asarray(cells, dtype=np.intp), grid.shape))
    corner = tuple(float(x) for x in grid.origin)
    return _GeometryObstacle(name, coal.makeOctree((idx + 0.5) * res, res), corner)  # type: ignore[arg-type]


def pieces_checker(robot: Robot, pieces: list[Any]) -> CollisionChecker:
    """A CollisionChecker of ``robot`` against the obstacles made by :func:`cells_octree` (their
    names must differ)."""
    return CollisionChecker(robot, _GeometryScene(tuple(pieces)))  # type: ignore[arg-type]


def pieces_checker_in_steps(robot: Robot, pieces: list[Any]) -> Generator[None, None, CollisionChecker]:
    """:func:`pieces_checker` built in steps (:meth:`CollisionChecker.in_steps`); ``yield from`` it."""
    return CollisionChecker.in_steps(robot, _GeometryScene(tuple(pieces)))  # type: ignore[arg-type]
