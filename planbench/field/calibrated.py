"""The calibrated matrix field: a smooth signed distance [m] from separable Gaussian kernels.

docs/method.md, "8. The calibrated field". The occupancy grid ``G`` is correlated with a Gaussian
``g(v) = exp(-|v|^2 / (2 sigma^2))``, which is a product of three 1D Gaussians (separable, like
the directional kernels) *and* depends on the Euclidean norm only. Normalised by the cell volume
``r^3`` and the Gaussian's integral, the sum is the fraction of a Gaussian blob at ``x`` that lies
in occupied space::

    m(x) = r^3 / ((2 pi)^(3/2) sigma^3) * sum_c G(c) g(x - c)        in [0, 1], no unit

independent of the resolution (it approximates an integral over the occupied volume). For a
half-space at signed distance ``d`` it is exactly ``Phi(-d / sigma)`` (``Phi`` the standard normal
CDF), so the calibrated distance inverts that::

    d(x) = -sigma Phi^-1(m(x))            [m]; exact for a flat face, negative inside

Its gradient is ``grad d = -sigma sqrt(2 pi) exp(d^2 / (2 sigma^2)) grad m``, and ``grad m`` is
again a correlation with separable kernels (one axis takes the Gaussian's derivative), so the three
components are the matrix field's directional kernels with the derivative of a Gaussian as profile
and a Gaussian as taper.

Evaluation: :func:`calibrated_at` at points, straight from the grid (the Gaussians at the point's
exact offsets; nothing is precomputed, for grids that change), and :func:`calibrated_full` at every
cell centre by separable 1D passes (for static scenes; sampled trilinearly, it equals
:func:`calibrated_at` at cell centres). Cells beyond the grid hold the grid's ``outside``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planbench.errors import InvalidConfigError, ResourceLimitError
from planbench.field.full import MatrixField
from planbench.field.interpolate import as_points
from planbench.field.kernels import MAX_KERNEL_CELLS
from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime import backend as _backend

__all__ = ["CalibratedKernel", "CalibratedSpec", "DistanceField", "calibrated_at", "calibrated_full", "to_distance"]

TAIL_SIGMAS = 4.0
"""The kernel reaches ``reach + TAIL_SIGMAS * sigma``: a cell farther than that from a point within
``reach`` of an obstacle weighs at most ``exp(-4 reach / sigma - 8)`` of the nearest one."""
_SERIAL_POINTS = 64  # up to this many points: no parallel region (a planner's control points)


@dataclass(frozen=True)
class CalibratedSpec:
    """The calibrated field's settings in metres; :meth:`build` turns them into cells."""

    sigma: float = 0.02
    """Standard deviation of the Gaussian [m]: the distance is exact at a flat face and
    over-estimated by up to ``0.67 sigma`` at a convex edge, ``1.15 sigma`` at a convex corner
    (docs/method.md, section 8)."""
    reach: float = 0.15
    """Largest distance that must be right [m] (the push's influence distance); beyond it the
    distance is at least ``reach`` (the kernel is truncated, which only drops mass)."""

    def build(self, resolution: float) -> CalibratedKernel:
        """The kernel for a grid of ``resolution`` [m/cell]."""
        for name, value in (("sigma", self.sigma), ("reach", self.reach), ("resolution", resolution)):
            _check_positive(name, value)
        half = math.ceil((self.reach + TAIL_SIGMAS * self.sigma) / resolution - 1e-9)
        if 2 * half + 1 > MAX_KERNEL_CELLS:
            raise ResourceLimitError(
                f"the calibrated kernel would be {2 * half + 1} cells a side, more than "
                f"{MAX_KERNEL_CELLS} (planbench.field.kernels.MAX_KERNEL_CELLS): use a coarser grid, "
                "a smaller sigma or a shorter reach"
            )
        return CalibratedKernel(float(self.sigma), float(self.reach), float(resolution), half)


@dataclass(frozen=True)
class CalibratedKernel:
    """The Gaussian for one resolution: ``half`` cells from the centre to the cube's face."""

    sigma: float
    reach: float
    resolution: float
    half: int

    @property
    def norm(self) -> float:
        """``r^3 / ((2 pi)^(3/2) sigma^3)``: turns a sum over cells into the occupied fraction."""
        return float(self.resolution**3 / ((2 * math.pi) ** 1.5 * self.sigma**3))

    def factors(self) -> tuple[np.ndarray, np.ndarray]:
        """``(g, dg)`` at cell offsets ``-half .. half``: the Gaussian, and its derivative kernel
        ``(u r / sigma^2) g(u r)`` (antisymmetric; correlated, it gives ``d sum / d x``)."""
        off = np.arange(-self.half, self.half + 1) * self.resolution
        g = np.exp(-(off**2) / (2 * self.sigma**2))
        return g, off / self.sigma**2 * g

    def check_resolution(self, resolution: float) -> None:
        if abs(self.resolution - resolution) > 1e-9 * resolution:
            raise InvalidConfigError(
                f"the calibrated kernel was built for resolution {self.resolution:g} m but the grid has "
                f"{resolution:g} m; build it with CalibratedSpec.build(grid.resolution)"
            )


@dataclass(frozen=True, eq=False)
class DistanceField:
    """The calibrated distance at a grid's cell centres, stored for trilinear sampling:
    ``deficit`` (component 0: ``min(d, reach) - reach``, zero where nothing is near, so zero beyond
    the stored cells is the truth) and ``gradient`` (``grad d``, three components)."""

    deficit: MatrixField
    gradient: MatrixField
    reach: float

    def sample(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(d, grad d)`` at points (N, 3) [m], ``d`` capped at ``reach``."""
        return self.reach + self.deficit.sample(points)[:, 0], self.gradient.sample(points)


def to_distance(sums: np.ndarray, kernel: CalibratedKernel) -> tuple[np.ndarray, np.ndarray]:
    """``(d, grad d)`` from the raw sums (N, 4): ``(S, dS/dx, dS/dy, dS/dz)`` (module docstring).
    ``d`` is ``inf`` (gradient zero) where no occupied cell is within the kernel."""
    from scipy.special import ndtri  # on use: scipy.special takes a while to import

    m = sums[:, 0] * kernel.norm
    near = m > 1e-300
    mc = np.clip(m, 1e-300, 1.0 - 1e-15)  # deep inside a solid m rounds to 1
    u = ndtri(mc)  # = -d / sigma
    d = np.where(near, -kernel.sigma * u, np.inf)
    scale = np.where(near, -kernel.sigma * math.sqrt(2 * math.pi) * np.exp(0.5 * u * u) * kernel.norm, 0.0)
    return d, sums[:, 1:] * scale[:, None]


def calibrated_sums(
    grid: OccupancyGrid, kernel: CalibratedKernel, points: np.ndarray, backend: str = "auto"
) -> np.ndarray:
    """The raw sums (N, 4) ``(S, grad S)`` at points (N, 3) [m], straight from the grid."""
    kernel.check_resolution(grid.resolution)
    pts = as_points(points)
    out = np.empty((len(pts), 4))
    data = np.ascontiguousarray(grid.data)
    if _backend.resolve(backend) == "numba":
        from planbench.field import _calibrated_compiled as compiled  # numba is optional

        run = compiled.gauss_points_serial if len(pts) <= _SERIAL_POINTS else compiled.gauss_points
        run(data, float(grid.outside), grid.origin, grid.resolution, kernel.sigma, kernel.half, pts, out)
        return out
    for p, x in enumerate(pts):
        out[p] = _sums_numpy(data, grid, kernel, x)
    return out


def calibrated_at(
    grid: OccupancyGrid, kernel: CalibratedKernel, points: np.ndarray, backend: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """``(d, grad d)`` at points (N, 3) [m]: the calibrated signed distance [m] (``inf`` beyond the
    kernel) and its gradient, from the grid without a full pass."""
    return to_distance(calibrated_sums(grid, kernel, points, backend), kernel)


def calibrated_full(grid: OccupancyGrid, kernel: CalibratedKernel, backend: str = "auto") -> DistanceField:
    """The calibrated distance and its gradient at every cell centre of ``grid`` (module docstring)."""
    kernel.check_resolution(grid.resolution)
    h = kernel.half
    g = np.full(tuple(n + 2 * h for n in grid.shape), float(grid.outside))
    g[h:-h, h:-h, h:-h] = grid.data
    G, D = kernel.factors()
    corr: Callable[..., None] = _scipy_pass
    if _backend.resolve(backend) == "numba":
        from planbench.field import _compiled  # numba is optional

        corr = _compiled.correlate_axis
    a, b = np.empty_like(g), np.empty_like(g)
    hz, hdz = np.empty_like(g), np.empty_like(g)
    sums = np.empty((4, *grid.shape))
    inner = (slice(h, -h),) * 3
    corr(g, hz, G, 2, 1.0)  # g_z G
    corr(g, hdz, D, 2, -1.0)  # dg_z G
    corr(hz, a, G, 1, 1.0)  # g_y g_z G
    corr(a, b, G, 0, 1.0)
    sums[0] = b[inner]  # S
    corr(a, b, D, 0, -1.0)
    sums[1] = b[inner]  # dS/dx
    corr(hz, a, D, 1, -1.0)  # dg_y g_z G
    corr(a, b, G, 0, 1.0)
    sums[2] = b[inner]  # dS/dy
    corr(hdz, a, G, 1, 1.0)  # g_y dg_z G
    corr(a, b, G, 0, 1.0)
    sums[3] = b[inner]  # dS/dz
    d, grad = to_distance(sums.reshape(4, -1).T, kernel)
    deficit = np.zeros((3, *grid.shape))
    deficit[0] = (np.minimum(d, kernel.reach) - kernel.reach).reshape(grid.shape)
    gradient = np.ascontiguousarray(grad.T.reshape(3, *grid.shape))
    for arr in (deficit, gradient):
        arr.setflags(write=False)
    return DistanceField(
        MatrixField(deficit, grid.origin.copy(), grid.resolution, 0, True),
        MatrixField(gradient, grid.origin.copy(), grid.resolution, 0, True),
        kernel.reach,
    )


def _sums_numpy(data: np.ndarray, grid: OccupancyGrid, kernel: CalibratedKernel, x: np.ndarray) -> np.ndarray:
    """:mod:`._calibrated_compiled`'s point sums in numpy (no numba)."""
    h, r, s = kernel.half, grid.resolution, kernel.sigma
    u = (x - grid.origin) / r - 0.5
    base = np.floor(u + 0.5).astype(np.int64) - h
    cells = base[:, None] + np.arange(2 * h + 1)  # (3, n)
    off = (cells - u[:, None]) * r
    w = np.exp(-(off**2) / (2 * s * s))
    dw = off / (s * s) * w
    inside = (cells >= 0) & (cells < np.array(grid.shape)[:, None])
    idx = np.clip(cells, 0, np.array(grid.shape)[:, None] - 1)
    block = data[idx[0][:, None, None], idx[1][None, :, None], idx[2][None, None, :]].astype(np.float64)
    mask = inside[0][:, None, None] & inside[1][None, :, None] & inside[2][None, None, :]
    block = np.where(mask, block, float(grid.outside))
    return np.array(
        [
            np.einsum("ijk,i,j,k->", block, w[0], w[1], w[2]),
            np.einsum("ijk,i,j,k->", block, dw[0], w[1], w[2]),
            np.einsum("ijk,i,j,k->", block, w[0], dw[1], w[2]),
            np.einsum("ijk,i,j,k->", block, w[0], w[1], dw[2]),
        ]
    )


def _scipy_pass(src: np.ndarray, dst: np.ndarray, k: np.ndarray, axis: int, sign: float) -> None:
    from scipy.ndimage import correlate1d  # on use (numpy backend only)

    correlate1d(src, k, axis=axis, output=dst, mode="constant", cval=0.0)


def _check_positive(name: str, value: float) -> None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidConfigError(f"{name} must be a number [m], got {value!r}") from None
    if isinstance(value, bool) or not (math.isfinite(v) and v > 0):
        raise InvalidConfigError(f"{name} must be finite and > 0 [m], got {value!r}")
