"""Per-frame cost of the sensing models (planbench.reactive.sensing) on a MotionBenchMaker scene.

    python benchmarks/sensing.py               # 20 frames per row (a few seconds)
    python benchmarks/sensing.py --frames 50

Scene ``mbm:box/0001`` (7 primitives) plus a ball that moves every frame; the Panda moves from its
start towards its goal configuration over the frames, in view of the camera; grid resolution
0.02 m over the default bounds (the cube of half side reach + 0.1 m, 142^3 cells). Rows (medians
over the frames, after one untimed warm-up frame) [ms]:

- truth, fresh: ``OccupancyGrid.from_scene`` of the whole scene each frame (what caching saves);
- truth: ``Sensor.capture`` (unmoved obstacles cached, the ball voxelised each frame);
- depth WxH: ``Sensor.capture`` with one camera (ray casting, noise, dropout, robot removal and
  ``OccupancyGrid.from_points``), and of that the point cloud alone (``Sensor.point_cloud``).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np
from _frames import MovingScene, median_ms

from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.scenario import CameraSettings, SensingSettings
from planbench.reactive.sensing import Sensor, camera_rays

CAMERA = CameraSettings(position=(1.5, 0.3, 0.9), look_at=(0.4, 0.0, 0.3), noise_std=0.005, dropout=0.05)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    args = parser.parse_args(argv)
    n = args.frames + 1
    moving = MovingScene(n)
    robot, start, scene, q = moving.robot, moving.start, moving.scene, moving.q

    origin, dirs = camera_rays(CAMERA)
    hand = robot.frame_pose(start).translation
    in_view = (dirs @ ((hand - origin) / np.linalg.norm(hand - origin))).max() > 0.9999
    rng = np.random.default_rng(0)
    res = 0.02
    print(f"mbm:box/0001 + a moving ball, Panda ({'hand in view' if in_view else 'hand NOT in view'}), ", end="")
    print(f"resolution {res} m, median of {args.frames} frames [ms]")

    truth = Sensor(SensingSettings(model="truth", resolution=res), robot)
    bounds = truth.bounds
    print(f"  grid {OccupancyGrid.empty(bounds[0], bounds[1], res).shape}")
    fresh = median_ms(args.frames, lambda k: OccupancyGrid.from_scene(scene(k), res, bounds=bounds))
    print(f"  truth, fresh from_scene     {fresh:7.1f}")
    cached = median_ms(args.frames, lambda k: truth.capture(scene(k), q(k), 0.0, k, rng))
    print(f"  truth (cached)              {cached:7.1f}")
    for width, height in ((160, 120), (320, 240)):
        cam = replace(CAMERA, width=width, height=height)
        sensor = Sensor(SensingSettings(model="depth", resolution=res, cameras=(cam,)), robot)

        def capture(k: int, s: Sensor = sensor) -> object:
            return s.capture(scene(k), q(k), 0.0, k, rng)

        def cloud_of(k: int, s: Sensor = sensor) -> object:
            return s.point_cloud(scene(k), q(k), rng)

        total = median_ms(args.frames, capture)
        cloud = median_ms(args.frames, cloud_of)
        points = len(sensor.point_cloud(scene(0), q(0), rng))
        print(f"  depth {width}x{height:<4}  capture {total:7.1f}   point cloud {cloud:6.1f}   ({points} points)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
