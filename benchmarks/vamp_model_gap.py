"""How far planbench's robot geometry sticks out of VAMP's sphere model, per link.

Usage::

    python benchmarks/vamp_model_gap.py [--robot panda] [--configurations 20] [--points 2000]

VAMP checks collisions with spheres fitted to its own copy of the robot's meshes; planbench checks
the robot's collision meshes (example-robot-data's, through coal). For random configurations
within both robots' limits (seed 0), points are sampled on each of planbench's collision meshes
(area-weighted, ``--points`` per mesh, seed 0), placed by planbench's kinematics and moved into
VAMP's world frame, and measured against VAMP's spheres at the same configuration
(``vamp.<robot>.fk``): a point's *gap* is its distance to the nearest sphere's surface, positive when
it lies outside every sphere. Printed per link: the share of points outside every sphere, the
median and largest gap [mm] over configurations (the largest over the link's points at each). A
link whose geometry sticks out this far can touch an obstacle that VAMP's check passes.
"""

from __future__ import annotations

import argparse

import numpy as np
import pinocchio as pin
import trimesh

from planbench.robot import load_robot
from planbench_plugins.vamp_planners import vamp_robot


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--configurations", type=int, default=20)
    parser.add_argument("--points", type=int, default=2000)
    args = parser.parse_args()
    robot = load_robot(args.robot)
    vr = vamp_robot(robot)
    rng = np.random.default_rng(0)
    lower, upper = np.maximum(robot.lower, vr.lower), np.minimum(robot.upper, vr.upper)
    geoms = robot.collision_model.geometryObjects
    local: list[np.ndarray | None] = []
    for g in geoms:
        kind = type(g.geometry).__name__
        if kind == "Box":  # coal's Box keeps half sides
            mesh = trimesh.creation.box(extents=2.0 * np.asarray(g.geometry.halfSide))
        elif g.meshPath and g.meshPath.lower().endswith((".stl", ".dae", ".obj")):
            mesh = trimesh.load(g.meshPath, force="mesh")
            mesh.apply_scale(np.asarray(g.meshScale))
        else:
            local.append(None)  # another primitive: not measured
            continue
        pts, _ = trimesh.sample.sample_surface(mesh, args.points, seed=0)
        local.append(np.asarray(pts))
    data = robot.model.createData()
    gdata = pin.GeometryData(robot.collision_model)
    gaps: dict[str, list[float]] = {}  # per link: the largest gap at each configuration [m]
    outside: dict[str, list[float]] = {}  # per link: the share of its points outside every sphere
    for _ in range(args.configurations):
        q = rng.uniform(lower, upper)
        pin.forwardKinematics(robot.model, data, q)
        pin.updateGeometryPlacements(robot.model, data, robot.collision_model, gdata)
        spheres = vr.module.fk(q.astype(np.float32))
        centres = np.array([[s.x, s.y, s.z] for s in spheres])
        radii = np.array([s.r for s in spheres])
        for k, g in enumerate(geoms):
            if local[k] is None:
                continue
            M = gdata.oMg[k]
            world = local[k] @ M.rotation.T + M.translation
            world = world @ vr.base[:3, :3].T + vr.base[:3, 3]
            d = np.linalg.norm(world[:, None, :] - centres[None, :, :], axis=2) - radii[None, :]
            gap = d.min(axis=1)
            link = robot.model.frames[g.parentFrame].name
            gaps.setdefault(link, []).append(float(gap.max()))
            outside.setdefault(link, []).append(float((gap > 0).mean()))
    # several geometries of one link (the Panda's finger boxes) are pooled: the largest gap of any
    print("| link | points outside every sphere | median largest gap [mm] | largest gap [mm] |")
    print("| --- | --- | --- | --- |")
    for link, g in gaps.items():
        print(f"| {link} | {100 * np.mean(outside[link]):.1f} % | {1e3 * np.median(g):.1f} | {1e3 * np.max(g):.1f} |")


if __name__ == "__main__":
    main()
