"""The field's hot loops, compiled with numba (imported only when numba is installed).

Each function works on arrays whose cells beyond the grid are zero (the caller has subtracted the
``outside`` occupancy, see ``full.py``), in the arrays' own dtype. Compiled code is cached on disk
(``cache=True``), so only the first run on a machine pays the compile time.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["correlate_axis", "lazy_points", "lazy_points_serial", "sample_points", "sample_points_scaled"]


@njit(parallel=True, fastmath=True, cache=True)
def _planes(src, dst, k, sign):  # type: ignore[no-untyped-def]
    """Correlate (n0, m) along axis 0: the inner loops run over whole contiguous planes."""
    n0, m = src.shape
    c = (k.shape[0] - 1) // 2
    for i in prange(n0):
        k0 = k[c]
        for j in range(m):
            dst[i, j] = k0 * src[i, j]
        for t in range(1, c + 1):
            w = k[c + t]
            sw = sign * w
            hi = i + t
            lo = i - t
            if hi < n0 and lo >= 0:
                for j in range(m):
                    dst[i, j] += w * src[hi, j] + sw * src[lo, j]
            elif hi < n0:
                for j in range(m):
                    dst[i, j] += w * src[hi, j]
            elif lo >= 0:
                for j in range(m):
                    dst[i, j] += sw * src[lo, j]


@njit(parallel=True, fastmath=True, cache=True)
def _rows(src, dst, k, sign, i0, i1):  # type: ignore[no-untyped-def]
    """Correlate (n0, n1, n2) along axis 1 for the planes i0 <= i < i1 (the others are left as
    they are): the inner loops run over contiguous rows."""
    n0, n1, n2 = src.shape
    c = (k.shape[0] - 1) // 2
    for i in prange(i0, i1):
        k0 = k[c]
        for j in range(n1):
            for l in range(n2):
                dst[i, j, l] = k0 * src[i, j, l]
            for t in range(1, c + 1):
                w = k[c + t]
                sw = sign * w
                hi = j + t
                lo = j - t
                if hi < n1 and lo >= 0:
                    for l in range(n2):
                        dst[i, j, l] += w * src[i, hi, l] + sw * src[i, lo, l]
                elif hi < n1:
                    for l in range(n2):
                        dst[i, j, l] += w * src[i, hi, l]
                elif lo >= 0:
                    for l in range(n2):
                        dst[i, j, l] += sw * src[i, lo, l]


@njit(parallel=True, fastmath=True, cache=True)
def _lines(src, dst, k, sign):  # type: ignore[no-untyped-def]
    """Correlate (m, n) along its last (contiguous) axis: each line is copied into the middle of a
    zero-padded buffer, then one bounds-free sweep per tap pair."""
    m, n = src.shape
    c = (k.shape[0] - 1) // 2
    chunks = min(m, 256)
    for b in prange(chunks):
        buf = np.zeros(n + 2 * c, src.dtype)
        mid = buf[c : c + n]
        for r in range(b * m // chunks, (b + 1) * m // chunks):
            s = src[r]
            d = dst[r]
            k0 = k[c]
            for j in range(n):
                mid[j] = s[j]
                d[j] = k0 * s[j]
            for t in range(1, c + 1):
                w = k[c + t]
                sw = sign * w
                sp = buf[c + t : c + t + n]
                sm = buf[c - t : c - t + n]
                for j in range(n):
                    d[j] += w * sp[j] + sw * sm[j]


def correlate_axis(
    src: np.ndarray, dst: np.ndarray, k: np.ndarray, axis: int, sign: float, planes: tuple[int, int] | None = None
) -> None:
    """``dst = correlate1d(src, k, axis)`` with zeros beyond the ends; ``k`` symmetric (``sign``
    +1) or antisymmetric (-1) and in the arrays' dtype. ``src``, ``dst``: C-contiguous 3D.
    ``planes`` = (i0, i1) limits an axis-1 pass to those planes of axis 0."""
    n0, n1, n2 = src.shape
    s = src.dtype.type(sign)
    if axis == 0:
        _planes(src.reshape(n0, n1 * n2), dst.reshape(n0, n1 * n2), k, s)
    elif axis == 1:
        i0, i1 = planes if planes is not None else (0, n0)
        _rows(src, dst, k, s, i0, i1)
    else:
        _lines(src.reshape(n0 * n1, n2), dst.reshape(n0 * n1, n2), k, s)


@njit(parallel=True, fastmath=True, cache=True)
def _embed_lines(grid, outside, m, T, P, h, c):  # type: ignore[no-untyped-def]
    """First passes from the raw grid (n0, n1, n2) into arrays grown by ``m`` cells per side:
    ``h = T_z (G - outside)`` and ``c = P_z (G - outside)`` on the grid's (x, y) lines, each line
    read once. Lines of ``h`` and ``c`` outside the grid's (x, y) range are not written."""
    n0, n1, n2 = grid.shape
    ct = (T.shape[0] - 1) // 2
    cp = (P.shape[0] - 1) // 2
    pad = max(ct, cp)
    n = n2 + 2 * m  # output line length
    o = grid.dtype.type(outside)
    for i in prange(n0):
        buf = np.zeros(n + 2 * pad, grid.dtype)  # line of G - outside, zeros beyond the grid
        mid = buf[pad + m : pad + m + n2]
        for j in range(n1):
            row = grid[i, j]
            for q in range(n2):
                mid[q] = row[q] - o
            dh = h[i + m, j + m]
            dc = c[i + m, j + m]
            k0 = T[ct]
            centre = buf[pad : pad + n]
            for q in range(n):
                dh[q] = k0 * centre[q]
                dc[q] = 0.0
            for t in range(1, ct + 1):
                w = T[ct + t]
                sp = buf[pad + t : pad + t + n]
                sm = buf[pad - t : pad - t + n]
                for q in range(n):
                    dh[q] += w * (sp[q] + sm[q])
            for t in range(1, cp + 1):
                w = P[cp + t]
                sp = buf[pad + t : pad + t + n]
                sm = buf[pad - t : pad - t + n]
                for q in range(n):
                    dc[q] += w * (sp[q] - sm[q])


def field_from_grid(grid: np.ndarray, outside: float, m: int, P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The three components (3, n0 + 2m, n1 + 2m, n2 + 2m) of the field of ``grid`` (with
    ``outside`` beyond it), in the grid's dtype; ``P`` and ``T`` in that dtype too.

    Eight passes; the first two read the grid once and the two T_y passes skip the planes of
    axis 0 that are still zero (outside the grid, in the margin). Intermediates live in the output
    arrays until those are written, so only one temporary array is needed."""
    n0, n1, n2 = grid.shape
    shape = (n0 + 2 * m, n1 + 2 * m, n2 + 2 * m)
    out = np.zeros((3, *shape), dtype=grid.dtype)  # zero pages: unwritten lines cost nothing
    f_x, f_y, f_z = out[0], out[1], out[2]
    _embed_lines(grid, outside, m, T, P, f_y, f_z)  # f_y holds T_z G', f_z holds P_z G' for now
    tmp = np.zeros(shape, dtype=grid.dtype)
    grid_planes = (m, m + n0)
    correlate_axis(f_y, tmp, T, 1, 1.0, grid_planes)  # only the grid's planes are non-zero
    correlate_axis(tmp, f_x, P, 0, -1.0)  # F_x = P_x T_y T_z G'
    correlate_axis(f_y, tmp, T, 0, 1.0)
    correlate_axis(tmp, f_y, P, 1, -1.0)  # F_y = P_y T_x T_z G'
    tmp[:m] = 0.0
    tmp[m + n0 :] = 0.0
    correlate_axis(f_z, tmp, T, 1, 1.0, grid_planes)
    correlate_axis(tmp, f_z, T, 0, 1.0)  # F_z = T_x T_y P_z G'
    return out


@njit(cache=True, fastmath=True)
def _effective(k, w, out):  # type: ignore[no-untyped-def]
    """Blend a centred 1D kernel (length 2c+1) into ``out`` (length 2m+2, m >= c) for the two cell
    centres around a point: ``out[m + u] = (1 - w) k(u) + w k(u - 1)``, u = -m .. m+1."""
    m = (out.shape[0] - 2) // 2
    c = (k.shape[0] - 1) // 2
    for j in range(out.shape[0]):
        out[j] = 0.0
    for j in range(k.shape[0]):
        out[m - c + j] += (1.0 - w) * k[j]
        out[m - c + j + 1] += w * k[j]


@njit(cache=True, fastmath=True)
def _surface_value(grid, ix, iy, iz, o):  # type: ignore[no-untyped-def]
    """The surface pass (:mod:`planbench.field.surface`) at one cell: ``G (1 - min of its 6 face
    neighbours)``, neighbours beyond the grid holding ``o`` (``outside``)."""
    g = grid[ix, iy, iz]
    nx, ny, nz = grid.shape
    freest = grid[ix - 1, iy, iz] if ix > 0 else o
    freest = min(freest, grid[ix + 1, iy, iz] if ix + 1 < nx else o)
    freest = min(freest, grid[ix, iy - 1, iz] if iy > 0 else o)
    freest = min(freest, grid[ix, iy + 1, iz] if iy + 1 < ny else o)
    freest = min(freest, grid[ix, iy, iz - 1] if iz > 0 else o)
    freest = min(freest, grid[ix, iy, iz + 1] if iz + 1 < nz else o)
    return g * (1 - freest)


@njit(cache=True, fastmath=True)
def _lazy_point(grid, outside, origin, resolution, along, across, points, out, p, surface):  # type: ignore
    """The field at ``points[p]`` into ``out[p]``: the body of :func:`lazy_points` (shared by its
    parallel and serial drivers, so both compute the same numbers). ``surface``: each cell read
    through the surface pass (:func:`_surface_value`), so no pass over the whole grid is needed."""
    nx, ny, nz = grid.shape
    m = max(along.shape[0], across.shape[0]) // 2
    size = 2 * m + 2
    dt = grid.dtype.type
    o = dt(outside)
    base = np.empty(3, np.int64)
    P = np.empty((3, size), grid.dtype)
    T = np.empty((3, size), grid.dtype)
    for a in range(3):
        u = (points[p, a] - origin[a]) / resolution - 0.5
        f = math.floor(u)
        base[a] = np.int64(f) - m
        _effective(along, u - f, P[a])
        _effective(across, u - f, T[a])
    x0 = max(base[0], 0)
    x1 = min(base[0] + size, nx)
    y0 = max(base[1], 0)
    y1 = min(base[1] + size, ny)
    z0 = max(base[2], 0)
    z1 = min(base[2] + size, nz)
    ox = base[0]
    oy = base[1]
    oz = base[2]
    at = np.empty(size, grid.dtype)  # z-line weighted by T_y
    ap = np.empty(size, grid.dtype)  # z-line weighted by P_y
    fx = 0.0
    fy = 0.0
    fz = 0.0
    nzb = z1 - z0
    for ix in range(x0, x1):
        for j in range(size):
            at[j] = 0.0
            ap[j] = 0.0
        at_s = at[z0 - oz : z1 - oz]
        ap_s = ap[z0 - oz : z1 - oz]
        for iy in range(y0, y1):
            ty = T[1, iy - oy]
            py = P[1, iy - oy]
            row = grid[ix, iy, z0:z1]
            for j in range(nzb):
                g = row[j]
                if surface and g > 0:
                    g = _surface_value(grid, ix, iy, z0 + j, o)
                v = g - o
                at_s[j] += ty * v
                ap_s[j] += py * v
        tt = 0.0
        tp = 0.0
        pt = 0.0
        for j in range(size):
            tt += at[j] * T[2, j]
            tp += at[j] * P[2, j]
            pt += ap[j] * T[2, j]
        fx += P[0, ix - ox] * tt
        fy += T[0, ix - ox] * pt
        fz += T[0, ix - ox] * tp
    out[p, 0] = fx
    out[p, 1] = fy
    out[p, 2] = fz


@njit(parallel=True, cache=True, fastmath=True)
def lazy_points(grid, outside, origin, resolution, along, across, points, out, surface=False):  # type: ignore
    """Interpolated field at each point from the occupancy grid directly (see ``lazy.py``), the
    points shared out over numba's threads (:mod:`planbench.runtime.threads` decides when).

    The trilinear weights are folded into 1D kernels over the (2m+2)^3 block around the point, and
    the block is contracted one axis at a time: y with two rows of weights into two z-lines, then z
    and x by dot products. ``out`` (N, 3) float64 receives (F_x, F_y, F_z).
    """
    for p in prange(points.shape[0]):
        _lazy_point(grid, outside, origin, resolution, along, across, points, out, p, surface)


@njit(cache=True, fastmath=True)
def lazy_points_serial(grid, outside, origin, resolution, along, across, points, out, surface=False):  # type: ignore
    """:func:`lazy_points` on the calling thread only: no parallel region is entered, so a small
    call never waits for (or wakes) numba's thread pool."""
    for p in range(points.shape[0]):
        _lazy_point(grid, outside, origin, resolution, along, across, points, out, p, surface)


@njit(cache=True)
def sample_points(comp, origin, resolution, margin, points, out):  # type: ignore[no-untyped-def]
    """Trilinear interpolation of ``comp`` (3, mx, my, mz) at points (see ``interpolate.py``);
    stored cells beyond the array count as zero."""
    sample_points_scaled(comp, origin, resolution, margin, 1.0, points, out)


@njit(cache=True)
def sample_points_scaled(comp, origin, resolution, margin, scale, points, out):  # type: ignore[no-untyped-def]
    """:func:`sample_points` times ``scale`` (a gain applied in the same pass)."""
    mx, my, mz = comp.shape[1], comp.shape[2], comp.shape[3]
    for p in range(points.shape[0]):
        u0 = (points[p, 0] - origin[0]) / resolution - 0.5 + margin
        u1 = (points[p, 1] - origin[1]) / resolution - 0.5 + margin
        u2 = (points[p, 2] - origin[2]) / resolution - 0.5 + margin
        b0, b1, b2 = math.floor(u0), math.floor(u1), math.floor(u2)
        i0, i1, i2 = np.int64(b0), np.int64(b1), np.int64(b2)
        w0, w1, w2 = u0 - b0, u1 - b1, u2 - b2
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for dx in range(2):
            ix = i0 + dx
            if ix < 0 or ix >= mx:
                continue
            wx = w0 if dx else 1.0 - w0
            for dy in range(2):
                iy = i1 + dy
                if iy < 0 or iy >= my:
                    continue
                wxy = wx * (w1 if dy else 1.0 - w1)
                for dz in range(2):
                    iz = i2 + dz
                    if iz < 0 or iz >= mz:
                        continue
                    c = wxy * (w2 if dz else 1.0 - w2)
                    f0 += c * comp[0, ix, iy, iz]
                    f1 += c * comp[1, ix, iy, iz]
                    f2 += c * comp[2, ix, iy, iz]
        out[p, 0] = f0 * scale
        out[p, 1] = f1 * scale
        out[p, 2] = f2 * scale
