"""Lazy (point) evaluation of the matrix field, straight from the occupancy grid.

For a grid that changes every control tick, computing the whole field is waste: a planner needs
the field at a few dozen control points. At a point ``p`` this takes the window sums
``F_a(i) = sum_u (G(i + u) - outside) K_a(u)`` at the 8 cell centres around ``p`` and blends them
trilinearly (the same rule as :mod:`planbench.field.interpolate`). Trilinear blending is linear,
so it is folded into 1D kernels of one more cell (``(1 - w) k(u) + w k(u - 1)``) and the
(support * 2 + 2)^3 block around the point is contracted one axis at a time: about ``2 S^3``
multiply-adds per point for a block of ``S`` cells a side, not ``8 * 3 * L W H``.

Cells beyond the grid hold ``outside``; as the kernels sum to zero they contribute nothing once
``outside`` is subtracted, so the result equals the full field with its default margin, at every
point in space (far from the grid it is exactly zero).

With numba, a call that reads at most :data:`~planbench.runtime.threads.SERIAL_MAX_CELLS` grid cells
(a planner's few dozen control points) runs on the calling thread; larger ones share the points
out over numba's threads. Both give the same numbers (to rounding).
"""

from __future__ import annotations

import numpy as np

from planbench.field.interpolate import as_points
from planbench.field.kernels import Kernels
from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime import backend as _backend
from planbench.runtime.threads import serial_lazy

__all__ = ["lazy_field"]

_CHUNK = 64  # points per numpy block gather (memory: _CHUNK * S^3 values)


def lazy_field(
    grid: OccupancyGrid, kernels: Kernels, points: np.ndarray, backend: str = "auto", surface: bool = False
) -> np.ndarray:
    """Field (N, 3) float64 at points (N, 3) [m], computed from ``grid`` without a full pass.

    Works in the grid's dtype (float32 grids are summed in float32). ``surface``: the field of
    :func:`~planbench.field.surface.surface_grid` of ``grid``, each cell read through the surface
    pass (its 6 neighbours looked at only where it is occupied): no pass over the grid either, for
    grids that change every frame.
    """
    kernels.check_resolution(grid.resolution)
    pts = as_points(points)
    out = np.empty((len(pts), 3))
    data = np.ascontiguousarray(grid.data)
    if _backend.resolve(backend) == "numba":
        along, across = kernels.factors(data.dtype)
        from planbench.field import _compiled  # on use: numba is optional and takes 0.15 s to import

        compiled = _compiled
        kernel = (
            compiled.lazy_points_serial if serial_lazy(len(pts), kernels.support) else compiled.lazy_points
        )  # small calls stay on this thread (see .threads)
        kernel(data, grid.outside, grid.origin, grid.resolution, along, across, pts, out, surface)
        return out
    if surface:  # numpy: the whole pass once (the compiled kernel reads surfaces cell by cell)
        from planbench.field.surface import surface_grid

        grid = surface_grid(grid)
        data = np.ascontiguousarray(grid.data)
    for start in range(0, len(pts), _CHUNK):
        sl = slice(start, start + _CHUNK)
        out[sl] = _lazy_numpy(data, grid, kernels, pts[sl])
    return out


def _lazy_numpy(data: np.ndarray, grid: OccupancyGrid, kernels: Kernels, pts: np.ndarray) -> np.ndarray:
    m = kernels.support
    u = (pts - grid.origin) / grid.resolution - 0.5
    f = np.floor(u)
    w = (u - f)[:, :, None]  # (N, 3, 1)
    cells = f.astype(np.int64)[:, :, None] - m + np.arange(2 * m + 2)  # (N, 3, S) block indices
    inside = (cells >= 0) & (cells < np.array(grid.shape)[None, :, None])
    P, T = (_blend(_centred(k, m), w) * inside for k in (kernels.along, kernels.across))
    idx = np.clip(cells, 0, np.array(grid.shape)[None, :, None] - 1)
    block = data[idx[:, 0, :, None, None], idx[:, 1, None, :, None], idx[:, 2, None, None, :]]
    block = block - block.dtype.type(grid.outside)  # (N, S, S, S); out-of-grid weights are 0
    zt = np.einsum("nijk,nk->nij", block, T[:, 2])
    zp = np.einsum("nijk,nk->nij", block, P[:, 2])
    fx = np.einsum("nij,ni,nj->n", zt, P[:, 0], T[:, 1])
    fy = np.einsum("nij,ni,nj->n", zt, T[:, 0], P[:, 1])
    fz = np.einsum("nij,ni,nj->n", zp, T[:, 0], T[:, 1])
    return np.stack([fx, fy, fz], axis=1)


def _centred(k: np.ndarray, m: int) -> np.ndarray:
    """Zero-pad a centred odd kernel to 2m+1 cells."""
    c = (len(k) - 1) // 2
    return np.pad(k, (m - c, m - c))


def _blend(k: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, 3, 2m+2): ``(1 - w) k(u) + w k(u - 1)`` for u = -m .. m+1."""
    zero = np.zeros(1)
    return (1.0 - w) * np.concatenate([k, zero]) + w * np.concatenate([zero, k])
