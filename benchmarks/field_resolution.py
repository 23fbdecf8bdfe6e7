"""How the matrix field's values scale with the grid resolution, per kernel profile.

    python benchmarks/field_resolution.py
    python benchmarks/field_resolution.py --distance 0.05 --reach 0.15 --resolutions 0.04,0.02,0.01

A flat wall, x >= 0, wide enough (1 m x 1 m) to fill the kernel across its axis, is written straight
into an occupancy grid whose cell faces lie on x = 0 at every resolution, in two forms:

- ``thin``: one cell thick, what the planner sees with ``surface_only=True`` (its default: the
  surface pre-pass leaves one layer of cells whatever the obstacle's thickness);
- ``solid``: a slab 0.24 m thick, no surface pre-pass (``surface_only=False``).

The field is evaluated with :func:`planbench.field.lazy_field` (the same numbers as the full field)
at a point ``--distance`` in front of the wall's face, for kernels with the planner's defaults
(``kernel_reach`` 0.15 m, linear taper, width = reach) and each profile. It prints ``|F_x|`` [field
units] per resolution, the ratio between consecutive resolutions, and then what the planner's
repulsion makes of it: the gain derived from ``standoff`` at each resolution (what the planners
use, times ``repulsion_gain``), and the push [m/s] at the point, with that gain and with a raw
``k_rep`` fixed at the ``--reference`` resolution (what a gain in field units would do). Takes a
few seconds.
"""

from __future__ import annotations

import argparse

import numpy as np

from planbench.field import PROFILES, KernelSpec, lazy_field
from planbench.field.scene_field import standoff_gain
from planbench.geometry.occupancy import OccupancyGrid

SPEED_MAX = 0.25  # the loop's default cruising speed [m/s]
STANDOFF = 0.10  # the loop's default stand-off [m]
HALF_SIDE = 0.5  # the wall spans y, z in [-0.5, 0.5] m
SLAB = 0.24  # thickness of the solid wall [m] (a whole number of cells at 0.04, 0.02, 0.01 m)


def wall_grid(resolution: float, thickness: float, depth: float) -> OccupancyGrid:
    """Grid covering x in [-depth, thickness + depth], y and z in [-HALF_SIDE, HALF_SIDE] [m], with
    occupancy 1 in the cells of 0 <= x < thickness. Cell faces lie on x = 0."""
    n_front = int(round(depth / resolution))
    n_wall = max(1, int(round(thickness / resolution)))
    n_side = int(round(2 * HALF_SIDE / resolution))
    data = np.zeros((n_front + n_wall + n_front, n_side, n_side))
    data[n_front : n_front + n_wall] = 1.0
    origin = np.array([-n_front * resolution, -HALF_SIDE, -HALF_SIDE])
    return OccupancyGrid(data, origin, resolution)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--distance", type=float, default=0.05, help="point to wall face [m] (default 0.05)")
    ap.add_argument("--reach", type=float, default=0.15, help="kernel reach [m] (default 0.15, the planner's)")
    ap.add_argument("--resolutions", default="0.04,0.02,0.01", help="cell sizes [m], coarse to fine")
    ap.add_argument("--reference", type=float, default=0.02, help="resolution a fixed gain is calibrated at [m]")
    args = ap.parse_args()
    resolutions = [float(r) for r in args.resolutions.split(",")]
    if args.reference not in resolutions:
        resolutions.append(args.reference)
    point = np.array([[-args.distance, 0.0, 0.0]])
    depth = args.reach + 0.1

    field: dict[tuple[str, str, float], float] = {}
    gain: dict[tuple[str, float], float] = {}
    for profile in PROFILES:
        for r in resolutions:
            kernels = KernelSpec(reach=args.reach, profile=profile, taper="linear").build(r)
            gain[profile, r] = standoff_gain(kernels, SPEED_MAX, STANDOFF)
            for wall, thickness in (("thin", r), ("solid", SLAB)):
                grid = wall_grid(r, thickness, depth)
                field[wall, profile, r] = abs(float(lazy_field(grid, kernels, point)[0, 0]))

    shown = [r for r in resolutions if r in [float(x) for x in args.resolutions.split(",")]]
    print(
        f"Field magnitude |F_x| [field units] at {args.distance:g} m from a wall, "
        f"kernel reach {args.reach:g} m, linear taper"
    )
    head = " | ".join(f"{r:g} m" for r in shown)
    ratios = " | ".join(f"{b:g}/{a:g}" for a, b in zip(shown[:-1], shown[1:], strict=True))
    print(f"\n| wall | profile | {head} | {ratios} |")
    print("|---|---|" + "---|" * (2 * len(shown) - 1))
    for wall in ("thin", "solid"):
        for profile in PROFILES:
            vals = [field[wall, profile, r] for r in shown]
            cells = " | ".join(f"{v:.4g}" for v in vals)
            rat = " | ".join(f"{b / a:.2f}x" if a > 0 else "-" for a, b in zip(vals[:-1], vals[1:], strict=True))
            print(f"| {wall} | {profile} | {cells} | {rat} |")

    ref = args.reference
    print(
        f"\nRepulsion at the same point (thin wall, as with surface_only=True), speed_max {SPEED_MAX} m/s, "
        f"standoff {STANDOFF} m"
    )
    print(
        "\n| profile | resolution | derived gain [m/s per unit] | push, derived gain [m/s] | "
        f"push, raw k_rep fixed at {ref:g} m [m/s] |"
    )
    print("|---|---|---|---|---|")
    for profile in PROFILES:
        for r in shown:
            f = field["thin", profile, r]
            print(
                f"| {profile} | {r:g} m | {gain[profile, r]:.4g} | {gain[profile, r] * f:.3f} | "
                f"{gain[profile, ref] * f:.3f} |"
            )


if __name__ == "__main__":
    main()
