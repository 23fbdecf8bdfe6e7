"""Slow, obviously-correct references for the field: used by the tests and the benchmark.

- :func:`window_sums`: ``F_a(i) = sum_u G(i + u) K_a(u)`` at given cells by explicit window
  multiply-and-sum on a grid padded with ``outside`` (no separability, no zero-sum trick).
- :func:`brute_force_field`: trilinear blend of :func:`window_sums` at the 8 cells around points.
- :func:`dense_field`: ``scipy.ndimage.correlate`` with the dense 3D kernels (O(N L W H)).
- :func:`fft_field`: the same correlation by FFT (``scipy.fft``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import DTypeLike
from scipy import fft
from scipy.ndimage import correlate

from planbench.field.kernels import Kernels
from planbench.geometry.occupancy import OccupancyGrid

__all__ = ["window_sums", "brute_force_field", "dense_field", "fft_field"]


def window_sums(grid: OccupancyGrid, kernels: Kernels, cells: np.ndarray) -> np.ndarray:
    """Field (M, 3) at integer cells (M, 3) (which may lie outside the grid)."""
    cells = np.atleast_2d(np.asarray(cells, dtype=np.int64))
    m = kernels.support
    lo = cells.min(axis=0) - m
    hi = cells.max(axis=0) + m + 1
    # A padded copy of G covering every window: grid cells where they exist, `outside` elsewhere.
    pad_lo = np.maximum(0, -lo)
    pad_hi = np.maximum(0, hi - np.array(grid.shape))
    padded = np.pad(
        grid.data.astype(np.float64),
        list(zip(pad_lo, pad_hi, strict=True)),
        mode="constant",
        constant_values=grid.outside,
    )
    shift = pad_lo
    dense = [_centred3(kernels.dense(a), m) for a in range(3)]
    out = np.empty((len(cells), 3))
    for n, c in enumerate(cells):
        s = c - m + shift
        window = padded[s[0] : s[0] + 2 * m + 1, s[1] : s[1] + 2 * m + 1, s[2] : s[2] + 2 * m + 1]
        out[n] = [np.sum(window * k) for k in dense]
    return out


def brute_force_field(grid: OccupancyGrid, kernels: Kernels, points: np.ndarray) -> np.ndarray:
    """Field (N, 3) at points (N, 3) [m]: window sums at the 8 surrounding cell centres, blended
    trilinearly."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    u = (pts - grid.origin) / grid.resolution - 0.5
    base = np.floor(u).astype(np.int64)
    w = u - np.floor(u)
    out = np.zeros((len(pts), 3))
    for corner in np.ndindex(2, 2, 2):
        c = np.array(corner)
        weight = np.prod(np.where(c, w, 1.0 - w), axis=1)
        out += weight[:, None] * window_sums(grid, kernels, base + c)
    return out


def dense_field(grid: OccupancyGrid, kernels: Kernels, components: tuple[int, ...] = (0, 1, 2)) -> np.ndarray:
    """Field (len(components), nx, ny, nz) on the grid's cells by dense 3D correlation."""
    return np.stack([correlate(grid.data, kernels.dense(a), mode="constant", cval=grid.outside) for a in components])


def fft_field(grid: OccupancyGrid, kernels: Kernels, dtype: DTypeLike = np.float64, workers: int = -1) -> np.ndarray:
    """Field (3, nx, ny, nz) on the grid's cells by FFT: one forward transform of ``G - outside``
    (zero-padded so nothing wraps around), one per kernel, and three inverse transforms."""
    g = (grid.data - grid.outside).astype(dtype)
    m = kernels.support
    shape = [fft.next_fast_len(n + 2 * m, real=True) for n in g.shape]
    g_hat = fft.rfftn(g, shape, workers=workers)
    out = np.empty((3, *g.shape), dtype=dtype)
    for a in range(3):
        k = kernels.dense(a).astype(dtype)
        # Correlation is convolution with the flipped kernel, shifted by the kernel's half size.
        conv = fft.irfftn(g_hat * fft.rfftn(k[::-1, ::-1, ::-1], shape, workers=workers), shape, workers=workers)
        h = [(n - 1) // 2 for n in k.shape]
        out[a] = conv[h[0] : h[0] + g.shape[0], h[1] : h[1] + g.shape[1], h[2] : h[2] + g.shape[2]]
    return out


def _centred3(k: np.ndarray, m: int) -> np.ndarray:
    """Zero-pad a centred 3D kernel to (2m+1)^3."""
    pads = [((2 * m + 1 - n) // 2,) * 2 for n in k.shape]
    return np.pad(k, pads)
