"""The full matrix field over a whole grid by separable 1D passes (docs/method.md, section 3).

``F_a = G (correlate) K_a`` for a in x, y, z, with ``G`` padded by the grid's ``outside``
occupancy. The kernels sum to zero (the profile is antisymmetric), so the field of a uniform
occupancy is zero and ``F(G) = F(G - outside)``: the passes correlate ``G - outside`` with zeros
beyond the grid, which honours ``outside`` exactly without carrying a padding value from pass to
pass. Eight 1D passes give the three components (the taper passes are shared)::

    H = T_z G            F_x = P_x T_y H      F_y = P_y T_x H      F_z = T_x T_y P_z G

With numba (``backend="numba"``, the default when it is installed) the passes are compiled loops
over contiguous planes, rows and lines, run on all cores; the first two read the grid once and
write straight into the grown arrays, and the intermediates live in the output arrays. Without
numba each pass is ``scipy.ndimage.correlate1d`` (6-15x slower at 128^3, same numbers).

``margin`` cells of field are also stored on every side of the grid. With the default margin (the
kernels' support) the stored array covers every cell where the field can be non-zero, so sampling
it (:meth:`MatrixField.sample`) gives the same numbers as :func:`~planbench.field.lazy.lazy_field`
everywhere, inside and outside the grid. ``margin=0`` stores the grid's cells only (cheaper); the
field within ``support`` cells beyond the grid is then sampled as zero, an approximation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import DTypeLike

from planbench.errors import InvalidConfigError
from planbench.field.interpolate import sample_field
from planbench.field.kernels import Kernels
from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime import backend as _backend

__all__ = ["MatrixField", "full_field", "correlate_separable"]

DTYPES = (np.float32, np.float64)


@dataclass(frozen=True, eq=False)
class MatrixField:
    """The three field components at cell centres of a grid grown by ``margin`` cells per side.

    ``components[a, i, j, k]`` is ``F_a`` at grid cell ``(i - margin, j - margin, k - margin)``,
    i.e. at ``origin + (index - margin + 0.5) * resolution``. ``origin`` [m] is the grid's corner,
    ``resolution`` [m/cell]. ``exact`` tells whether the margin covers the kernels' support (then
    the field beyond the stored cells is exactly zero). The array is read-only.
    """

    components: np.ndarray
    origin: np.ndarray
    resolution: float
    margin: int
    exact: bool

    def sample(self, points: np.ndarray, backend: str = "auto") -> np.ndarray:
        """Trilinearly interpolated field (N, 3) [field units] at points (N, 3) [m]."""
        return sample_field(self, points, backend=backend)

    @property
    def grid_view(self) -> np.ndarray:
        """(3, nx, ny, nz) view of the components on the grid's own cells."""
        m = self.margin
        if m == 0:
            return self.components
        return self.components[:, m:-m, m:-m, m:-m]


def full_field(
    grid: OccupancyGrid,
    kernels: Kernels,
    dtype: DTypeLike = np.float32,
    margin: int | None = None,
    backend: str = "auto",
) -> MatrixField:
    """The matrix field of ``grid`` for ``kernels``, computed in ``dtype`` (float32 or float64).

    ``margin``: cells of field stored beyond the grid on each side; ``None`` = ``kernels.support``
    (exact sampling everywhere, see module docstring). ``backend``: "auto", "numba" or "numpy".
    """
    dt = np.dtype(dtype)
    if dt not in [np.dtype(d) for d in DTYPES]:
        raise InvalidConfigError(f"field dtype must be float32 or float64, got {dt}")
    kernels.check_resolution(grid.resolution)
    m = kernels.support if margin is None else int(margin)
    if m < 0:
        raise InvalidConfigError(f"margin must be >= 0 cells, got {margin}")
    if _backend.resolve(backend) == "numba":
        P, T = kernels.factors(dt)
        data = np.ascontiguousarray(grid.data, dtype=dt)
        from planbench.field import _compiled  # on use: numba is optional and takes 0.15 s to import

        components = _compiled.field_from_grid(data, grid.outside, m, P, T)
    else:
        g = np.zeros(tuple(n + 2 * m for n in grid.shape), dtype=dt)
        inner = g[m : m + grid.shape[0], m : m + grid.shape[1], m : m + grid.shape[2]]
        np.subtract(grid.data, grid.outside, out=inner, casting="unsafe")
        components = correlate_separable(g, kernels, backend="numpy")
    components.setflags(write=False)
    return MatrixField(components, grid.origin.copy(), grid.resolution, m, m >= kernels.support)


def correlate_separable(g: np.ndarray, kernels: Kernels, backend: str = "auto") -> np.ndarray:
    """The three components (3, *g.shape) of ``g`` correlated with the kernels, zeros beyond ``g``.

    ``g`` is a C-contiguous float32 or float64 array; the result has its dtype.
    """
    g = np.ascontiguousarray(g)
    dt = g.dtype
    out = np.empty((3, *g.shape), dtype=dt)
    P, T = kernels.factors(dt)
    if _backend.resolve(backend) == "numba":
        from planbench.field import _compiled  # on use: numba is optional and takes 0.15 s to import

        corr: Callable[..., None] = _compiled.correlate_axis
    else:
        corr = _scipy_pass
    h = np.empty_like(g)
    tmp = np.empty_like(g)
    corr(g, h, T, 2, 1.0)  # H = T_z G
    corr(h, tmp, T, 1, 1.0)
    corr(tmp, out[0], P, 0, -1.0)  # F_x = P_x T_y H
    corr(h, tmp, T, 0, 1.0)
    corr(tmp, out[1], P, 1, -1.0)  # F_y = P_y T_x H
    corr(g, h, P, 2, -1.0)
    corr(h, tmp, T, 1, 1.0)
    corr(tmp, out[2], T, 0, 1.0)  # F_z = T_x T_y P_z G
    return out


def _scipy_pass(src: np.ndarray, dst: np.ndarray, k: np.ndarray, axis: int, sign: float) -> None:
    # scipy.ndimage on use (numpy backend only): ~0.15 s to import; planbench.field loads with planbench --help
    from scipy.ndimage import correlate1d

    correlate1d(src, k, axis=axis, output=dst, mode="constant", cval=0.0)
