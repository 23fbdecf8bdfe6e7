"""Distances between robot bodies and point-cloud obstacles for certified checking.

coal answers a mesh-to-octree distance in tens of milliseconds to over a hundred on a 30k-cube
depth-camera cloud (its octree traversal prunes poorly on thin shells), a hull-to-octree one in
about 1-2 ms. Certification needs thousands of such queries per path. So for a pair of a robot
body and a cloud (:mod:`planbench.geometry.pointcloud`: a union of lattice cubes) the certified checker
uses instead:

- **bound**: the body's bounding sphere (centre and radius from its local AABB) against the cubes,
  ``signed_distance(centre) - radius`` from the cloud's k-d tree (~20 us). Every point of the body
  lies within the sphere, so this is a lower bound of the body's distance.
- **exact**: coal's collision test of the body against the octree (~10-40 us); when they touch or
  overlap, minus the deepest contact coal reports (the depth into one cube, a lower bound of the
  depth into the union). Otherwise the body's distance to the union's boundary surface (a coal
  BVH of the exposed cube faces, ~0.5 ms): outside the union the nearest point of the union lies on
  its boundary, so the two distances are equal.

The same octree is what :class:`~planbench.checking.collision.CollisionChecker` tests, so "free" means the
same in both.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import coal
import numpy as np

__all__ = ["CloudPair", "cloud_pairs"]


@dataclass
class CloudPair:
    """One (robot body, cloud obstacle) pair: geometry indices, the body's geometry and bounding
    sphere (centre in its own frame [m], radius [m]), the cloud and its octree."""

    robot: int
    obstacle: int
    geometry: Any
    centre: np.ndarray
    radius: float
    cloud: Any
    octree: Any

    def __post_init__(self) -> None:
        self._collision = coal.CollisionRequest()
        self._collision.enable_contact = True
        self._collision.num_max_contacts = 64
        self._distance = coal.DistanceRequest()
        self._distance.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess

    def bound(self, oMg: Any) -> float:
        """A lower bound [m] of the pair's distance with bodies placed at ``oMg`` (pinocchio's)."""
        body, obstacle = oMg[self.robot], oMg[self.obstacle]
        local = obstacle.actInv(body.act(self.centre))
        return float(self.cloud.signed_distance(np.asarray(local)[None])[0]) - self.radius

    def exact(self, oMg: Any) -> float:
        """The pair's signed distance [m] (module docstring for the depth when overlapping)."""
        body, obstacle = oMg[self.robot], oMg[self.obstacle]
        tb = coal.Transform3s(body.rotation, body.translation)
        to = coal.Transform3s(obstacle.rotation, obstacle.translation)
        hit = coal.CollisionResult()
        if coal.collide(self.geometry, tb, self.octree, to, self._collision, hit):
            return min(0.0, *(c.penetration_depth for c in hit.getContacts()))
        return float(coal.distance(self.geometry, tb, self.cloud.surface, to, self._distance, coal.DistanceResult()))


def cloud_pairs(geometry_model: Any, pairs: list[tuple[int, int]], scene: Any, n_robot: int) -> dict[int, CloudPair]:
    """The pairs (index into ``pairs``) of a robot body and a ``pointcloud`` obstacle of ``scene``."""
    clouds = {f"obstacle:{o.name}": o for o in scene.obstacles if o.type == "pointcloud"}
    if not clouds:
        return {}
    objects = geometry_model.geometryObjects
    out = {}
    for k, (a, b) in enumerate(pairs):
        robot, other = (a, b) if b >= n_robot else (b, a)
        obstacle = clouds.get(objects[other].name) if other >= n_robot and robot < n_robot else None
        if obstacle is None:
            continue
        geom = objects[robot].geometry
        geom.computeLocalAABB()
        lo, hi = np.asarray(geom.aabb_local.min_), np.asarray(geom.aabb_local.max_)
        out[k] = CloudPair(
            robot,
            other,
            geom,
            0.5 * (lo + hi),
            0.5 * float(np.linalg.norm(hi - lo)),
            obstacle.cloud(),
            objects[other].geometry,
        )
    return out
