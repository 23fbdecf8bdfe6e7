"""The matrix field: a repulsive vector field from an occupancy grid and three directional kernels.

docs/method.md, sections 1-3. Typical use::

    from planbench.field import KernelSpec, full_field, lazy_field

    kernels = KernelSpec(reach=0.2, profile="gaussian").build(grid.resolution)
    field = full_field(grid, kernels)          # static scene: once
    F = field.sample(points)                   # (N, 3) at control points [m]
    F = lazy_field(grid, kernels, points)      # changing grid: no full pass, same numbers

Modules: ``kernels`` (profiles, tapers, sizes), ``full`` (separable passes over the grid),
``lazy`` (window sums at points), ``interpolate`` (trilinear sampling), ``surface`` (thin-wall
pre-pass), ``reference`` (brute-force checks), ``plots``, ``bench`` and ``commands`` (CLI);
``calibrated`` (section 8: a signed distance in metres from separable Gaussian kernels).
"""

from planbench.field.full import MatrixField, full_field
from planbench.field.kernels import PROFILES, TAPERS, Kernels, KernelSpec
from planbench.field.lazy import lazy_field
from planbench.field.surface import surface_grid

__all__ = ["KernelSpec", "Kernels", "MatrixField", "PROFILES", "TAPERS", "full_field", "lazy_field", "surface_grid"]
