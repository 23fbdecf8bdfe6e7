"""Plots of the matrix field (matplotlib, no GUI: each function returns a Figure, can write a PNG).

- :func:`plot_profiles`: the profile along the axis for each profile type, and the tapers
  (the draft's "ERK" and linear kernel graphics).
- :func:`plot_kernel`: one kernel's 3D shape: its 1D factors, the central slices of ``K_x`` and a
  surface view of the slice through the kernel's centre.
- :func:`plot_field_slice`: the field around obstacles on a plane ``x``, ``y`` or ``z = value``:
  colour = field magnitude, arrows = in-plane direction, hatched grey = occupied cells.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure

from planbench.errors import InvalidConfigError
from planbench.field.full import MatrixField
from planbench.field.kernels import PROFILES, TAPERS, Kernels, KernelSpec
from planbench.files.outputs import check_output
from planbench.geometry.occupancy import OccupancyGrid

__all__ = ["plot_profiles", "plot_kernel", "plot_field_slice", "parse_slice"]

AXES = "xyz"


def _save(fig: Figure, out: str | Path | None) -> Figure:
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(check_output(out), dpi=120)
    return fig


def plot_profiles(
    reach: float = 0.2, resolution: float = 0.01, out: str | Path | None = None, highlight: str | None = None
) -> Figure:
    """Profiles ``P(s)`` along the axis for every built-in profile type, and the tapers ``T``.

    ``reach`` [m], ``resolution`` [m/cell]. Values are those of the kernels planbench builds
    (gain 1, default ``sigma`` and ``power``).
    """
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    ax_p, ax_t = fig.subplots(1, 2)
    for name in PROFILES:
        k = KernelSpec(reach=reach, profile=name).build(resolution)
        s = (np.arange(len(k.along)) - k.half_length) * resolution
        lw = 2.6 if name == highlight else 1.5
        ax_p.plot(s, k.along, "o-", ms=2.5, lw=lw, label=name)
    ax_p.axhline(0, color="0.6", lw=0.8)
    ax_p.axvline(0, color="0.6", lw=0.8)
    ax_p.set(
        title="Profile P along the axis (an obstacle at +s pushes to -s)",
        xlabel="offset s of the occupied cell along the axis [m]",
        ylabel="kernel value",
    )
    ax_p.legend()
    for name in TAPERS:
        k = KernelSpec(reach=reach, taper=name).build(resolution)
        t = (np.arange(len(k.across)) - k.half_width) * resolution
        ax_t.plot(t, k.across, "o-", ms=2.5, lw=1.5, label=name)
    ax_t.set(title="Taper T across the axis", xlabel="offset across the axis [m]", ylabel="weight", ylim=(0, 1.08))
    ax_t.legend()
    fig.suptitle(f"Matrix-field kernel factors (reach {reach:g} m, {resolution:g} m cells)")
    return _save(fig, out)


def plot_kernel(kernels: Kernels, out: str | Path | None = None, title: str = "") -> Figure:
    """The 3D shape of ``K_x``: factors, slices z = 0 and y = 0, and a surface of slice z = 0."""
    k = kernels.dense("x")
    r = kernels.resolution
    c, w = kernels.half_length, kernels.half_width
    s = (np.arange(-c, c + 1)) * r
    t = (np.arange(-w, w + 1)) * r
    lim = np.abs(k).max()
    norm = TwoSlopeNorm(0.0, -lim, lim)
    fig = Figure(figsize=(12, 9), layout="constrained")
    ax = fig.add_subplot(2, 2, 1)
    ax.plot(s, kernels.along, "o-", ms=3, label="profile P (along x)")
    ax.plot(t, kernels.across, "s--", ms=3, label="taper T (across: y, z)")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set(title="1D factors: K_x = P(x) T(y) T(z)", xlabel="offset [m]", ylabel="value")
    ax.legend()
    ax3 = fig.add_subplot(2, 2, 2, projection="3d")
    X, Y = np.meshgrid(s, t, indexing="ij")
    ax3.plot_surface(X, Y, k[:, :, w], cmap="coolwarm", norm=norm, linewidth=0.2, edgecolor="0.3")
    ax3.set(title="K_x on the slice z = 0", xlabel="x [m]", ylabel="y [m]", zlabel="value")
    for n, (sl, label) in enumerate(((k[:, :, w], "y"), (k[:, w, :], "z"))):
        ax = fig.add_subplot(2, 2, 3 + n)
        im = ax.imshow(
            sl.T,
            origin="lower",
            cmap="coolwarm",
            norm=norm,
            aspect="equal",
            extent=(s[0] - r / 2, s[-1] + r / 2, t[0] - r / 2, t[-1] + r / 2),
        )
        ax.set(title=f"K_x on the slice {'z' if label == 'y' else 'y'} = 0", xlabel="x [m]", ylabel=f"{label} [m]")
        fig.colorbar(im, ax=ax, shrink=0.85)
    fig.suptitle(
        title or f"Kernel K_x: {len(kernels.along)} x {len(kernels.across)} x {len(kernels.across)} cells of {r:g} m"
    )
    return _save(fig, out)


def parse_slice(text: str) -> tuple[int, float]:
    """``"z=0.3"`` -> (2, 0.3): the axis index and the plane's coordinate [m]."""
    axis, sep, value = text.partition("=")
    axis = axis.strip().lower()
    try:
        coord = float(value)
    except ValueError:
        coord = float("nan")
    if not sep or axis not in AXES or not np.isfinite(coord):
        raise InvalidConfigError(f"--slice is written axis=value in metres, e.g. z=0.3; got {text!r}")
    return AXES.index(axis), coord


def plot_field_slice(
    grid: OccupancyGrid,
    field: MatrixField,
    axis: int,
    value: float,
    out: str | Path | None = None,
    title: str = "",
    samples: int = 160,
    arrows: int = 28,
) -> Figure:
    """The field on the plane ``axis = value`` [m] over the grid's extent (plus the margin).

    Colour: ``|F|`` (log-scaled); arrows: the in-plane direction of ``F`` (unit length, drawn where
    ``|F|`` is non-zero); grey: cells whose occupancy on the plane is >= 0.5.
    """
    u_ax, v_ax = [a for a in range(3) if a != axis]
    pad = field.margin * field.resolution
    lo, hi = grid.origin - pad, grid.upper + pad
    n_u = samples
    n_v = max(2, int(round(samples * (hi[v_ax] - lo[v_ax]) / (hi[u_ax] - lo[u_ax]))))
    u = np.linspace(lo[u_ax], hi[u_ax], n_u)
    v = np.linspace(lo[v_ax], hi[v_ax], n_v)
    U, V = np.meshgrid(u, v, indexing="ij")
    pts = np.empty((U.size, 3))
    pts[:, axis], pts[:, u_ax], pts[:, v_ax] = value, U.ravel(), V.ravel()
    F = field.sample(pts).reshape(n_u, n_v, 3)
    mag = np.linalg.norm(F, axis=2)
    occ = grid.occupancy_at(pts).reshape(n_u, n_v)

    fig = Figure(figsize=(8.5, 7.5), layout="constrained")
    ax = fig.add_subplot()
    extent = (u[0], u[-1], v[0], v[-1])
    positive = mag[mag > 0]
    floor = max(positive.max() * 1e-3, positive.min()) if positive.size else 1.0
    im = ax.imshow(np.log10(np.maximum(mag, floor)).T, origin="lower", extent=extent, cmap="magma", aspect="equal")
    fig.colorbar(im, ax=ax, shrink=0.8, label="log10 |F| (field magnitude)")
    ax.contourf(U, V, occ, levels=[0.5, 1.01], colors=["0.75"], hatches=["//"], alpha=0.9)
    ax.contour(U, V, occ, levels=[0.5], colors=["white"], linewidths=0.8)
    step_u = max(1, n_u // arrows)
    step_v = max(1, n_v // arrows)
    Fu, Fv = F[::step_u, ::step_v, u_ax], F[::step_u, ::step_v, v_ax]
    norm = np.hypot(Fu, Fv)
    show = norm > 1e-9 * max(norm.max(), 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        ax.quiver(
            U[::step_u, ::step_v][show],
            V[::step_u, ::step_v][show],
            (Fu / norm)[show],
            (Fv / norm)[show],
            color="cyan",
            scale=arrows * 1.3,
            width=0.0025,
            pivot="mid",
        )
    ax.set(xlim=(u[0], u[-1]), ylim=(v[0], v[-1]), xlabel=f"{AXES[u_ax]} [m]", ylabel=f"{AXES[v_ax]} [m]")
    ax.set_title(title or f"Matrix field on the plane {AXES[axis]} = {value:g} m")
    return _save(fig, out)
