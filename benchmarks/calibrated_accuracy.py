"""Accuracy of the calibrated field's distance against the exact distance transform (issue 32).

    python benchmarks/calibrated_accuracy.py
    python benchmarks/calibrated_accuracy.py --problems "mbm:*/0001" tuning/panda/0000.json tuning/ur5/0005.json

For each problem's scene, voxelized as the planners do (:func:`planbench.geometry.occupancy.scene_grid`,
rule ``"any"``, margin reach plus a cell, no surface pass), the calibrated distance at every free cell
centre with ``0 < d_edt <= reach`` (:func:`planbench.field.calibrated.calibrated_full`) against the
signed distance transform of the same grid (scipy's ``distance_transform_edt`` to the occupied cells'
faces, as ``edt-field`` computes it). Prints per resolution and sigma the median, p95 and largest
absolute error in cells of that resolution (and the signed median: > 0 = the calibrated field
over-estimates the clearance).

Resolution: the same points (the cell centres of the coarsest grid, 0 < d_edt <= reach there) are
evaluated on every grid with :func:`planbench.field.calibrated.calibrated_at`, and the difference
from the coarsest grid's value is printed in millimetres, beside the same difference of the EDT
(the voxelization itself moves the obstacles' faces by up to a cell).
"""

from __future__ import annotations

import argparse

import numpy as np

from planbench.field.calibrated import CalibratedSpec, calibrated_at, calibrated_full
from planbench.geometry.occupancy import scene_grid
from planbench.problems.datasets import load_problems
from planbench_plugins.potential_fields.edt import signed_distance

PROBLEMS = ("mbm:*/0001",)
"""Default: the first MotionBenchMaker problem of each family (the tuning range); add generated
scenes of the tuning seed as files (``benchmarks/tuning_set.py --seed 1``)."""


def _edt_at(sd: np.ndarray, grid, points: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The EDT's signed distance at the cell containing each point."""
    idx = np.floor((points - grid.origin) / grid.resolution).astype(int)
    idx = np.clip(idx, 0, np.array(sd.shape) - 1)
    return sd[idx[:, 0], idx[:, 1], idx[:, 2]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", nargs="+", default=list(PROBLEMS))
    ap.add_argument("--sigmas", default="0.01,0.015,0.02,0.03")
    ap.add_argument("--resolutions", default="0.02,0.01")
    ap.add_argument("--reach", type=float, default=0.15)
    ap.add_argument("--points", type=int, default=4000, help="resolution check: points per problem")
    args = ap.parse_args()
    sigmas = [float(s) for s in args.sigmas.split(",")]
    resolutions = [float(r) for r in args.resolutions.split(",")]
    rng = np.random.default_rng(0)
    errors: dict[tuple[float, float], list[np.ndarray]] = {}
    res_diff: dict[tuple[float, float], list[np.ndarray]] = {}
    problems = [p for selector in args.problems for p in load_problems(selector)]
    for problem in problems:
        ref = problem.id
        coarse_pts: np.ndarray | None = None
        coarse_vals: dict[float, np.ndarray] = {}
        coarse_edt: np.ndarray | None = None
        for r in resolutions:
            grid = scene_grid(problem.scene, r, args.reach + r, robot=problem.robot)
            if grid is None:
                continue
            sd = signed_distance(np.asarray(grid.data) > 0, r)
            free = (sd > 0) & (sd <= args.reach)
            if coarse_pts is None:
                centres = np.argwhere(free)
                pick = rng.choice(len(centres), size=min(args.points, len(centres)), replace=False)
                coarse_pts = grid.origin + (centres[pick] + 0.5) * r
                coarse_edt = sd[tuple(centres[pick].T)]
            for sigma in sigmas:
                kernel = CalibratedSpec(sigma=sigma, reach=args.reach).build(r)
                field = calibrated_full(grid, kernel)
                d = args.reach + np.asarray(field.deficit.components[0])
                err = (d[free] - sd[free]) / r
                errors.setdefault((r, sigma), []).append(err)
                at, _ = calibrated_at(grid, kernel, coarse_pts)
                if r == resolutions[0]:
                    coarse_vals[sigma] = at
                else:
                    res_diff.setdefault((r, sigma), []).append(at - coarse_vals[sigma])
            if r != resolutions[0]:
                res_diff.setdefault((r, -1.0), []).append(_edt_at(sd, grid, coarse_pts) - coarse_edt)
        print(f"done {ref}", flush=True)
    print("\n| resolution [m] | sigma [m] | cells | median abs error [cells] | p95 [cells] | max [cells] |", end="")
    print(" signed median [cells] |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for (r, sigma), errs in errors.items():
        e = np.concatenate(errs)
        a = np.abs(e)
        print(
            f"| {r:g} | {sigma:g} | {len(e)} | {np.median(a):.3f} | {np.percentile(a, 95):.3f} | "
            f"{a.max():.3f} | {np.median(e):+.3f} |"
        )
    print(f"\nSame points, value minus the value at {resolutions[0]:g} m [mm] (sigma -1 = the EDT itself):")
    print("| resolution [m] | sigma [m] | median abs [mm] | p95 [mm] |")
    print("| --- | --- | --- | --- |")
    for (r, sigma), diffs in res_diff.items():
        a = np.abs(np.concatenate(diffs)) * 1000
        a = a[np.isfinite(a)]
        print(f"| {r:g} | {sigma:g} | {np.median(a):.2f} | {np.percentile(a, 95):.2f} |")


if __name__ == "__main__":
    main()
