"""CLI subcommands of the matrix field: ``field``, ``kernel`` and ``bench-field``.

``planbench.cli.main`` calls :func:`add_commands` with its argparse subparsers; each command's ``func``
takes the parsed arguments and returns an exit code.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

import planbench
from planbench.errors import InvalidConfigError
from planbench.field import full_field, surface_grid
from planbench.field.bench import add_arguments, run_from_args
from planbench.field.kernels import PROFILES, TAPERS, KernelSpec
from planbench.files.inputs import check_writable
from planbench.files.outputs import check_output
from planbench.geometry.occupancy import OccupancyGrid

log = logging.getLogger(__name__)

__all__ = ["add_commands"]


def add_commands(subparsers: Any) -> None:
    """Add ``field``, ``kernel`` and ``bench-field`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "field",
        help="plot the matrix field of a problem's scene on a slice (PNG)",
        description="Voxelize a problem's scene, compute its matrix field and plot a slice: colour "
        "= field magnitude, arrows = in-plane direction, grey = obstacles.",
    )
    p.add_argument(
        "--problem", default="mbm:box/0001", help="problem selector or file; the first problem's scene is used"
    )
    p.add_argument("--slice", default="z=0.3", help="plane to draw, axis=value [m] (default z=0.3)")
    p.add_argument("--resolution", type=float, default=0.02, help="grid cell size [m]")
    p.add_argument(
        "--surface", action="store_true", help="apply the surface pre-pass (keep occupied cells with a free neighbour)"
    )
    p.add_argument("--outside", type=float, default=0.0, help="occupancy beyond the grid: 0 free, 1 walled in")
    _kernel_arguments(p, reach=0.2)
    p.add_argument("--out", default="field.png", help="PNG file to write")
    p.set_defaults(func=cmd_field)

    p = subparsers.add_parser(
        "kernel",
        help="plot a directional kernel's shape, or all profiles (PNG)",
        description="Plot the kernel K_x (factors, slices, surface) for the chosen settings; with "
        "--profile all, compare every profile and taper instead.",
    )
    _kernel_arguments(p, reach=0.2, allow_all=True)
    p.add_argument("--resolution", type=float, default=0.01, help="cell size [m]")
    p.add_argument("--out", default="kernel.png", help="PNG file to write")
    p.set_defaults(func=cmd_kernel)

    p = subparsers.add_parser(
        "bench-field",
        help="benchmark the matrix field against dense, FFT and distance transform",
        description="Time the full field (separable, compiled and scipy), dense 3D correlation, "
        "FFT and a Euclidean distance transform + gradient, and the lazy and "
        "precomputed point queries; print medians and ratios measured in one run.",
    )
    add_arguments(p)
    p.set_defaults(func=cmd_bench)


def _kernel_arguments(p: argparse.ArgumentParser, reach: float, allow_all: bool = False) -> None:
    profiles = (*PROFILES, "all") if allow_all else PROFILES
    p.add_argument("--profile", choices=profiles, default="linear", help="profile along the axis")
    p.add_argument("--taper", choices=TAPERS, default="linear", help="taper across the axis")
    p.add_argument("--reach", type=float, default=reach, help="kernel reach along the axis [m]")
    p.add_argument(
        "--width", type=float, default=None, help="kernel half-width across the axis [m] (default: the reach)"
    )
    p.add_argument("--gain", type=float, default=1.0, help="field gain")
    p.add_argument("--sigma", type=float, default=None, help="gaussian profile sigma [m]")
    p.add_argument("--power", type=float, default=2.0, help="inverse-power exponent")


def _spec(args: argparse.Namespace) -> KernelSpec:
    return KernelSpec(
        reach=args.reach,
        width=args.width,
        profile=args.profile,
        taper=args.taper,
        gain=args.gain,
        sigma=args.sigma,
        power=args.power,
    )


def cmd_field(args: argparse.Namespace) -> int:
    # plots on use: matplotlib takes ~0.3 s to import, and this module loads with the CLI (planbench --help)
    from planbench.field.plots import parse_slice, plot_field_slice

    axis, value = parse_slice(args.slice)
    if not 0.0 <= args.outside <= 1.0:
        raise InvalidConfigError(f"--outside is an occupancy in [0, 1] (0 free, 1 walled in), got {args.outside}")
    check_writable(args.out, "--out", folder_made=True)
    check_output(args.out)
    problem = planbench.load_problems(args.problem)[0]
    kernels = _spec(args).build(args.resolution)
    grid = OccupancyGrid.from_scene(problem.scene, args.resolution, padding=kernels.reach, outside=args.outside)
    if args.surface:
        grid = surface_grid(grid)
    field = full_field(grid, kernels)
    name = getattr(problem, "id", None) or getattr(problem, "name", "") or args.problem
    surface = ", surface cells" if args.surface else ""
    title = (
        f"{name}: matrix field on {args.slice} m ({args.profile} profile, reach "
        f"{kernels.reach:g} m, {args.resolution:g} m cells{surface})"
    )
    plot_field_slice(grid, field, axis, value, out=args.out, title=title)
    print(f"wrote {args.out} (grid {grid.shape[0]}x{grid.shape[1]}x{grid.shape[2]} cells)")
    return 0


def cmd_kernel(args: argparse.Namespace) -> int:
    from planbench.field.plots import plot_kernel, plot_profiles  # matplotlib on use, as in cmd_field

    check_writable(args.out, "--out", folder_made=True)
    check_output(args.out)
    if args.profile == "all":
        plot_profiles(reach=args.reach, resolution=args.resolution, out=args.out)
    else:
        kernels = _spec(args).build(args.resolution)
        n_l, n_w = len(kernels.along), len(kernels.across)
        title = (
            f"Kernel K_x: {args.profile} profile, {args.taper} taper, reach "
            f"{kernels.reach:g} m ({n_l} x {n_w} x {n_w} cells of {args.resolution:g} m)"
        )
        plot_kernel(kernels, out=args.out, title=title)
    print(f"wrote {args.out}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    return run_from_args(args)
