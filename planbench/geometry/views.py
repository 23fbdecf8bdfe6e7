"""The cells of a grid a pinhole camera has seen to be free: those in its image, nearer to it
than what their pixel saw.

A depth pixel observes the pyramid of space its image area spans, from the optical centre up to
the range it measured. A cell counts as seen when its centre projects into a pixel and lies
nearer to the optical centre than that pixel's ``free`` length [m] (for a pixel that returned a
point: its range). This is the projective update of dense mapping (as nvblox integrates depth
images): every cell in view gets the pixel it falls in, at any range, where walking one thin ray
per pixel would leave cells between the rays unseen once a cell is smaller than a pixel's
footprint (beyond 2.3 m for 2 cm cells and the default camera's 0.5 degree pixels).

With numba (:mod:`planbench.runtime.backend`), one compiled loop over the cells; without it, the
same arithmetic in numpy, one slab of cells at a time. Both mark the same cells.

:func:`first_blocked` walks lines of sight the other way, from a camera to cells, and says what
each meets first: the arm's cells or occupied ones (:mod:`planbench.reactive.shadows`).
"""

from __future__ import annotations

import numpy as np

from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime import backend as _backend

__all__ = ["first_blocked", "mark_seen"]


def mark_seen(
    out: np.ndarray,
    lower: np.ndarray,
    resolution: float,
    origin: np.ndarray,
    axes: np.ndarray,
    pixel: float,
    width: int,
    height: int,
    free: np.ndarray,
    backend: str = "auto",
) -> np.ndarray:
    """Set ``out`` (a bool grid, cell ``(0, 0, 0)``'s corner at ``lower`` [m], cells of
    ``resolution`` [m]) where the camera at ``origin`` [m] saw free space (module docstring).

    ``axes``: rows forward, right and up (unit vectors); ``pixel``: a pixel's size at unit focal
    length; ``free``: the free length [m] of each of the ``height * width`` pixels, row by row
    from the top-left corner (0: nothing seen). Returns ``out``."""
    if out.dtype != np.bool_ or out.ndim != 3:
        raise ValueError(f"out must be a 3D bool array, got {out.dtype} {out.shape}")
    free = np.ascontiguousarray(free, dtype=np.float64)
    if free.shape != (int(width) * int(height),):
        raise ValueError(f"free must hold one length per pixel ({width * height}), got shape {free.shape}")
    lower = np.ascontiguousarray(lower, dtype=np.float64)
    origin = np.ascontiguousarray(origin, dtype=np.float64)
    axes = np.ascontiguousarray(axes, dtype=np.float64)
    args = (lower, float(resolution), origin, axes, float(pixel), int(width), int(height), free, out)
    if _backend.resolve(backend) == "numba":
        from planbench.geometry import _compiled  # on use: numba is optional and takes 0.15 s to import

        _compiled.mark_seen(*args)
    else:
        _mark_seen_numpy(*args)
    return out


def _mark_seen_numpy(
    lower: np.ndarray,
    resolution: float,
    origin: np.ndarray,
    axes: np.ndarray,
    pixel: float,
    width: int,
    height: int,
    free: np.ndarray,
    out: np.ndarray,
) -> None:
    """The compiled loop's arithmetic, a slab ``out[i]`` at a time."""
    n0, n1, n2 = out.shape
    (fx, fy, fz), (rx, ry, rz), (ux, uy, uz) = axes
    free2 = free * free
    vy = (lower[1] + (np.arange(n1) + 0.5) * resolution - origin[1])[:, None]
    vz = (lower[2] + (np.arange(n2) + 0.5) * resolution - origin[2])[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(n0):
            vx = lower[0] + (i + 0.5) * resolution - origin[0]
            z = vx * fx + vy * fy + vz * fz
            inv = 1.0 / (z * pixel)
            col = np.floor((vx * rx + vy * ry + vz * rz) * inv + width / 2.0)
            row = np.floor(height / 2.0 - (vx * ux + vy * uy + vz * uz) * inv)
            inside = (z > 0.0) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
            at = np.where(inside, row * width + col, 0).astype(np.int64)
            out[i] |= inside & (vx * vx + vy * vy + vz * vz <= free2[at])


def first_blocked(
    origin: np.ndarray,
    units: np.ndarray,
    steps: np.ndarray,
    step: float,
    grid: OccupancyGrid,
    arm: np.ndarray,
    occupied: np.ndarray,
    backend: str,
) -> np.ndarray:
    """Per line (unit direction ``units[n]`` from ``origin`` [m], sampled at ``k * step`` [m] for
    ``k = 1 .. steps[n]``) through ``grid``'s cells: 1 when its first sample in a cell of ``arm``
    or ``occupied`` (flat bool arrays of the grid's cells) is the arm's, 2 when occupied, -1 when
    none is (int8; :mod:`planbench.reactive.shadows`). Compiled with numba, or in numpy a slab of
    lines at a time: the same arithmetic, the same answers."""
    out = np.full(len(units), -1, dtype=np.int8)
    if not len(units):
        return out
    lower = np.ascontiguousarray(grid.origin, dtype=np.float64)
    shape = np.array(grid.shape, dtype=np.intp)
    res = float(grid.resolution)
    if _backend.resolve(backend) == "numba":
        from planbench.geometry import _compiled  # on use: numba is optional

        _compiled.first_blocked(
            origin, units, steps.astype(np.intp), float(step), lower, res, shape, arm, occupied, out
        )
        return out
    most = int(steps.max())
    if not most:
        return out
    s = np.arange(1, most + 1) * step  # [m] along the line
    for lo in range(0, len(units), 256):  # (lines, samples, 3) floats a slab at a time
        sl = slice(lo, lo + 256)
        ijk = np.floor(((origin + units[sl, None, :] * s[None, :, None]) - lower) / res).astype(np.intp)
        valid = np.all((ijk >= 0) & (ijk < shape), axis=2) & (np.arange(most)[None, :] < steps[sl, None])
        flat = np.ravel_multi_index(tuple(np.moveaxis(np.where(valid[..., None], ijk, 0), 2, 0)), grid.shape)
        hit_arm = valid & arm[flat]
        blocked = hit_arm | (valid & occupied[flat])
        k = np.argmax(blocked, axis=1)
        rows = np.arange(len(k))
        out[sl] = np.where(blocked[rows, k], np.where(hit_arm[rows, k], 1, 2), -1)
    return out
