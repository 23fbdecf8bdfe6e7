"""Trilinear sampling of a precomputed :class:`~planbench.field.full.MatrixField` at points.

The field is known at cell centres; a point takes the trilinear blend of the 8 centres around it
(``u = (p - origin) / resolution - 0.5``, corner ``floor(u)``, weights ``u - floor(u)``). Stored
cells beyond the array count as zero. With the default margin that is the true field (the field is
exactly zero more than ``support`` cells beyond the grid), so this sampler equals the lazy path at
every point in space; with ``margin=0`` it fades to zero over the last half cell of the grid.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from planbench.runtime import backend as _backend

if TYPE_CHECKING:
    from planbench.field.full import MatrixField

__all__ = ["sample_field", "field_sampler", "as_points"]

_CORNERS = np.array(list(np.ndindex(2, 2, 2)))  # (8, 3) offsets of the cell centres around a point


def as_points(points: np.ndarray) -> np.ndarray:
    """Points as a C-contiguous (N, 3) float64 array (a single point may be given as (3,))."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64))
    if pts.ndim == 1:
        pts = pts.reshape(1, -1)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array [m], got shape {np.shape(points)}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points must be finite")
    return pts


def sample_field(field: MatrixField, points: np.ndarray, backend: str = "auto") -> np.ndarray:
    """Field (N, 3) float64 at points (N, 3) [m] by trilinear interpolation."""
    pts = as_points(points)
    out = np.empty((len(pts), 3))
    if _backend.resolve(backend) == "numba":
        from planbench.field import _compiled  # on use: numba is optional and takes 0.15 s to import

        sample = _compiled.sample_points_scaled
        sample(field.components, field.origin, float(field.resolution), int(field.margin), 1.0, pts, out)
    else:
        out[:] = _sample_numpy(field, pts)
    return out


def field_sampler(
    field: MatrixField, points: np.ndarray, out: np.ndarray, scale: float = 1.0, backend: str = "auto"
) -> Callable[[], None]:
    """A function of no arguments that writes ``scale`` times the field at ``points`` (N, 3) [m]
    into ``out`` (N, 3) each time it is called: for a loop that moves the same points in place
    and samples them again (a planner's control points, every step).

    The compiled sampler is bound to these two arrays, so a call skips numba's per-call type
    checks as well as :func:`sample_field`'s checks and allocation: ``points`` must be a
    C-contiguous float64 (N, 3) array, ``out`` a writable float64 (N, 3) array (checked here,
    once), and the points finite when sampled."""
    if points.dtype != np.float64 or points.ndim != 2 or points.shape[1] != 3 or not points.flags.c_contiguous:
        raise ValueError(f"points must be a C-contiguous float64 (N, 3) array, got {points.dtype} {points.shape}")
    if out.dtype != np.float64 or out.shape != points.shape or not out.flags.writeable:
        raise ValueError(f"out must be a writable float64 array of shape {points.shape}, got {out.dtype} {out.shape}")
    if _backend.resolve(backend) == "numba":
        import numba  # imported with _compiled already; planbench.field imports numba on first use only

        args = (field.components, field.origin, float(field.resolution), int(field.margin), float(scale), points, out)
        from planbench.field import _compiled  # on use: numba is optional and takes 0.15 s to import

        sample = _compiled.sample_points_scaled
        return functools.partial(sample.compile(tuple(numba.typeof(a) for a in args)), *args)

    def sample_numpy() -> None:
        np.multiply(_sample_numpy(field, points), scale, out=out)

    return sample_numpy


def _sample_numpy(field: MatrixField, pts: np.ndarray) -> np.ndarray:
    comp = field.components
    shape = np.array(comp.shape[1:])
    u = (pts - field.origin) / field.resolution - 0.5 + field.margin
    base = np.floor(u)
    w = (u - base)[:, None, :]  # (N, 1, 3)
    idx = base.astype(np.int64)[:, None, :] + _CORNERS  # (N, 8, 3)
    ok = np.all((idx >= 0) & (idx < shape), axis=2)
    weight = np.prod(np.where(_CORNERS, w, 1.0 - w), axis=2) * ok  # (N, 8)
    idx = np.clip(idx, 0, shape - 1)
    values = comp[:, idx[..., 0], idx[..., 1], idx[..., 2]]  # (3, N, 8)
    return np.einsum("anc,nc->na", values, weight)  # type: ignore[no-any-return]
