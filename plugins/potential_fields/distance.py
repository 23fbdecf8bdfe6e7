"""``distance-field``: Khatib repulsion from coal's exact link-obstacle distances and witness points.

Per step, at the arm's configuration (placements from the loop's own forward kinematics):

1. every moving robot geometry's world placement (``pinocchio.updateGeometryPlacements``);
2. cheap culling: a geometry's bounding sphere against an obstacle's world AABB gives a lower
   bound of their distance; pairs with that bound ``>= d0`` are skipped (no push possible), and
   the rest are visited in order of their bound, skipping a pair whose bound is not below its
   link's nearest distance found so far (only the nearest obstacle per link is needed);
3. coal's distance (GJK, EPA when penetrating) for the remaining pairs, through
   ``pinocchio.computeDistance``: signed distance ``d``, witness point ``p`` on the robot, and the
   separating normal ``n`` (from the robot towards the obstacle, also when they overlap);
4. per link (all geometries of one link), the nearest obstacle only (Khatib 1986: one point of
   closest approach per link): ``f = |f|(d) * (-n)`` applied at ``p``
   (:mod:`planbench_plugins.ik_loop.khatib`), mapped by the loop through the Jacobian of ``p``
   (support row of the link's joint).

Robot meshes are replaced by their convex hulls (coal's ``buildConvexRepresentation``): GJK/EPA
then gives signed distances and a separating direction when a link touches an obstacle (a mesh
BVH only reports 0), and a hull contains its mesh, so ``d`` never overestimates the true clearance.
Coal's octree distance queries are not used: measured at 18-22 ms per link mesh while planning
(issue 6), three orders of magnitude above these primitive-to-hull queries.
"""

from __future__ import annotations

from typing import Any

import coal
import numpy as np
import pinocchio as pin

from planbench.checking.collision import fresh_geometry_data, witnesses
from planbench.problem import Problem
from planbench.robot import link_of
from planbench_plugins.ik_loop import (
    ArmKinematics,
    ControlPoints,
    IKLoopPlanner,
    Repulsion,
    ZeroRepulsion,
    khatib_gain,
    khatib_magnitude,
)
from planbench_plugins.potential_fields.config import DistanceFieldConfig

__all__ = ["DistanceFieldPlanner", "DistanceFieldRepulsion"]


def _support_row(model: Any, joint: int) -> np.ndarray:
    """1.0 for every velocity index of ``joint`` and its ancestors (they move a point it carries)."""
    row = np.zeros(model.nv)
    j = joint
    while j > 0:
        row[model.joints[j].idx_v] = 1.0
        j = model.parents[j]
    return row


_HULLS: dict[tuple[int, str], tuple[Any, Any]] = {}
"""Convex hulls made, by the robot (its id; the entry keeps it) and geometry name: a controller
builds a repulsion per sensor frame from the same robot's meshes."""


def _hull(geometry: Any) -> Any:
    """The convex hull of a mesh (a copy; the robot's own geometry is left untouched), else the
    primitive itself."""

    if isinstance(geometry, coal.BVHModelBase):
        mesh = geometry.clone()
        mesh.buildConvexRepresentation(False)
        return mesh.convex
    return geometry


def _robot_hull(robot: Any, g: Any) -> Any:
    """:func:`_hull` of the robot's geometry object ``g``, made once per robot and geometry."""
    key = (id(robot), str(g.name))
    made = _HULLS.get(key)
    if made is None or made[0] is not robot:
        made = _HULLS[key] = (robot, _hull(g.geometry))
    return made[1]


class DistanceFieldRepulsion:
    """Nearest-obstacle Khatib push per robot link at coal's witness point (module docstring).

    ``link_names`` (L,) the links, one output row each; rows of links with no obstacle within
    ``d0`` have zero push (their point is the link's first geometry's centre). After
    :meth:`forces`, ``distance`` (L,) holds each link's nearest distance [m] (``inf`` when culled).
    """

    def __init__(self, robot: Any, scene: Any, gain: float, influence_distance: float, floor: float) -> None:

        self._pin = pin
        self.gain, self.d0, self.floor = float(gain), float(influence_distance), float(floor)
        self.model = model = robot.model
        gm = pin.GeometryModel()
        robot_geoms = [g for g in robot.collision_model.geometryObjects if g.parentJoint != 0]
        links: list[str] = []
        link_of_geom, centres, radii = [], [], []
        for g in robot_geoms:
            geom = _robot_hull(robot, g)
            geom.computeLocalAABB()
            lo, hi = np.array(geom.aabb_local.min_), np.array(geom.aabb_local.max_)
            centres.append(0.5 * (lo + hi))
            radii.append(0.5 * float(np.linalg.norm(hi - lo)))
            obj = pin.GeometryObject(g.name, int(g.parentJoint), int(g.parentFrame), g.placement, geom)
            gm.addGeometryObject(obj)
            link = link_of(g.name)
            if link not in links:
                links.append(link)
            link_of_geom.append(links.index(link))
        self.n_robot = len(robot_geoms)
        self.link_names = tuple(links)
        self._link_of_geom = np.array(link_of_geom, dtype=np.intp)
        self._centre_local = np.array(centres).reshape(-1, 3)
        self._radius = np.array(radii)
        geom_joint = np.array([int(g.parentJoint) for g in robot_geoms], dtype=np.intp)
        # one joint per link (a link's geometries are rigidly attached to it)
        self.joint = np.array([geom_joint[self._link_of_geom == i][0] for i in range(len(links))], dtype=np.intp)
        self.support = np.array([_support_row(model, int(j)) for j in self.joint]).reshape(len(links), model.nv)
        lo_obs, hi_obs, octree = [], [], []
        for obstacle in scene.obstacles:
            gid = gm.addGeometryObject(
                pin.GeometryObject(
                    f"obstacle:{obstacle.name}", 0, 0, obstacle.placement(), obstacle.collision_geometry()
                )
            )
            lo, hi = obstacle.aabb()
            lo_obs.append(lo)
            hi_obs.append(hi)
            octree.append(isinstance(obstacle.collision_geometry(), coal.OcTree))
            for rid in range(self.n_robot):
                gm.addCollisionPair(pin.CollisionPair(rid, gid))
        self.n_obstacles = len(lo_obs)
        self._octree = np.array(octree, dtype=bool)  # coal's witnesses of these need correcting
        self._obs_lo = np.array(lo_obs).reshape(-1, 3)
        self._obs_hi = np.array(hi_obs).reshape(-1, 3)
        # pair index of (robot geometry r, obstacle o), as pinocchio stored it
        self._pair = np.empty((self.n_robot, self.n_obstacles), dtype=np.intp)
        for k, pair in enumerate(gm.collisionPairs):
            r, o = sorted((pair.first, pair.second))
            self._pair[r, o - self.n_robot] = k
        self.geometry_model = gm
        self._data = None
        self._geom_data = fresh_geometry_data(gm)
        self._oMg = [self._geom_data.oMg[i] for i in range(self.n_robot)]
        L = len(links)
        self.points = np.zeros((L, 3))
        self.F = np.zeros((L, 3))
        self.distance = np.full(L, np.inf)
        self.n_pairs_checked = 0
        """Pairs handed to coal in the last call (after culling)."""

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pin = self._pin
        gm, gd = self.geometry_model, self._geom_data
        pin.updateGeometryPlacements(kin.model, kin.data, gm, gd)
        R = np.array([M.rotation for M in self._oMg])
        t = np.array([M.translation for M in self._oMg])
        centre = np.einsum("gij,gj->gi", R, self._centre_local) + t  # (G, 3)
        # lower bound of each (geometry, obstacle) distance: sphere to box
        c = centre[:, None]
        gap = np.maximum(self._obs_lo[None] - c, 0.0) + np.maximum(c - self._obs_hi[None], 0.0)
        bound = np.sqrt(np.einsum("goa,goa->go", gap, gap)) - self._radius[:, None]
        near = np.argwhere(bound < self.d0)
        near = near[np.argsort(bound[near[:, 0], near[:, 1]], kind="stable")]  # nearest bound first
        best = self.distance
        best.fill(np.inf)
        F, points = self.F, self.points
        F.fill(0.0)
        normals = np.zeros((len(best), 3))
        first = np.ones(len(best), dtype=bool)
        checked = 0
        for r, o in near:
            link = self._link_of_geom[r]
            if bound[r, o] >= best[link]:  # cannot beat this link's nearest so far
                continue
            res = pin.computeDistance(gm, gd, int(self._pair[r, o]))
            checked += 1
            d = res.min_distance
            if d < best[link]:
                best[link] = d
                points[link], _, normals[link] = witnesses(res, bool(self._octree[o]))
                first[link] = False
        self.n_pairs_checked = checked
        for link in np.flatnonzero(first):
            points[link] = centre[int(np.argmax(self._link_of_geom == link))]
        mag = khatib_magnitude(best, self.gain, self.d0, self.floor)
        F[:] = -mag[:, None] * normals  # away from the obstacle (coal's normal points robot -> obstacle)
        return points, F, self.support, self.joint


class DistanceFieldPlanner(IKLoopPlanner):
    """``distance-field``: the shared IK loop (:mod:`planbench_plugins.ik_loop.loop`) with
    Khatib repulsion from coal's exact distances (:class:`DistanceFieldRepulsion`). Settings:
    :class:`~planbench_plugins.potential_fields.config.DistanceFieldConfig`."""

    name = "distance-field"
    Config = DistanceFieldConfig

    def make_repulsion(self, problem: Problem, points: ControlPoints) -> Repulsion:
        """The robot's hulls and the scene's obstacles in one geometry model; the gain from the stand-off."""
        cfg = self.config
        gain = cfg.repulsion_gain * khatib_gain(cfg.speed_max, cfg.standoff, cfg.influence_distance)
        if len(problem.scene) == 0 or gain <= 0:
            return ZeroRepulsion()
        return DistanceFieldRepulsion(problem.robot, problem.scene, gain, cfg.influence_distance, cfg.distance_floor)
