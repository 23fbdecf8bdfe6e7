"""The shipped depth-camera example: a MotionBenchMaker scene seen by two simulated depth cameras,
as a problem whose only obstacle is the point cloud they return.

Regenerate it (deterministic for a seed) with ``python -m planbench.reactive.depth_example [OUT_DIR]``;
by default it rewrites ``planbench/data/examples``. The cameras are those of
:mod:`planbench.reactive.sensing` (Embree ray casting, range noise along each ray, the robot
removed by its geometry at the start configuration), cropped to the cube the arm can reach (as the
reactive benchmark's grid is). The cloud is thinned to one point per cube
of the obstacle's geometry (edge ``2 * POINT_RADIUS``), which keeps the file small and changes
nothing the planners or the validator see. A camera sees only front surfaces: what the obstacles
hide is free space in this problem, as it would be for a planner fed the real sensor.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from planbench.geometry.pointcloud import VoxelCloud, write_points

__all__ = ["DepthExample", "EXAMPLE", "make_example"]

POINT_RADIUS = 0.005
"""Point radius of the example cloud [m]: cubes of 1 cm."""


@dataclass(frozen=True)
class DepthExample:
    """What the example is made of. Lengths in m."""

    name: str = "depth_camera_table"
    source: str = "mbm:table_pick/0002"
    """The MotionBenchMaker problem whose scene is seen and whose start and goal are kept (one whose
    straight start-goal motion collides, so that planners have work to do)."""
    cameras: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
        ((1.5, -0.2, 1.1), (0.35, -0.95, 0.35)),
        ((-0.6, -0.1, 1.2), (0.35, -0.95, 0.35)),
    )
    """(optical centre, look-at point) of each camera [m], in the robot's base frame: both above the
    table, on the robot's side, aimed at the objects."""
    width: int = 320
    height: int = 240
    noise_std: float = 0.002
    """Range noise along each ray [m]."""
    dropout: float = 0.02
    seed: int = 0
    radius: float = POINT_RADIUS


EXAMPLE = DepthExample()


def example_cloud(spec: DepthExample = EXAMPLE) -> tuple[Any, np.ndarray]:
    """The source problem and the cameras' (N, 3) points [m], one per occupied cube."""
    from planbench.problems.datasets import load_problems
    from planbench.reactive.scenario import CameraSettings, SensingSettings, default_bounds
    from planbench.reactive.sensing import Sensor

    problem = load_problems(spec.source)[0]
    cameras = tuple(
        CameraSettings(
            position=pos,
            look_at=at,
            width=spec.width,
            height=spec.height,
            noise_std=spec.noise_std,
            dropout=spec.dropout,
        )
        for pos, at in spec.cameras
    )
    sensor = Sensor(SensingSettings(model="depth", cameras=cameras), problem.robot)
    points = sensor.point_cloud(problem.scene, problem.start, np.random.default_rng(spec.seed))
    lo, hi = default_bounds(problem.robot, 0.1)  # what the arm can reach, as the sensing benchmark crops
    points = points[np.all((points >= lo) & (points <= hi), axis=1)]
    cell = 2.0 * spec.radius
    _, first = np.unique(np.floor(points / cell).astype(np.int64), axis=0, return_index=True)
    return problem, points[np.sort(first)]


def make_example(out_dir: str | Path, spec: DepthExample = EXAMPLE) -> Path:
    """Write ``<name>.npz`` and ``<name>.json`` (the problem) into ``out_dir``; the problem's path."""
    from planbench.problem import Problem
    from planbench.scene import Obstacle, Scene

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    source, points = example_cloud(spec)
    if len(points) == 0:
        raise RuntimeError(f"the cameras of {spec} see nothing of {spec.source}'s scene; aim them at it")
    cloud_file = out / f"{spec.name}.npz"
    write_points(cloud_file, points)
    obstacle = Obstacle("camera-cloud", "pointcloud", path=str(cloud_file), radius=spec.radius)
    scene = Scene((obstacle,), f"examples:{spec.name}")
    problem = Problem.create(
        source.robot,
        scene,
        source.start,
        source.goal.q,
        source.goal.pose,
        source.tolerances,
        id=f"examples:{spec.name}",
        metadata={
            "set": "examples",
            "source": spec.source,
            "generator": "planbench.reactive.depth_example",
            "seed": spec.seed,
            "cameras": [{"position": list(p), "look_at": list(a)} for p, a in spec.cameras],
            "image": [spec.width, spec.height],
            "noise_std": spec.noise_std,
            "dropout": spec.dropout,
            "points": len(points),
        },
    )
    check = problem.check()
    if not check.ok:
        raise RuntimeError(f"the example's start or goal collides with its cloud: {check.messages()}")
    d = problem.to_dict()
    d["scene"]["obstacles"][0]["path"] = cloud_file.name  # relative to the problem file
    target = out / f"{spec.name}.json"
    target.write_text(json.dumps(d, indent=1) + "\n")
    return target


def shipped_example_dir() -> Path:
    """Where the shipped example lives (inside the installed package)."""
    return Path(str(resources.files("planbench") / "data" / "examples"))


def _summary(cloud: VoxelCloud) -> str:
    lo, hi = cloud.bounds()
    return f"{len(cloud)} cubes of {cloud.cell * 100:g} cm, from {np.round(lo, 3)} to {np.round(hi, 3)} m"


if __name__ == "__main__":
    path = make_example(sys.argv[1] if len(sys.argv) > 1 else shipped_example_dir())
    from planbench.problem import Problem

    p = Problem.load(path)
    print(f"wrote {path} ({path.stat().st_size} B) and its cloud: {_summary(p.scene.obstacles[0].cloud())}")
