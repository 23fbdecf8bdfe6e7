"""The calibrated field's point sums, compiled with numba (imported only when numba is installed).

See :mod:`planbench.field.calibrated`: at each point, the Gaussian-weighted occupancy sum ``S`` and
its gradient, over the cube of ``2 half + 1`` cells around the point's nearest cell centre (cells
beyond the grid hold ``outside``). Compiled code is cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["gauss_points", "gauss_points_serial"]


@njit(cache=True, fastmath=True)
def _gauss_point(grid, outside, origin, resolution, sigma, half, points, out, p):  # type: ignore[no-untyped-def]
    """``out[p] = (S, dS/dx, dS/dy, dS/dz)`` at ``points[p]``: one 1D Gaussian and its derivative
    per axis at the point's exact offsets, contracted z, then y, then x."""
    nx, ny, nz = grid.shape
    n = 2 * half + 1
    w = np.empty((3, n))
    dw = np.empty((3, n))
    base = np.empty(3, np.int64)
    inv = 1.0 / (2.0 * sigma * sigma)
    inv_s2 = 1.0 / (sigma * sigma)
    for a in range(3):
        u = (points[p, a] - origin[a]) / resolution - 0.5  # continuous cell index of the point
        b = np.int64(math.floor(u + 0.5)) - half
        base[a] = b
        for j in range(n):
            off = (b + j - u) * resolution  # cell centre minus point [m]
            e = math.exp(-off * off * inv)
            w[a, j] = e
            dw[a, j] = off * inv_s2 * e
    o = outside
    s = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for i in range(n):
        ix = base[0] + i
        inx = 0 <= ix < nx
        if not inx and o == 0.0:
            continue
        a_w = 0.0  # sum over y, z of G w_y w_z
        a_dy = 0.0  # G dw_y w_z
        a_dz = 0.0  # G w_y dw_z
        for j in range(n):
            iy = base[1] + j
            iny = inx and 0 <= iy < ny
            if not iny and o == 0.0:
                continue
            zw = 0.0
            zd = 0.0
            for k in range(n):
                iz = base[2] + k
                g = grid[ix, iy, iz] if (iny and 0 <= iz < nz) else o
                if g != 0.0:
                    zw += g * w[2, k]
                    zd += g * dw[2, k]
            a_w += w[1, j] * zw
            a_dy += dw[1, j] * zw
            a_dz += w[1, j] * zd
        s += w[0, i] * a_w
        sx += dw[0, i] * a_w
        sy += w[0, i] * a_dy
        sz += w[0, i] * a_dz
    out[p, 0] = s
    out[p, 1] = sx
    out[p, 2] = sy
    out[p, 3] = sz


@njit(parallel=True, cache=True, fastmath=True)
def gauss_points(grid, outside, origin, resolution, sigma, half, points, out):  # type: ignore[no-untyped-def]
    """:func:`_gauss_point` for every point, shared out over numba's threads."""
    for p in prange(points.shape[0]):
        _gauss_point(grid, outside, origin, resolution, sigma, half, points, out, p)


@njit(cache=True, fastmath=True)
def gauss_points_serial(grid, outside, origin, resolution, sigma, half, points, out):  # type: ignore[no-untyped-def]
    """:func:`gauss_points` on the calling thread (a planner's few dozen control points)."""
    for p in range(points.shape[0]):
        _gauss_point(grid, outside, origin, resolution, sigma, half, points, out, p)
