"""The camera-view marking of :mod:`planbench.geometry.views`, compiled with numba (imported only
when numba is installed). The same arithmetic, in the same order, as the numpy implementation
there: both mark the same cells. No ``fastmath``: the two must agree on every rounding.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["first_blocked", "mark_seen"]


@njit(cache=True)
def mark_seen(lower, resolution, origin, axes, pixel, width, height, free, out):  # type: ignore[no-untyped-def]
    """Set ``out[i, j, k]`` where the cell's centre is in the camera's image and nearer to its
    optical centre than its pixel's ``free`` length (module docstring of ``views``)."""
    n0, n1, n2 = out.shape
    fx, fy, fz = axes[0, 0], axes[0, 1], axes[0, 2]  # forward
    rx, ry, rz = axes[1, 0], axes[1, 1], axes[1, 2]  # right
    ux, uy, uz = axes[2, 0], axes[2, 1], axes[2, 2]  # up
    half_w, half_h = width / 2.0, height / 2.0
    free2 = free * free
    vz = np.empty(n2)
    for k in range(n2):
        vz[k] = lower[2] + (k + 0.5) * resolution - origin[2]
    zf, zr, zu, zz = vz * fz, vz * rz, vz * uz, vz * vz  # the last terms of the sums below, per k
    for i in range(n0):
        vx = lower[0] + (i + 0.5) * resolution - origin[0]
        for j in range(n1):
            vy = lower[1] + (j + 0.5) * resolution - origin[1]
            af, ar, au, aa = vx * fx + vy * fy, vx * rx + vy * ry, vx * ux + vy * uy, vx * vx + vy * vy
            for k in range(n2):
                z = af + zf[k]
                if not z > 0.0:
                    continue
                inv = 1.0 / (z * pixel)
                col = math.floor((ar + zr[k]) * inv + half_w)
                row = math.floor(half_h - (au + zu[k]) * inv)
                if col < 0 or col >= width or row < 0 or row >= height:
                    continue
                if aa + zz[k] <= free2[row * width + col]:
                    out[i, j, k] = True


@njit(cache=True, inline="always")
def _point_cell(local, part, rotations, translations, lower, inv, shape, n):  # type: ignore[no-untyped-def]
    """The flat index of the cell of point ``local[n]`` placed by its part's rotation and
    translation, or -1 when it lies outside the grid of ``shape`` (cells of ``1 / inv`` m)."""
    p = part[n]
    x, y, z = local[n, 0], local[n, 1], local[n, 2]
    wx = rotations[p, 0, 0] * x + rotations[p, 0, 1] * y + rotations[p, 0, 2] * z + translations[p, 0]
    wy = rotations[p, 1, 0] * x + rotations[p, 1, 1] * y + rotations[p, 1, 2] * z + translations[p, 1]
    wz = rotations[p, 2, 0] * x + rotations[p, 2, 1] * y + rotations[p, 2, 2] * z + translations[p, 2]
    i = math.floor((wx - lower[0]) * inv)
    j = math.floor((wy - lower[1]) * inv)
    k = math.floor((wz - lower[2]) * inv)
    if i < 0 or i >= shape[0] or j < 0 or j >= shape[1] or k < 0 or k >= shape[2]:
        return -1
    return (i * shape[1] + j) * shape[2] + k


@njit(cache=True)
def part_cells(local, part, rotations, translations, lower, resolution, shape, mask, stop_at_false, out):  # type: ignore[no-untyped-def]
    """Visit the cell of each point ``local[n]`` of part ``part[n]`` placed by its rotation and
    translation (module docstring of ``part_cells``): set it in ``out`` (flat), or with
    ``stop_at_false`` return True at the first whose cell is False in ``mask`` (flat)."""
    inv = 1.0 / resolution
    for n in range(local.shape[0]):
        flat = _point_cell(local, part, rotations, translations, lower, inv, shape, n)
        if flat < 0:
            continue
        if stop_at_false:
            if not mask[flat]:
                return True
        else:
            out[flat] = True
    return False


@njit(cache=True)
def part_cell_indices(local, part, rotations, translations, lower, resolution, shape, out):  # type: ignore[no-untyped-def]
    """Write the flat index of each point's cell into ``out`` (as :func:`part_cells` visits them,
    points outside the grid left out); return how many were written."""
    inv = 1.0 / resolution
    m = 0
    for n in range(local.shape[0]):
        flat = _point_cell(local, part, rotations, translations, lower, inv, shape, n)
        if flat < 0:
            continue
        out[m] = flat
        m += 1
    return m


@njit(cache=True)
def fuse_free(seen, hit, log_odds, known, miss, lowest):  # type: ignore[no-untyped-def]
    """The map's update of the cells a frame saw free (module docstring of ``occupancy_map``), all
    arrays flat: a seen cell becomes known, and unless it was hit, its log-odds drop by ``miss``
    (negative) down to ``lowest``."""
    for n in range(seen.shape[0]):
        if seen[n]:
            known[n] = True
            if not hit[n]:
                value = log_odds[n] + miss
                log_odds[n] = value if value > lowest else lowest


@njit(cache=True)
def above(log_odds, threshold, out):  # type: ignore[no-untyped-def]
    """``out[n] = 1.0`` where ``log_odds[n] > threshold``, else 0.0 (flat arrays)."""
    for n in range(log_odds.shape[0]):
        out[n] = 1.0 if log_odds[n] > threshold else 0.0


@njit(cache=True)
def first_blocked(origin, units, steps, step, lower, resolution, shape, arm, occupied, out):  # type: ignore[no-untyped-def]
    """For each line ``n`` from ``origin`` along ``units[n]``, sampled at ``k * step`` for ``k = 1
    .. steps[n]``: 1 when the first sample in a marked cell is in ``arm``, 2 when in ``occupied``
    (flat bool grids of ``shape``), else -1 (``planbench.reactive.shadows``; the arm first where a
    cell is both)."""
    n0, n1, n2 = shape[0], shape[1], shape[2]
    for n in range(units.shape[0]):
        out[n] = -1
        for k in range(1, steps[n] + 1):
            s = k * step
            i = math.floor(((origin[0] + units[n, 0] * s) - lower[0]) / resolution)
            j = math.floor(((origin[1] + units[n, 1] * s) - lower[1]) / resolution)
            m = math.floor(((origin[2] + units[n, 2] * s) - lower[2]) / resolution)
            if i < 0 or j < 0 or m < 0 or i >= n0 or j >= n1 or m >= n2:
                continue
            flat = (i * n1 + j) * n2 + m
            if arm[flat]:
                out[n] = 1
                break
            if occupied[flat]:
                out[n] = 2
                break
