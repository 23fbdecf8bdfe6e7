"""Point-cloud scenes: what a 50k-point depth-camera cloud costs to load, voxelize and validate
against, next to the old route of one box obstacle per occupied cell.

The cloud: the shipped example's cameras (``planbench.reactive.depth_example``) at 400x300 pixels, the
first ``--points`` points (default 50,000) kept unthinned, as a ``pointcloud`` obstacle of point
radius 5 mm (1 cm cubes). Printed (median of ``--repeats``):

- load + octree: reading the .npz, building the cubes and coal's octree;
- surface BVH: the cubes' boundary mesh that certified distances use (built once per cloud);
- scene_grid: the 2 cm grid the field planners and OMPL's grid checker use;
- validation per path: ``planbench.evaluate`` (certified verdict and clearance) of the paths that
  straight-line, ompl-rrtconnect and matrix-field return, with a fresh problem each repeat.

The boxes route (one ``box`` obstacle per cube, what users had to do before) is measured on the
same cubes made coarser (``--boxes-radius``, default 2 cm: 4 cm cubes) because at 1 cm it takes
minutes per path; the cloud route is measured on those coarse cubes too, for the comparison.

    .venv/bin/python benchmarks/pointcloud.py [--points 50000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import planbench
from planbench.geometry.occupancy import scene_grid
from planbench.geometry.pointcloud import VoxelCloud, load_cloud, read_points, write_points
from planbench.problem import Problem
from planbench.reactive.depth_example import EXAMPLE, example_cloud
from planbench.scene import Obstacle, Scene

PLANNERS = ("straight-line", "ompl-rrtconnect", "matrix-field")


def _median(f, repeats: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def _problem(source: Problem, scene: Scene) -> Problem:
    return Problem.create(source.robot, scene, source.start, source.goal.q, source.goal.pose, id="pointcloud-bench")


def _cloud_scene(path: Path, radius: float) -> Scene:
    return Scene((Obstacle("cloud", "pointcloud", path=str(path), radius=radius),))


def _boxes_scene(cloud: VoxelCloud) -> Scene:
    size = (cloud.cell,) * 3
    return Scene(tuple(Obstacle(f"cell-{i}", "box", tuple(c), size=size) for i, c in enumerate(cloud.centres.tolist())))


def _validate(source: Problem, scene: Scene, paths: dict[str, planbench.PlanResult], repeats: int) -> dict[str, float]:
    out = {}
    for name, result in paths.items():
        out[name] = _median(lambda r=result: planbench.evaluate(_problem(source, scene), r), repeats)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=50_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--boxes-radius", type=float, default=0.02)
    args = ap.parse_args()
    source, points = example_cloud(replace(EXAMPLE, width=400, height=300, radius=1e-4))
    points = points[: args.points]
    tmp = Path(tempfile.mkdtemp())
    write_points(tmp / "cloud.npz", points)
    radius = EXAMPLE.radius

    def load() -> None:  # load_cloud caches per file: build what it builds, uncached
        VoxelCloud.from_points(read_points(tmp / "cloud.npz"), 2 * radius).octree()

    t_load = _median(load, args.repeats)
    cloud = load_cloud(tmp / "cloud.npz", radius)
    t_surface = _median(lambda: VoxelCloud(cloud.cells, cloud.cell).surface, args.repeats)
    scene = _cloud_scene(tmp / "cloud.npz", radius)
    t_grid = _median(lambda: scene_grid(scene, 0.02, 0.1, robot=source.robot), args.repeats)
    problem = _problem(source, scene)
    paths = {}
    for name in PLANNERS:
        paths[name] = planbench.plan(problem, planbench.make_planner(name), seed=0, time_limit=5.0)
    t_valid = _validate(source, scene, paths, args.repeats)
    print(f"cloud: {len(points)} points -> {len(cloud)} cubes of {cloud.cell * 100:g} cm")
    print(f"load + octree            {t_load * 1e3:8.1f} ms")
    print(f"surface BVH              {t_surface * 1e3:8.1f} ms")
    print(f"scene_grid (2 cm)        {t_grid * 1e3:8.1f} ms")
    for name, t in t_valid.items():
        ev = planbench.evaluate(problem, paths[name])
        waypoints = paths[name].path
        n = 0 if waypoints is None else len(waypoints)
        print(f"evaluate {name:<16}{t * 1e3:8.1f} ms  ({n} waypoints, {ev.status}, success {ev.success})")

    coarse = VoxelCloud.from_points(points, 2 * args.boxes_radius)
    write_points(tmp / "coarse.npz", coarse.centres)
    coarse_scene = _cloud_scene(tmp / "coarse.npz", args.boxes_radius)
    boxes = _boxes_scene(coarse)
    print(f"\ncoarse: {len(coarse)} cubes of {coarse.cell * 100:g} cm; pointcloud obstacle vs one box per cube")
    for label, sc in (("pointcloud", coarse_scene), ("boxes", boxes)):
        t = time.perf_counter()
        grid = scene_grid(sc, 0.02, 0.1, robot=source.robot)
        t_g = time.perf_counter() - t
        t_v = _validate(source, sc, paths, 1)
        occupied = int((grid.data > 0).sum()) if grid is not None else 0
        cells = ", ".join(f"{n} {v * 1e3:.0f} ms" for n, v in t_v.items())
        print(f"{label:<11} scene_grid {t_g * 1e3:8.1f} ms ({occupied} cells); evaluate: {cells}")


if __name__ == "__main__":
    main()
