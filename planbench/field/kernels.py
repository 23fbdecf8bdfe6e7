"""Directional repulsive kernels (docs/method.md, section 2).

One kernel per axis ``a`` in {x, y, z}, each separable into 1D factors::

    K_x[i, j, k] = P[i] * T[j] * T[k]     K_y = T[i] P[j] T[k]     K_z = T[i] T[j] P[k]

``P`` (``Kernels.along``, ``L`` cells) is the antisymmetric profile along the axis and ``T``
(``Kernels.across``, ``W`` cells) the symmetric taper across it; both are odd-sized and centred on
their middle cell. Index ``c + s`` of ``P`` (``c = (L - 1) // 2``) weighs the cell ``s`` steps along
``+a`` from the query point, and ``P[c + s] < 0`` for ``s > 0``: an obstacle on the ``+a`` side
pushes the point towards ``-a`` (``P[c] = 0``, ``P[c - s] = -P[c + s]``).

Sizes are settings in metres (:class:`KernelSpec`) turned into cells with the grid resolution:
``L = 2 * round(reach / resolution) + 1`` and ``W = 2 * round(width / resolution) + 1`` (rounded to
the nearest whole cell, halves up). :meth:`Kernels.from_cells` takes the cell counts directly.

Profiles (magnitude ``|P|`` as a function of the distance ``d`` [m] from the point, ``d > 0``):

- ``"linear"``: ``(R + r - d) / (R + r)`` with reach ``R`` and resolution ``r`` — in cells
  ``(c + 1 - |s|) / (c + 1)``: 1 next to the point, ``1 / (c + 1)`` at the last cell.
- ``"gaussian"``: ``exp(-d^2 / (2 sigma^2))``, ``sigma`` [m] defaulting to ``R / 2``.
- ``"inverse-power"``: ``(r / d)^power`` — the inverse power of the distance in metres, scaled so
  that the nearest cell weighs 1; strongly non-linear (the draft's "non-linear repulsive kernel").
- a callable ``f(d) -> magnitudes``: ``d`` is an array of distances [m]; values must be finite and
  ``>= 0``. The sign (antisymmetry) is applied here, so a user cannot break the convention.

Tapers (weight ``T`` as a function of the distance across the axis, ``T`` symmetric):
``"linear"`` ``(w + 1 - |t|) / (w + 1)`` in cells (``w = (W - 1) // 2``), ``"gaussian"``
(``taper_sigma`` [m], default ``width / 2``), ``"constant"`` (a box), or a callable like profiles.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import DTypeLike

from planbench.errors import InvalidConfigError, ResourceLimitError

__all__ = ["KernelSpec", "Kernels", "PROFILES", "TAPERS", "ProfileFn"]

ProfileFn = Callable[[np.ndarray], np.ndarray]
"""Magnitude as a function of distance [m] (an array of positive distances)."""

PROFILES = ("linear", "gaussian", "inverse-power")
TAPERS = ("linear", "gaussian", "constant")
AXES = "xyz"
MAX_KERNEL_CELLS = 1001
"""The most cells a kernel may have along or across its axis (a reach of 0.2 m at 0.01 m is 41)."""
MAX_DENSE_CELLS = 1 << 25
"""The most cells of a kernel built whole in 3D (:meth:`Kernels.dense`, for plots: 256 MiB)."""


@dataclass(frozen=True)
class KernelSpec:
    """Kernel settings in metres; :meth:`build` turns them into cells for one grid resolution."""

    reach: float = 0.2
    """Influence distance along the axis [m]: the kernel spans ``-reach .. +reach``."""
    width: float | None = None
    """Half-width across the axis [m]; ``None`` = same as ``reach`` (a cubic kernel)."""
    profile: str | ProfileFn = "linear"
    """Profile along the axis: one of :data:`PROFILES` or a callable (see module docstring)."""
    taper: str | ProfileFn = "linear"
    """Taper across the axis: one of :data:`TAPERS` or a callable."""
    gain: float = 1.0
    """Multiplies the profile (the field's scale) [-]."""
    sigma: float | None = None
    """Standard deviation of the gaussian profile [m]; default ``reach / 2``."""
    taper_sigma: float | None = None
    """Standard deviation of the gaussian taper [m]; default ``width / 2``."""
    power: float = 2.0
    """Exponent of the inverse-power profile [-]."""

    def build(self, resolution: float) -> Kernels:
        """The kernels for a grid of ``resolution`` [m/cell]."""
        resolution = _positive(resolution, "resolution", "m/cell")
        reach = _positive(self.reach, "reach", "m")
        width = reach if self.width is None else _positive(self.width, "width", "m")
        half_l = _cells(reach, resolution)
        half_w = _cells(width, resolution)
        for name, value, half in (("reach", reach, half_l), ("width", width, half_w)):
            if half < 1:
                raise InvalidConfigError(
                    f"kernel {name} {value:g} m is under half a cell of {resolution:g} m, so the "
                    f"kernel would be 1 cell (it needs >= 3): use {name} >= {resolution:g} m "
                    "or a finer grid"
                )
        return Kernels.from_cells(
            2 * half_l + 1,
            2 * half_w + 1,
            resolution=resolution,
            profile=self.profile,
            taper=self.taper,
            gain=self.gain,
            sigma=self.sigma,
            taper_sigma=self.taper_sigma,
            power=self.power,
        )


@dataclass(frozen=True, eq=False)
class Kernels:
    """The 1D factors of the three directional kernels, for one grid resolution.

    ``along``: (L,) antisymmetric profile ``P`` (gain included); ``across``: (W,) symmetric taper
    ``T``; ``resolution`` [m/cell]. Both arrays are float64 and read-only.
    """

    along: np.ndarray
    across: np.ndarray
    resolution: float = 1.0

    def __post_init__(self) -> None:
        along = _vector(self.along, "along (profile)")
        across = _vector(self.across, "across (taper)")
        if along[len(along) // 2] != 0.0 or not np.array_equal(along, -along[::-1]):
            raise InvalidConfigError(
                "the profile along the axis must be antisymmetric (P[c + s] == -P[c - s], "
                "P[c] == 0); build kernels with KernelSpec or Kernels.from_cells"
            )
        if not np.array_equal(across, across[::-1]):
            raise InvalidConfigError("the taper across the axis must be symmetric (T[c + t] == T[c - t])")
        _positive(self.resolution, "resolution", "m/cell")
        for arr in (along, across):
            arr.setflags(write=False)
        object.__setattr__(self, "along", along)
        object.__setattr__(self, "across", across)
        object.__setattr__(self, "resolution", float(self.resolution))

    @classmethod
    def from_cells(
        cls,
        length: int,
        width: int | None = None,
        *,
        resolution: float = 1.0,
        profile: str | ProfileFn = "linear",
        taper: str | ProfileFn = "linear",
        gain: float = 1.0,
        sigma: float | None = None,
        taper_sigma: float | None = None,
        power: float = 2.0,
    ) -> Kernels:
        """Kernels of ``length`` cells along the axis and ``width`` across (default: ``length``).

        Both must be odd and >= 3. ``resolution`` [m/cell] converts cell offsets to the distances
        [m] that profiles, ``sigma`` and ``taper_sigma`` are expressed in.
        """
        width = length if width is None else width
        for name, n in (("length", length), ("width", width)):
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
                raise InvalidConfigError(f"kernel {name} must be a whole number of cells, got {n!r}")
            if n < 3 or n % 2 == 0:
                hint = f"use {max(3, n + 1 if n % 2 == 0 else 3)}"
                raise InvalidConfigError(
                    f"kernel {name} must be odd and >= 3 cells (a centre cell and at least one "
                    f"on each side), got {n}; {hint}"
                )
            if n > MAX_KERNEL_CELLS:
                raise ResourceLimitError(
                    f"kernel {name} of {n:,} cells is more than the {MAX_KERNEL_CELLS:,} planbench builds "
                    "(planbench.field.kernels.MAX_KERNEL_CELLS): use a coarser resolution or a shorter reach"
                )
        resolution = _positive(resolution, "resolution", "m/cell")
        gain = _positive(gain, "gain", "-")
        c, w = (length - 1) // 2, (width - 1) // 2
        d_along = np.arange(1, c + 1) * resolution  # distances of cells 1..c [m]
        d_across = np.arange(0, w + 1) * resolution
        mag = _profile_magnitude(profile, d_along, c, resolution, sigma, power)
        half_taper = _taper_values(taper, d_across, w, resolution, taper_sigma)
        along = np.concatenate([mag[::-1], [0.0], -mag]) * gain
        across = np.concatenate([half_taper[:0:-1], half_taper])
        return cls(along, across, resolution)

    @property
    def half_length(self) -> int:
        """Cells from the centre to the end of the profile along the axis (``c``)."""
        return (len(self.along) - 1) // 2

    @property
    def half_width(self) -> int:
        """Cells from the centre to the edge across the axis."""
        return (len(self.across) - 1) // 2

    @property
    def support(self) -> int:
        """Cells from the centre to the farthest cell of any of the three kernels."""
        return max(self.half_length, self.half_width)

    @property
    def reach(self) -> float:
        """Influence distance along the axis [m]."""
        return self.half_length * self.resolution

    def check_resolution(self, resolution: float) -> None:
        """Raise unless these kernels were built for a grid of ``resolution`` [m/cell]."""
        if abs(self.resolution - resolution) > 1e-9 * resolution:
            raise InvalidConfigError(
                f"kernels were built for resolution {self.resolution:g} m but the grid has "
                f"{resolution:g} m; build them with KernelSpec.build(grid.resolution)"
            )

    def factors(self, dtype: DTypeLike) -> tuple[np.ndarray, np.ndarray]:
        """``(along, across)`` cast to ``dtype`` (cached: the hot paths call this every tick)."""
        key = np.dtype(dtype)
        cache = self.__dict__.setdefault("_factors", {})
        if key not in cache:
            cache[key] = (self.along.astype(key), self.across.astype(key))
        return cache[key]  # type: ignore[no-any-return]

    def dense(self, axis: int | str) -> np.ndarray:
        """The full 3D kernel ``K_axis`` (L or W cells per dimension), axis order x, y, z."""
        a = _axis(axis)
        cells = len(self.along) * len(self.across) ** 2
        if cells > MAX_DENSE_CELLS:
            raise ResourceLimitError(
                f"the dense kernel would have {len(self.along)} x {len(self.across)} x {len(self.across)} = "
                f"{cells:,} cells, more than {MAX_DENSE_CELLS:,} (planbench.field.kernels.MAX_DENSE_CELLS)"
            )
        factors = [self.along if b == a else self.across for b in range(3)]
        return np.einsum("i,j,k->ijk", *factors)


def _axis(axis: int | str) -> int:
    if isinstance(axis, str) and axis in AXES and len(axis) == 1:
        return AXES.index(axis)
    if isinstance(axis, (int, np.integer)) and 0 <= axis < 3:
        return int(axis)
    raise InvalidConfigError(f"axis must be 0, 1, 2 or 'x', 'y', 'z', got {axis!r}")


def _cells(metres: float, resolution: float) -> int:
    """Nearest whole number of cells, halves rounded up (tolerant to float noise)."""
    return int(np.floor(metres / resolution + 0.5 + 1e-9))


def _positive(value: float, name: str, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidConfigError(f"{name} must be a number [{unit}], got {value!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise InvalidConfigError(f"{name} must be finite and > 0 [{unit}], got {value!r}")
    return v


def _vector(arr: np.ndarray, name: str) -> np.ndarray:
    v = np.array(arr, dtype=np.float64)
    if v.ndim != 1 or len(v) < 3 or len(v) % 2 == 0:
        raise InvalidConfigError(f"kernel factor {name} must be 1D with an odd length >= 3, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise InvalidConfigError(f"kernel factor {name} must be finite")
    return v


def _profile_magnitude(
    profile: str | ProfileFn, d: np.ndarray, c: int, resolution: float, sigma: float | None, power: float
) -> np.ndarray:
    if callable(profile):
        return _user_values(profile, d, "profile")
    if profile == "linear":
        return (c + 1 - d / resolution) / (c + 1)
    if profile == "gaussian":
        s = c * resolution / 2 if sigma is None else _positive(sigma, "sigma", "m")
        return np.exp(-(d**2) / (2 * s**2))
    if profile == "inverse-power":
        return (resolution / d) ** _positive(power, "power", "-")
    raise InvalidConfigError(
        f"unknown kernel profile {profile!r}; use one of {PROFILES} or a function of the distance [m]"
    )


def _taper_values(
    taper: str | ProfileFn, d: np.ndarray, w: int, resolution: float, taper_sigma: float | None
) -> np.ndarray:
    if callable(taper):
        return _user_values(taper, d, "taper")
    if taper == "linear":
        return (w + 1 - d / resolution) / (w + 1)
    if taper == "gaussian":
        s = w * resolution / 2 if taper_sigma is None else _positive(taper_sigma, "taper_sigma", "m")
        return np.exp(-(d**2) / (2 * s**2))
    if taper == "constant":
        return np.ones_like(d)
    raise InvalidConfigError(f"unknown kernel taper {taper!r}; use one of {TAPERS} or a function of the distance [m]")


def _user_values(fn: ProfileFn, d: np.ndarray, what: str) -> np.ndarray:
    values = np.asarray(fn(d.copy()), dtype=np.float64)
    if values.shape != d.shape:
        raise InvalidConfigError(
            f"a {what} function must return one value per distance (shape {d.shape}), got shape {values.shape}"
        )
    if not np.all(np.isfinite(values)) or np.any(values < 0):
        raise InvalidConfigError(
            f"a {what} function must return finite values >= 0; the sign convention is applied by planbench"
        )
    return values
