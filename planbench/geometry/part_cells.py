"""The grid cells that points fixed to rigid parts fall in: a robot's sample points, its links moving.

Points are given once in their part's frame; each call places the parts (a rotation and a
translation each) and visits the cell of every point. Two questions are asked of a grid this way
at every control tick, so the loop is compiled when numba is there (:mod:`planbench.runtime.backend`):
which cells the points fill (:meth:`PartPoints.mark`), and whether any point lies in a cell a mask
says nothing of (:meth:`PartPoints.any_outside`, which stops at the first). Without numba the same
arithmetic, in the same order, runs in numpy: both visit the same cells.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planbench.runtime import backend as _backend

__all__ = ["PartPoints"]


def _sorted_unique(values: np.ndarray) -> np.ndarray:
    """``np.unique`` of a 1-D integer array by a sort and a comparison of neighbours: 0.2 ms where
    ``np.unique`` (numpy 2.3's hash, then a sort) takes 0.7 ms on the Panda's 30,000 body points."""
    values = np.sort(values)
    if len(values) < 2:
        return values
    first = np.empty(len(values), dtype=bool)
    first[0] = True
    np.not_equal(values[1:], values[:-1], out=first[1:])
    return values[first]


class PartPoints:
    """Points [m] fixed to rigid parts, in each part's own frame."""

    def __init__(self, parts: Sequence[np.ndarray], backend: str = "auto") -> None:
        self.n_parts = len(parts)
        pieces = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in parts]
        self.local = np.ascontiguousarray(np.concatenate(pieces) if pieces else np.zeros((0, 3)))
        self.part = np.repeat(np.arange(len(pieces), dtype=np.int64), [len(p) for p in pieces])
        self.backend = _backend.resolve(backend)

    def mark(
        self, out: np.ndarray, lower: np.ndarray, resolution: float, rotations: np.ndarray, translations: np.ndarray
    ) -> np.ndarray:
        """Set the cells of ``out`` (a bool grid, cell ``(0, 0, 0)``'s corner at ``lower`` [m]) that
        hold a point, the parts placed by ``rotations`` (P, 3, 3) and ``translations`` (P, 3) [m];
        points outside the grid are left out. Returns ``out``."""
        self._visit(out, lower, resolution, rotations, translations, stop_at_false=False)
        return out

    def any_outside(
        self, mask: np.ndarray, lower: np.ndarray, resolution: float, rotations: np.ndarray, translations: np.ndarray
    ) -> bool:
        """Whether a point, the parts so placed, lies in a cell of the grid where ``mask`` (bool)
        is False (points outside the grid do not count)."""
        return self._visit(mask, lower, resolution, rotations, translations, stop_at_false=True)

    def cells(
        self,
        shape: tuple[int, ...],
        lower: np.ndarray,
        resolution: float,
        rotations: np.ndarray,
        translations: np.ndarray,
    ) -> np.ndarray:
        """Flat indices (sorted, each once) of the cells of a grid of ``shape`` that hold a point:
        the cells :meth:`mark` sets, found without a grid-sized array (marking then scanning a
        142^3 grid costs milliseconds; a few thousand points, a fraction of one)."""
        rotations = np.ascontiguousarray(rotations, dtype=np.float64).reshape(self.n_parts, 3, 3)
        translations = np.ascontiguousarray(translations, dtype=np.float64).reshape(self.n_parts, 3)
        lower = np.ascontiguousarray(lower, dtype=np.float64)
        size = np.array(shape, dtype=np.int64)
        args = (self.local, self.part, rotations, translations, lower, float(resolution), size)
        if self.backend == "numba":
            from planbench.geometry import _compiled  # on use: numba is optional

            out = np.empty(len(self.local), dtype=np.int64)
            return _sorted_unique(out[: _compiled.part_cell_indices(*args, out)])
        return _sorted_unique(_flat_cells(*args))

    def _visit(
        self,
        grid: np.ndarray,
        lower: np.ndarray,
        resolution: float,
        rotations: np.ndarray,
        translations: np.ndarray,
        stop_at_false: bool,
    ) -> bool:
        if grid.dtype != np.bool_ or grid.ndim != 3 or not grid.flags.c_contiguous:
            raise ValueError(f"the grid must be a C-contiguous 3D bool array, got {grid.dtype} {grid.shape}")
        rotations = np.ascontiguousarray(rotations, dtype=np.float64).reshape(self.n_parts, 3, 3)
        translations = np.ascontiguousarray(translations, dtype=np.float64).reshape(self.n_parts, 3)
        lower = np.ascontiguousarray(lower, dtype=np.float64)
        shape = np.array(grid.shape, dtype=np.int64)
        flat = grid.reshape(-1)
        args = (self.local, self.part, rotations, translations, lower, float(resolution), shape, flat, stop_at_false)
        if self.backend == "numba":
            from planbench.geometry import _compiled  # on use: numba is optional

            return bool(_compiled.part_cells(*args, flat))
        return _part_cells_numpy(*args, flat)


def _part_cells_numpy(
    local: np.ndarray,
    part: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    lower: np.ndarray,
    resolution: float,
    shape: np.ndarray,
    mask: np.ndarray,
    stop_at_false: bool,
    out: np.ndarray,
) -> bool:
    """The compiled loop's arithmetic for all points at once."""
    flat = _flat_cells(local, part, rotations, translations, lower, resolution, shape)
    if stop_at_false:
        return not bool(mask[flat].all())
    out[flat] = True
    return False


def _flat_cells(
    local: np.ndarray,
    part: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    lower: np.ndarray,
    resolution: float,
    shape: np.ndarray,
) -> np.ndarray:
    """The flat index of each point's cell, points outside the grid left out (the compiled loop's
    arithmetic, in its order)."""
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    R, t = rotations[part], translations[part]
    inv = 1.0 / resolution
    cells = []
    for a in range(3):
        w = R[:, a, 0] * x + R[:, a, 1] * y + R[:, a, 2] * z + t[:, a]
        cells.append(np.floor((w - lower[a]) * inv).astype(np.int64))
    i, j, k = cells
    inside = (i >= 0) & (i < shape[0]) & (j >= 0) & (j < shape[1]) & (k >= 0) & (k < shape[2])
    return ((i * shape[1] + j) * shape[2] + k)[inside]
