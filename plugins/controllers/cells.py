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

__all__ = ["cell_scene", "observed_scene"]


def cell_scene(grid: OccupancyGrid, threshold: float = 0.5) -> Scene:
    """The cells of ``grid`` with occupancy ``>= threshold`` as a scene of boxes (empty when none)."""
    part = occupied_part(grid)  # the merging visits every column: only those of the occupied block
    occupied = None if part is None else np.asarray(part.data) >= threshold
    if part is None or occupied is None or not occupied.any():
        return Scene(name="observed-cells")
    res = part.resolution
    obstacles = []
    for k, (lo_idx, hi_idx) in enumerate(merge_cells(occupied)):
        lo = part.origin + np.asarray(lo_idx) * res
        size = (np.asarray(hi_idx) - np.asarray(lo_idx)) * res
        centre = lo + 0.5 * size
        obstacles.append(Obstacle(f"cells-{k}", "box", position=tuple(centre), size=tuple(size)))
    return Scene(tuple(obstacles), name="observed-cells")


def observed_scene(observation: object) -> tuple[Scene, str]:
    """The geometry of an observation and where it came from: its ``scene`` (``"scene"``, truth
    sensing) when it has one, else its grid's occupied cells as boxes (``"grid cells"``)."""
    scene = getattr(observation, "scene", None)
    if scene is not None:
        return scene, "scene"
    return cell_scene(observation.grid), "grid cells"  # type: ignore[attr-defined]
