"""An observed grid's occupied cells as geometry, for controllers that measure distances.

``distance-field`` and ``matrix-field-qp`` measure exact distances (coal) to geometry. With truth
sensing the observation carries the scene; a depth grid does not, so its occupied cells become the
geometry, in one of two ways (their setting ``observed_geometry``):

- ``"octree"`` (default): the occupied cells within ``reach`` of the arm's control points, as one
  ``coal.OcTree`` (:func:`near_cells_scene`). Cells farther away cannot push within the frame;
  coal measures a link's distance to the whole octree in one query.
- ``"boxes"``: every occupied cell of the grid, merged greedily into few boxes whose union is
  exactly those cells (:func:`planbench.geometry.occupancy.merge_cells`, which the OMPL planners'
  grid checker uses too), one obstacle each. A map holds thousands of cells, and building a
  distance model over hundreds of boxes cost seconds of charged compute a frame
  (docs/reactive.md, "Results on dynamic-test").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import coal
import numpy as np
import pinocchio as pin
from scipy.spatial import cKDTree

from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid, merge_cells
from planbench.scene import Obstacle, Scene
from planbench_plugins.controllers.crop import occupied_part

__all__ = [
    "OBSERVED_GEOMETRIES",
    "CellsOctree",
    "CellsScene",
    "cell_boxes",
    "cell_scene",
    "near_cells_scene",
    "observed_scene",
]

OBSERVED_GEOMETRIES = ("octree", "boxes")
"""How a depth grid's occupied cells become geometry (module docstring)."""


@dataclass(frozen=True)
class GeometrySettings:
    """How a depth grid becomes the geometry a controller measures distances to (module
    docstring); a mixin of ``distance-field``'s and ``matrix-field-qp``'s configs."""

    observed_geometry: str = "octree"
    """``"octree"``: the occupied cells within ``geometry_reach`` of a control point, one octree;
    ``"boxes"``: every occupied cell, merged into boxes (seconds a frame with a map)."""
    geometry_reach: float = 0.3
    """[m] with ``"octree"``, the cells within this distance of a control point: a field's reach
    from a link surface (0.15 m), a link's radius (0.09 m) and the arm's motion in a 30 Hz frame
    at 2 m/s (0.06 m)."""

    def validate_geometry(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad setting."""
        if self.observed_geometry not in OBSERVED_GEOMETRIES:
            raise InvalidConfigError(
                f"observed_geometry must be one of {OBSERVED_GEOMETRIES} (how a depth grid's cells become "
                f"geometry), got {self.observed_geometry!r}"
            )
        v = self.geometry_reach
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise InvalidConfigError(f"geometry_reach must be a finite number > 0 [m], got {v!r}")


@dataclass(frozen=True)
class CellsOctree:
    """Cells of a grid as one obstacle: a ``coal.OcTree`` placed at the grid's corner (its cells
    lie on multiples of the resolution from there), with its world bounding box [m]."""

    name: str
    geometry: Any
    corner: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def placement(self) -> Any:
        return pin.SE3(np.eye(3), np.asarray(self.corner, dtype=float))

    def collision_geometry(self) -> Any:
        return self.geometry

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lower.copy(), self.upper.copy()


@dataclass(frozen=True)
class CellsScene:
    """What the distance models read from a scene: named obstacles."""

    obstacles: tuple[CellsOctree, ...] = ()
    name: str = "observed-cells"

    def __len__(self) -> int:
        return len(self.obstacles)


def near_cells_scene(grid: OccupancyGrid, points: np.ndarray, reach: float, threshold: float = 0.5) -> CellsScene:
    """The cells of ``grid`` with occupancy ``>= threshold`` whose centre lies within ``reach`` [m]
    of one of the (N, 3) ``points`` [m], as one octree obstacle (an empty scene when none). Only
    the block of the grid around the points is read (a pass over a whole 142^3 grid costs
    milliseconds)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if not len(points):
        return CellsScene()
    res, shape = grid.resolution, np.array(grid.shape)
    corner = np.asarray(grid.origin, dtype=float)
    lo = np.clip(np.floor((points.min(axis=0) - reach - corner) / res).astype(int), 0, shape)
    hi = np.clip(np.ceil((points.max(axis=0) + reach - corner) / res).astype(int), 0, shape)
    if np.any(hi <= lo):
        return CellsScene()
    block = np.asarray(grid.data)[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    index = np.argwhere(block >= threshold) + lo  # cells of the grid
    if not len(index):
        return CellsScene()
    centres = corner + (index + 0.5) * res
    distance, _ = cKDTree(points).query(centres, distance_upper_bound=reach)
    index, centres = index[np.isfinite(distance)], centres[np.isfinite(distance)]
    if not len(index):
        return CellsScene()
    octree = coal.makeOctree((index + 0.5) * res, res)  # on the octree's own cells, placed at the corner
    half = 0.5 * res
    return CellsScene(
        (CellsOctree("near-cells", octree, corner, centres.min(axis=0) - half, centres.max(axis=0) + half),)
    )


def cell_boxes(cells: np.ndarray, origin: np.ndarray, resolution: float, prefix: str = "cells") -> list[Obstacle]:
    """The ``True`` cells of a bool array (a grid's shape, its corner at ``origin`` [m], cells of
    ``resolution`` [m]) merged into boxes named ``<prefix>-<k>``; only the block holding them is
    visited (the merging visits every column)."""
    columns = np.asarray(cells.any(axis=2))
    xs, ys = np.flatnonzero(columns.any(axis=1)), np.flatnonzero(columns.any(axis=0))
    if not len(xs):
        return []
    zs = np.flatnonzero(cells[xs[0] : xs[-1] + 1, ys[0] : ys[-1] + 1].any(axis=(0, 1)))
    lo0 = np.array([xs[0], ys[0], zs[0]])
    block = cells[xs[0] : xs[-1] + 1, ys[0] : ys[-1] + 1, zs[0] : zs[-1] + 1]
    obstacles = []
    for k, (lo_idx, hi_idx) in enumerate(merge_cells(block)):
        lo = origin + (lo0 + np.asarray(lo_idx)) * resolution
        size = (np.asarray(hi_idx) - np.asarray(lo_idx)) * resolution
        obstacles.append(Obstacle(f"{prefix}-{k}", "box", position=tuple(lo + 0.5 * size), size=tuple(size)))
    return obstacles


def cell_scene(grid: OccupancyGrid, threshold: float = 0.5) -> Scene:
    """The cells of ``grid`` with occupancy ``>= threshold`` as a scene of boxes (empty when none)."""
    part = occupied_part(grid)  # the merging visits every column: only those of the occupied block
    if part is None:
        return Scene(name="observed-cells")
    return Scene(tuple(cell_boxes(np.asarray(part.data) >= threshold, part.origin, part.resolution)), "observed-cells")


def observed_scene(
    observation: object, geometry: str = "boxes", points: np.ndarray | None = None, reach: float = 0.0
) -> tuple[Scene | CellsScene, str]:
    """The geometry of an observation and where it came from: its ``scene`` (``"scene"``, truth
    sensing) when it has one, else its grid's occupied cells: with ``geometry = "octree"`` those
    within ``reach`` [m] of ``points`` as one octree (``"near cells"``), with ``"boxes"`` all of
    them as boxes (``"grid cells"``)."""
    scene = getattr(observation, "scene", None)
    if scene is not None:
        return scene, "scene"
    grid = observation.grid  # type: ignore[attr-defined]
    if geometry == "octree":
        assert points is not None
        return near_cells_scene(grid, points, reach), "near cells"
    return cell_scene(grid), "grid cells"
