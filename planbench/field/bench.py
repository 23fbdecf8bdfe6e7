"""Benchmark of the matrix field (``planbench bench-field`` or ``python benchmarks/field.py``).

For each grid size (cells per side), kernel length ``L`` (cells along the axis; the width across
is the same, so ``L^3`` kernels) and dtype, in one run, medians of repeated runs of:

- ``full``: the separable field on the grid's cells (``margin=0``), default backend;
- ``+margin``: the same with the default margin (exact sampling everywhere), what
  :func:`~planbench.field.full.full_field` does by default;
- ``scipy1d``: the separable field with ``scipy.ndimage.correlate1d`` (the numpy backend);
- ``fft``: the three components by FFT (one forward transform of the grid);
- ``dense``: ``scipy.ndimage.correlate`` with the dense 3D kernels, measured for one component at
  the smallest size and ``L``, extrapolated (``~``) to three components and to the other sizes by
  the operation count ``N L^3``;
- ``edt+grad``: ``scipy.ndimage.distance_transform_edt`` of the free space plus ``np.gradient``
  (the classic distance-field approach; it does not depend on ``L`` or the dtype);
- ``lazy``/``sample``: the lazy field and trilinear sampling of the precomputed field at
  ``points`` random points in the grid [us], with warm caches (the same points again and again,
  like consecutive control ticks) and cold (after flushing the CPU caches).

The timed functions of a row run round-robin, so the machine's noise hits them alike; ratios
are ``edt+grad / full``, ``edt+grad / +margin`` and ``dense / full``, all from this one run.
The grid is a fixed pseudo-random set of boxes filling about 10 % of the volume.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.field.full import full_field
from planbench.field.kernels import Kernels
from planbench.field.lazy import lazy_field
from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime.backend import have_numba

__all__ = ["BenchSettings", "Row", "add_arguments", "run", "run_from_args", "format_table"]

RESOLUTION = 0.01  # [m/cell]; only scales the kernels' units, not the cost


@dataclass(frozen=True)
class BenchSettings:
    """What to time. ``budget`` [s]: stop repeating a row's round-robin once it has used this
    much time (after at least ``min_repeat`` rounds)."""

    sizes: tuple[int, ...] = (64, 128, 256)
    lengths: tuple[int, ...] = (21, 61)
    dtypes: tuple[str, ...] = ("float32", "float64")
    repeat: int = 7
    min_repeat: int = 3
    budget: float = 20.0
    points: int = 30
    scipy: bool = True
    fft: bool = True
    dense: bool = True
    seed: int = 0


@dataclass
class Row:
    n: int
    length: int
    dtype: str
    times: dict[str, float] = field(default_factory=dict)  # [s]
    extrapolated: set[str] = field(default_factory=set)


def median_times(
    fns: Mapping[str, Callable[[], object]],
    repeat: int,
    min_repeat: int,
    budget: float,
    before: Callable[[], object] | None = None,
) -> dict[str, float]:
    """Median wall time [s] of each function, run round-robin so that the machine's noise hits
    them alike; up to ``repeat`` rounds, fewer once ``budget`` [s] is spent (at least
    ``min_repeat``). ``before`` runs untimed before each call. The garbage collector is off."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    start = time.perf_counter()
    enabled = gc.isenabled()
    gc.disable()
    try:
        for done in range(1, repeat + 1):
            for name, fn in fns.items():
                if before is not None:
                    before()
                t = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t)
            if done >= min_repeat and time.perf_counter() - start > budget:
                break
    finally:
        if enabled:
            gc.enable()
    return {k: float(np.median(v)) for k, v in times.items()}


def bench_grid(n: int, dtype: str, seed: int) -> OccupancyGrid:
    """An n^3 grid with random boxes (about 10 % occupied), reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    data = np.zeros((n, n, n), dtype=dtype)
    while data.mean() < 0.1:
        lo = rng.integers(0, n, 3)
        size = rng.integers(max(1, n // 20), max(2, n // 5), 3)
        data[lo[0] : lo[0] + size[0], lo[1] : lo[1] + size[1], lo[2] : lo[2] + size[2]] = 1.0
    return OccupancyGrid(data, np.zeros(3), RESOLUTION)


def run(settings: BenchSettings, progress: Callable[[str], None] | None = None) -> list[Row]:
    """Time everything in ``settings``; returns one row per (size, length, dtype)."""
    # scipy.ndimage and scipy.fft (through reference) on use: 0.1-0.15 s each to import, and this
    # module loads with the CLI (planbench --help)
    from scipy.ndimage import correlate, distance_transform_edt

    from planbench.field.reference import fft_field

    say = progress or (lambda _msg: None)
    rng = np.random.default_rng(settings.seed)
    rows: list[Row] = []
    dense_rate = None  # [s per cell per kernel cell], from the first row
    scratch = np.zeros(16 * 2**20)  # 128 MiB: writing it evicts the CPU caches

    def evict() -> None:
        scratch[::8] += 1.0  # one write per cache line

    if have_numba():  # compile (or load the cached code) outside the timings
        for dt in settings.dtypes:
            g = bench_grid(8, dt, 0)
            k = Kernels.from_cells(3, resolution=RESOLUTION)
            full_field(g, k, dt).sample(np.zeros((1, 3)))
            lazy_field(g, k, np.zeros((1, 3)))
    for n in settings.sizes:
        for length in settings.lengths:
            kernels = Kernels.from_cells(length, resolution=RESOLUTION)
            for dt in settings.dtypes:
                grid = bench_grid(n, dt, settings.seed)
                free = grid.data < 0.5
                row = Row(n, length, dt)
                fns: dict[str, Callable[[], object]] = {
                    "full": lambda: full_field(grid, kernels, dt, margin=0),
                    "+margin": lambda: full_field(grid, kernels, dt),
                    "edt+grad": lambda: np.gradient(distance_transform_edt(free)),
                }
                if settings.scipy:
                    fns["scipy1d"] = lambda: full_field(grid, kernels, dt, margin=0, backend="numpy")
                if settings.fft:
                    fns["fft"] = lambda: fft_field(grid, kernels, np.dtype(dt).type)
                say(f"{n}^3 L={length} {dt}: " + ", ".join(fns))
                row.times.update(median_times(fns, settings.repeat, settings.min_repeat, settings.budget))
                if settings.dense:
                    if dense_rate is None:
                        say(f"{n}^3 L={length} {dt}: dense 3D correlation (one component, once)")
                        kx = kernels.dense(0)
                        one = median_times({"d": lambda: correlate(grid.data, kx, mode="constant")}, 1, 1, 0.0)["d"]
                        dense_rate = one / (n**3 * length**3)
                    row.times["dense"] = 3 * dense_rate * n**3 * length**3
                    if rows:
                        row.extrapolated.add("dense")
                say(f"{n}^3 L={length} {dt}: point queries")
                pts = grid.origin + rng.uniform(0.1, 0.9, (settings.points, 3)) * n * RESOLUTION
                precomputed = full_field(grid, kernels, dt)
                queries = {"lazy": lambda: lazy_field(grid, kernels, pts), "sample": lambda: precomputed.sample(pts)}
                row.times.update(median_times(queries, 300, 50, 1.0))
                cold = median_times(queries, 30, 10, 2.0, before=evict)
                row.times.update({f"{k} cold": v for k, v in cold.items()})
                del precomputed
                rows.append(row)
    return rows


def _ms(row: Row, key: str) -> str:
    if key not in row.times:
        return "-"
    v = row.times[key] * 1e3
    text = f"{v:.0f}" if v >= 100 else f"{v:.1f}"
    return ("~" if key in row.extrapolated else "") + text


def _ratio(row: Row, num: str, den: str) -> str:
    if num not in row.times or den not in row.times:
        return "-"
    return ("~" if num in row.extrapolated else "") + f"{row.times[num] / row.times[den]:.0f}x"


def format_table(rows: list[Row], points: int) -> str:
    """A markdown table of the rows (times in ms, point queries in us)."""
    head = [
        "grid",
        "L",
        "dtype",
        "full ms",
        "+margin ms",
        "scipy1d ms",
        "fft ms",
        "dense ms",
        "edt+grad ms",
        "edt/full",
        "edt/+margin",
        "dense/full",
        f"lazy {points} pts us",
        f"sample {points} pts us",
        "lazy cold us",
        "sample cold us",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [
            f"{r.n}^3",
            str(r.length),
            r.dtype,
            _ms(r, "full"),
            _ms(r, "+margin"),
            _ms(r, "scipy1d"),
            _ms(r, "fft"),
            _ms(r, "dense"),
            _ms(r, "edt+grad"),
            _ratio(r, "edt+grad", "full"),
            _ratio(r, "edt+grad", "+margin"),
            _ratio(r, "dense", "full"),
            f"{r.times['lazy'] * 1e6:.0f}",
            f"{r.times['sample'] * 1e6:.1f}",
            f"{r.times['lazy cold'] * 1e6:.0f}",
            f"{r.times['sample cold'] * 1e6:.0f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def environment() -> str:
    """One line: machine and versions, so a table can be reproduced."""
    import scipy  # on use, for its version: this module loads with the CLI (planbench --help)

    numba = "not installed"
    if have_numba():
        import numba as nb  # optional dependency

        numba = nb.__version__
    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"python {platform.python_version()}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}, numba {numba}"
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The benchmark's command-line options (shared by the CLI and ``benchmarks/field.py``)."""
    d = BenchSettings()
    p.add_argument("--sizes", type=int, nargs="+", default=list(d.sizes), help="cells per side")
    p.add_argument(
        "--lengths",
        type=int,
        nargs="+",
        default=list(d.lengths),
        help="kernel lengths L in cells (odd; kernels are L^3)",
    )
    p.add_argument("--dtypes", nargs="+", choices=["float32", "float64"], default=list(d.dtypes))
    p.add_argument("--repeat", type=int, default=d.repeat, help="runs per measurement (median)")
    p.add_argument(
        "--budget", type=float, default=d.budget, help="seconds after which a row stops repeating (min 3 rounds)"
    )
    p.add_argument("--points", type=int, default=d.points, help="points per lazy/sample query")
    p.add_argument("--quick", action="store_true", help="64^3 and 128^3, L=21 only")
    p.add_argument("--no-scipy", action="store_true", help="skip the correlate1d backend")
    p.add_argument("--no-fft", action="store_true", help="skip the FFT timing")
    p.add_argument("--no-dense", action="store_true", help="skip the dense 3D correlation")


MAX_SIZE = 400
"""The largest grid side timed (400^3 cells: 0.5 GB as float64, the dense and FFT rows several times that)."""


def _check_settings(s: BenchSettings) -> None:
    """Refuse settings that cannot be timed, before any timing."""
    for n in s.sizes:
        if not 8 <= n <= MAX_SIZE:
            raise InvalidConfigError(f"--sizes: a grid side must be between 8 and {MAX_SIZE} cells, got {n}")
    for name, value in (("--repeat", s.repeat), ("--points", s.points)):
        if value < 1:
            raise InvalidConfigError(f"{name} must be >= 1, got {value}")
    if not (np.isfinite(s.budget) and s.budget > 0):
        raise InvalidConfigError(f"--budget must be a finite number of seconds > 0, got {s.budget}")


def run_from_args(args: argparse.Namespace) -> int:
    sizes, lengths = (tuple(args.sizes), tuple(args.lengths))
    if args.quick:
        sizes, lengths = (64, 128), (21,)
    settings = BenchSettings(
        sizes=sizes,
        lengths=lengths,
        dtypes=tuple(args.dtypes),
        repeat=args.repeat,
        budget=args.budget,
        points=args.points,
        scipy=not args.no_scipy,
        fft=not args.no_fft,
        dense=not args.no_dense,
    )
    _check_settings(settings)
    for length in lengths:  # bad lengths fail before any timing
        Kernels.from_cells(length)
    started = time.perf_counter()
    rows = run(settings, progress=lambda msg: print(f"  ... {msg}", flush=True))
    print()
    print(format_table(rows, settings.points))
    print()
    print(
        f"Medians of up to {settings.repeat} round-robin runs (at least {settings.min_repeat});"
        f" point queries: medians of up to 300 repeats of the same points (warm caches) and of "
        f"30 after evicting the CPU caches (cold). '~': extrapolated from dense 3D correlation "
        f"of one component at {sizes[0]}^3, L={lengths[0]}."
    )
    print(f"{environment()}; total {time.perf_counter() - started:.0f} s")
    return 0
