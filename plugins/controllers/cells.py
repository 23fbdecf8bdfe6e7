"""An observed grid's occupied cells as box obstacles, for controllers that measure distances.

``distance-field`` and ``matrix-field-qp`` measure exact distances (coal) to geometry. With truth
sensing the observation carries the scene; a depth grid does not, so its occupied cells become the
geometry: merged greedily into few boxes whose union is exactly those cells
(:func:`planbench.geometry.occupancy.merge_cells`, which the OMPL planners' grid checker uses too).
"""

from __future__ import annotations

import numpy as np

from planbench.geometry.occupancy import OccupancyGrid, merge_cells
from planbench.scene import Obstacle, Scene
from planbench_plugins.controllers.crop import occupied_part

__all__ = ["cell_boxes", "cell_scene", "observed_scene"]


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


def observed_scene(observation: object) -> tuple[Scene, str]:
    """The geometry of an observation and where it came from: its ``scene`` (``"scene"``, truth
    sensing) when it has one, else its grid's occupied cells as boxes (``"grid cells"``)."""
    scene = getattr(observation, "scene", None)
    if scene is not None:
        return scene, "scene"
    return cell_scene(observation.grid), "grid cells"  # type: ignore[attr-defined]
