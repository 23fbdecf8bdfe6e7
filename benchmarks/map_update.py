"""The map's update per depth frame (planbench.geometry.occupancy_map) against OctoMap's, on the
same frames.

    python benchmarks/map_update.py             # 30 frames (about a minute with OctoMap)
    python benchmarks/map_update.py --frames 60

Scene ``mbm:box/0001`` plus a ball moving through it, the Panda moving from its start towards its
goal configuration in view of the default camera (160 x 120, 5 mm range noise, 5 % dropout, as the
``dynamic`` set's depth scenarios), grid resolution 0.02 m over the default bounds (142^3 cells).
The frames are cast once; each row times only what it names, median over the frames [ms]:

- planbench map: the projective free-space marking of every pixel
  (:func:`planbench.geometry.views.mark_seen`), the log-odds update (:meth:`OccupancyMap.integrate`)
  and the dense grid handed to the controller (:meth:`OccupancyMap.grid`);
- OctoMap (``pyoctomap``, when installed): ``insertPointCloud`` of the frame's points and of a
  point beyond ``max_range`` on each ray that met nothing (cleared up to ``max_range``), the same
  sensor model (hit 0.7, miss 0.4, clamping 0.12-0.97); then, on a few frames, reading it back
  into the dense known and occupied grids a controller reads (a walk over its leaves).

Whole ``Sensor.capture`` per frame with ``memory="map"`` and ``"frame"`` closes the table: the
budget is the sensor period (33 ms at 30 Hz) on one core.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from _frames import MovingScene, median_ms

from planbench.geometry.occupancy import grid_shape
from planbench.geometry.occupancy_map import OccupancyMap
from planbench.geometry.views import mark_seen
from planbench.reactive.scenario import CameraSettings, SensingSettings
from planbench.reactive.sensing import Sensor, camera_frame, camera_rays

CAMERA = CameraSettings(position=(1.5, 0.3, 0.9), look_at=(0.4, 0.0, 0.3), noise_std=0.005, dropout=0.05)
RES = 0.02


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    args = parser.parse_args(argv)
    n = args.frames + 1
    moving = MovingScene(n)
    robot, scene, q = moving.robot, moving.scene, moving.q

    settings = SensingSettings(model="depth", resolution=RES, cameras=(CAMERA,), memory="map")
    sensor = Sensor(settings, robot)
    lower, upper = sensor.bounds
    shape = grid_shape(lower, upper, RES)
    frames = [sensor.sense(scene(k), q(k), np.random.default_rng(k)) for k in range(n)]
    origin, axes, pixel = camera_frame(CAMERA)
    _, dirs = camera_rays(CAMERA)
    print(f"mbm:box/0001 + a moving ball, Panda moving; grid {shape} at {RES} m; median of {args.frames} frames [ms]")

    ours = OccupancyMap(lower, shape, RES)

    def update(k: int) -> object:
        cloud, (free,) = frames[k]
        seen = mark_seen(
            np.zeros(shape, dtype=bool), lower, RES, origin, axes, pixel, CAMERA.width, CAMERA.height, free
        )
        ours.integrate(seen, ours.cells_of(cloud))
        return ours.grid()

    print(f"  planbench map: mark_seen + integrate + grid   {median_ms(args.frames, update):7.1f}")
    try:
        import pyoctomap
    except ImportError:
        print("  OctoMap: pyoctomap not installed (pip install pyoctomap) - row skipped")
    else:
        tree = pyoctomap.OcTree(RES)
        tree.setProbHit(0.7), tree.setProbMiss(0.4), tree.setClampingThresMin(0.12), tree.setClampingThresMax(0.97)

        def octomap(k: int) -> object:
            cloud, (free,) = frames[k]
            far = origin + 2.0 * CAMERA.max_range * dirs[free == CAMERA.max_range]
            points = np.ascontiguousarray(np.concatenate([cloud, far]))
            return tree.insertPointCloud(points, origin, max_range=CAMERA.max_range)

        print(f"  OctoMap: insertPointCloud                      {median_ms(args.frames, octomap):7.1f}")

        def dense(k: int) -> object:
            known, occupied = np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool)
            for leaf in tree.begin_leafs_bbx(lower, upper):
                size = leaf.getSize()
                lo = np.floor((np.asarray(leaf.getCoordinate()) - size / 2 - lower) / RES + 0.5).astype(int)
                hi = lo + max(1, round(size / RES))
                block = (slice(lo[0], hi[0]), slice(lo[1], hi[1]), slice(lo[2], hi[2]))
                known[block] = True
                occupied[block] = tree.isNodeOccupied(leaf)
            return known, occupied

        print(f"  OctoMap: read back into dense grids             {median_ms(3, dense):7.1f}")
    for memory in ("map", "frame"):
        s = Sensor(SensingSettings(model="depth", resolution=RES, cameras=(CAMERA,), memory=memory), robot)

        def capture(k: int, s: Sensor = s) -> object:
            return s.capture(scene(k), q(k), k / 30.0, k, np.random.default_rng(k))

        print(f"  Sensor.capture, memory={memory:<5}                 {median_ms(args.frames, capture):7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
