"""Exact overlap of grid cells (axis-aligned cubes) with oriented boxes, for voxelisation.

The separating-axis theorem for two boxes: they are apart when their projections onto one of 15
axes do not overlap (the 3 grid axes, the box's 3 axes and their 9 cross products). Touching faces
do not count as overlap, so a cell that only shares a face with a box stays free.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cubes_overlap_boxes"]


def cubes_overlap_boxes(
    centres: np.ndarray, half: float, box_centres: np.ndarray, rotation: np.ndarray, extents: np.ndarray, tol: float
) -> np.ndarray:
    """Whether each axis-aligned cube (``centres`` (N, 3), half edge ``half`` [m]) overlaps, with
    interiors, the box at ``box_centres`` ((N, 3), pairwise, or one (3,)) with axes ``rotation``
    (columns) and half extents ``extents`` (3,) [m]; ``tol``: the relative margin under which a
    projection gap counts as touching (rounding of the centres)."""
    R = np.asarray(rotation, dtype=float)
    d = np.asarray(box_centres, dtype=float) - centres
    axes = [np.eye(3)[i] for i in range(3)] + [R[:, k] for k in range(3)]
    axes += [np.cross(np.eye(3)[i], R[:, k]) for i in range(3) for k in range(3)]
    separated = np.zeros(len(centres), dtype=bool)
    for axis in axes:
        if axis @ axis < 1e-20:  # parallel edges: the face axes already cover it
            continue
        radius = half * np.abs(axis).sum() + np.abs(axis @ R) @ extents
        separated |= np.abs(d @ axis) >= radius * (1.0 - tol)
    return ~separated
