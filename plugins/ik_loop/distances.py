"""Exact distances between a robot's geometries and a scene's obstacles, and between the robot's
own geometries (coal): ``matrix-field-qp``'s collision constraints and the loop's self-collision
push (:mod:`.self_collision`).

One ``pinocchio.GeometryModel`` holds the robot's collision geometries (a mesh replaced by its
convex hull) and every obstacle of the scene (its own coal geometry), with one distance pair per
(moving robot geometry, obstacle) and, optionally, the robot's own self-collision pairs (those of
its collision model, the SRDF's exclusions already removed). Per step, at the configuration the
loop's kinematics were last updated to (``kin.data``):

1. the robot geometries' world placements (``pinocchio.updateGeometryPlacements``);
2. culling: bounding spheres of the robot geometries against each other and against the
   obstacles' world AABBs give lower bounds of the pairs' distances; pairs whose bound is at least
   the influence distance are skipped;
3. coal's distance (GJK, EPA when the two overlap) for the remaining pairs: signed distance ``d``
   [m], the witness points on both bodies [m], and the unit normal ``n`` from the first body (a
   robot geometry) towards the second (an obstacle, or another robot geometry).

A convex hull (qhull, as :mod:`planbench.checking.certified` builds them) contains its mesh, so ``d`` never
overestimates the true clearance: a constraint that keeps the hulls apart keeps the meshes apart.
(``buildConvexRepresentation`` is not a hull: it keeps a mesh's own triangles, and on a non-convex
mesh such as the UR5's GJK then overestimates distances by centimetres.) Hull-to-primitive queries
cost a few microseconds each; coal's mesh (BVH) queries cost tens to hundreds.
"""

from __future__ import annotations

import weakref
from typing import Any, NamedTuple

import coal
import numpy as np
import pinocchio as pin

from planbench.checking.collision import fresh_geometry_data, witnesses

__all__ = ["DistanceModel", "PairDistances"]


class PairDistances:
    """The pairs near enough to matter at one configuration (arrays of length ``K``).

    ``pair`` (K,) indices of the pairs (names: :attr:`DistanceModel.pair_names`), ``distance`` [m]
    (negative when overlapping), ``point`` and ``other_point`` (K, 3) the witness points on the
    first and the second body [m], ``normal`` (K, 3) unit normals from the first body towards the
    second, ``first`` and ``second`` (K,) the bodies' geometry indices, ``support`` and
    ``other_support`` (K, n) 1.0 where joint ``k`` moves the first or the second body (all 0 for an
    obstacle or the robot's fixed base). ``rotation`` (B, 3, 3) and ``translation`` (B, 3): the
    world placement of every body at that configuration (obstacles: the identity, their geometry
    being given in the world).
    """

    def __init__(self, n_pairs: int, **arrays: np.ndarray) -> None:
        self.pair: np.ndarray = arrays["pair"]
        self.distance: np.ndarray = arrays["distance"]
        self.point: np.ndarray = arrays["point"]
        self.other_point: np.ndarray = arrays["other_point"]
        self.normal: np.ndarray = arrays["normal"]
        self.first: np.ndarray = arrays["first"]
        self.second: np.ndarray = arrays["second"]
        self.support: np.ndarray = arrays["support"]
        self.other_support: np.ndarray = arrays["other_support"]
        self.rotation: np.ndarray = arrays["rotation"]
        self.translation: np.ndarray = arrays["translation"]
        self._n_pairs = n_pairs

    def __len__(self) -> int:
        return len(self.distance)

    def by_pair(self) -> np.ndarray:
        """Distances [m] indexed by pair, ``inf`` for pairs not reported (P,)."""
        out = np.full(self._n_pairs, np.inf)
        out[self.pair] = self.distance
        return out

    def local(self, body: np.ndarray, world: np.ndarray) -> np.ndarray:
        """World points (K', 3) [m] in the frames of bodies ``body`` (K',) at this configuration."""
        return np.einsum("kji,kj->ki", self.rotation[body], world - self.translation[body])

    def world(self, body: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Points given in the frames of bodies ``body`` (K',), in the world at this configuration."""
        return np.einsum("kij,kj->ki", self.rotation[body], local) + self.translation[body]


def _hull(geometry: Any) -> Any:
    """The convex hull of a mesh (from a copy: the robot's own geometry is left untouched), or the
    geometry itself when it is a primitive or the hull cannot be built (a flat mesh)."""
    if isinstance(geometry, coal.BVHModelBase) and geometry.num_vertices >= 4:
        try:
            mesh = geometry.clone()
            mesh.buildConvexHull(False, "Qt")
            return mesh.convex
        except (RuntimeError, ValueError):
            return geometry
    return geometry


def _vertices(geometry: Any) -> np.ndarray:
    """Points (V, 3) whose convex hull contains ``geometry`` (in its own frame): a convex hull's
    vertices, else its local bounding box's eight corners."""
    if isinstance(geometry, coal.ConvexBase) and geometry.num_points:
        return np.asarray(geometry.points(), dtype=float).reshape(-1, 3)
    geometry.computeLocalAABB()
    lo, hi = np.array(geometry.aabb_local.min_), np.array(geometry.aabb_local.max_)
    return np.array([[(lo, hi)[i >> a & 1][a] for a in range(3)] for i in range(8)])


def _point_segment(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances [m] of ``points`` (V, 3) to the segment from ``a`` to ``b``."""
    d = b - a
    dd = float(d @ d)
    t = np.clip((points - a) @ d / dd, 0.0, 1.0) if dd > 0 else np.zeros(len(points))
    return np.linalg.norm(points - (a + t[:, None] * d), axis=1)


def bounding_capsule(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule containing ``points`` (V, 3), hence their convex hull: the segment's ends (3,),
    (3,) and its radius [m]. The segment runs along the points' principal axis, shortened at each
    end by the largest distance off the axis (a long link gets a long thin capsule, a round one a
    sphere); the radius is the largest distance of a point to it (a millionth of a millimetre added
    for rounding), so the capsule holds every point whatever the fit."""
    c = points.mean(axis=0)
    centred = points - c
    _, vecs = np.linalg.eigh(centred.T @ centred)
    axis = vecs[:, -1]
    t = centred @ axis
    off = float(np.max(np.linalg.norm(centred - t[:, None] * axis, axis=1)))
    lo, hi = float(t.min()) + off, float(t.max()) - off
    if lo > hi:
        lo = hi = 0.5 * (float(t.min()) + float(t.max()))
    a, b = c + lo * axis, c + hi * axis
    return a, b, float(np.max(_point_segment(points, a, b))) + 1e-9


def _support_row(model: Any, joint: int) -> np.ndarray:
    """1.0 at every velocity index of ``joint`` and its ancestors (the joints that move it)."""
    row = np.zeros(model.nv)
    j = joint
    while j > 0:
        jm = model.joints[j]
        row[jm.idx_v : jm.idx_v + jm.nv] = 1.0
        j = model.parents[j]
    return row


class _RobotBodies(NamedTuple):
    """What a distance model needs of each robot geometry, the same for every scene: the geometry
    queried (its convex hull, or the primitive), its bounding capsule (ends in its joint's frame
    [m], radius [m]) and its bounding sphere (centre in its own frame [m], radius [m])."""

    geometries: tuple[Any, ...]
    capsules: tuple[tuple[np.ndarray, np.ndarray, float], ...]
    centres: tuple[np.ndarray, ...]
    radii: tuple[float, ...]


_BODIES: weakref.WeakKeyDictionary[Any, tuple[int, _RobotBodies]] = weakref.WeakKeyDictionary()
"""Per robot object: its geometries' hulls and bounds, made once. A controller builds a distance
model on every frame's observed geometry, and the hulls (qhull on each mesh) and capsules were most
of that model's cost (Panda: 8.6 ms a model with no obstacle, 1.3 ms on the kept bodies). A geometry
is shared between models as the same coal object; coal's distance queries do not change it."""


def _robot_bodies(robot: Any) -> _RobotBodies:
    """:class:`_RobotBodies` of ``robot``'s collision model, from :data:`_BODIES` when made before
    (keyed by the robot object and checked against its collision model's identity)."""
    collision = robot.collision_model
    try:
        kept = _BODIES.get(robot)
    except TypeError:  # a robot object that cannot be weakly referenced: made every time
        kept = None
    if kept is not None and kept[0] == id(collision):
        return kept[1]
    geometries, capsules, centres, radii = [], [], [], []
    for g in collision.geometryObjects:
        geom = _hull(g.geometry)
        end0, end1, r = bounding_capsule(_vertices(geom))
        M = g.placement
        capsules.append((M.rotation @ end0 + M.translation, M.rotation @ end1 + M.translation, r))
        geom.computeLocalAABB()
        lo, hi = np.array(geom.aabb_local.min_), np.array(geom.aabb_local.max_)
        centres.append(0.5 * (lo + hi))
        radii.append(0.5 * float(np.linalg.norm(hi - lo)))
        geometries.append(geom)
    bodies = _RobotBodies(tuple(geometries), tuple(capsules), tuple(centres), tuple(radii))
    try:
        _BODIES[robot] = (id(collision), bodies)
    except TypeError:
        pass
    return bodies


class DistanceModel:
    """Distances between a robot's collision geometries and a scene's obstacles, and (with
    ``self_pairs``) between the robot's own geometries.

    ``influence`` [m]: pairs farther apart than this are not reported (:meth:`near`). Not
    thread-safe (own buffers).
    """

    def __init__(
        self, robot: Any, scene: Any, influence: float, self_pairs: bool = True, obstacle_pairs: bool = True
    ) -> None:
        self.influence = float(influence)
        model = robot.model
        gm = pin.GeometryModel()
        robot_geoms = list(robot.collision_model.geometryObjects)
        bodies = _robot_bodies(robot)
        centres, radii, capsules = bodies.centres, bodies.radii, bodies.capsules
        for g, geom in zip(robot_geoms, bodies.geometries, strict=True):
            gm.addGeometryObject(pin.GeometryObject(g.name, int(g.parentJoint), int(g.parentFrame), g.placement, geom))
        self.n_robot = n_robot = len(robot_geoms)
        moving = [g.parentJoint != 0 for g in robot_geoms]
        lows, highs, names = [], [], [g.name for g in robot_geoms]
        octrees = [False] * len(robot_geoms)  # bodies whose coal witnesses need correcting (an OcTree)
        for obstacle in scene.obstacles if obstacle_pairs else ():
            gid = gm.addGeometryObject(
                pin.GeometryObject(
                    f"obstacle:{obstacle.name}", 0, 0, obstacle.placement(), obstacle.collision_geometry()
                )
            )
            lo, hi = obstacle.aabb()
            lows.append(lo)
            highs.append(hi)
            names.append(f"obstacle:{obstacle.name}")
            octrees.append(isinstance(obstacle.collision_geometry(), coal.OcTree))
            for rid in range(n_robot):
                if moving[rid]:
                    gm.addCollisionPair(pin.CollisionPair(rid, gid))
        if self_pairs:  # pairs on one joint never move relative to each other: left out
            joint = [int(g.parentJoint) for g in robot_geoms]
            for cp in robot.collision_model.collisionPairs:
                a, b = int(cp.first), int(cp.second)
                if joint[a] != joint[b]:
                    gm.addCollisionPair(pin.CollisionPair(a, b))
        self.n_obstacles = len(lows)
        self._octree = np.array(octrees, dtype=bool) if any(octrees) else None  # None: no witness to correct
        n_bodies = n_robot + self.n_obstacles
        self.body_names = tuple(names)
        support = np.zeros((n_bodies, model.nv))
        for i, g in enumerate(robot_geoms):
            support[i] = _support_row(model, int(g.parentJoint))
        self._support = support
        first = np.array([int(p.first) for p in gm.collisionPairs], dtype=np.intp)
        second = np.array([int(p.second) for p in gm.collisionPairs], dtype=np.intp)
        if np.any(first >= n_robot):
            raise AssertionError("every pair's first body is a robot geometry")
        self._first, self._second = first, second
        self.n_pairs = len(first)
        self.pair_names = tuple((names[a], names[b]) for a, b in zip(first, second, strict=True))
        self.n_self_pairs = int(np.sum(second < n_robot))
        # culling: a sphere per robot geometry (local centre, radius), a box per obstacle
        self._centre_local = np.array(centres).reshape(-1, 3)
        self._radius = np.array(radii)
        # the same spheres in their joints' frames, for culling straight from the joint placements
        self.body_joint = np.array([int(g.parentJoint) for g in robot_geoms], dtype=np.intp)
        self.body_centre = np.array(
            [g.placement.rotation @ c + g.placement.translation for g, c in zip(robot_geoms, centres, strict=True)]
        ).reshape(-1, 3)
        self.body_segment = np.array([(a, b) for a, b, _ in capsules]).reshape(-1, 2, 3)
        """(B_robot, 2, 3): each robot geometry's bounding capsule, its segment's ends in its joint's frame [m]."""
        self.body_capsule_radius = np.array([r for _, _, r in capsules])
        """(B_robot,): the capsules' radii [m]."""
        self._obs_lo = np.array(lows).reshape(-1, 3)
        self._obs_hi = np.array(highs).reshape(-1, 3)
        self._is_self = second < n_robot
        self.geometry_model = gm
        self.geometry_data = gd = fresh_geometry_data(gm)  # the same answer whatever was queried before
        self._oMg = [gd.oMg[i] for i in range(n_robot)]
        self._results = [gd.distanceResults[k] for k in range(self.n_pairs)]  # references, fetched once
        self._rotation = np.tile(np.eye(3), (n_bodies, 1, 1))
        self._translation = np.zeros((n_bodies, 3))
        self._model = model
        self._data = model.createData()  # for :meth:`near_at`
        self.n_pairs_checked = 0
        """Pairs handed to coal by the last :meth:`near` (after culling)."""

    def _cull(self, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """Pairs whose lower bound (spheres against spheres or obstacle boxes) is below the
        influence distance, the robot geometries placed at ``rotation``, ``translation``."""
        n_robot = self.n_robot
        centre = np.einsum("gij,gj->gi", rotation, self._centre_local) + translation
        first, second = self._first, self._second
        bound = np.empty(self.n_pairs)
        c = centre[first]
        obstacle = ~self._is_self
        o = second[obstacle] - n_robot
        gap = np.maximum(self._obs_lo[o] - c[obstacle], 0.0) + np.maximum(c[obstacle] - self._obs_hi[o], 0.0)
        bound[obstacle] = np.sqrt(np.einsum("ka,ka->k", gap, gap)) - self._radius[first[obstacle]]
        s = self._is_self
        bound[s] = np.linalg.norm(c[s] - centre[second[s]], axis=1) - self._radius[first[s]] - self._radius[second[s]]
        return np.flatnonzero(bound < self.influence)

    def measure(
        self,
        model: Any,
        data: Any,
        candidates: np.ndarray,
        pair: np.ndarray,
        distance: np.ndarray,
        point: np.ndarray,
        other_point: np.ndarray,
        normal: np.ndarray,
    ) -> int:
        """:meth:`near` for the pairs ``candidates`` into the caller's buffers (of at least
        ``len(candidates)`` rows): the ``k`` pairs within the influence distance, in the order of
        ``candidates``, in the first ``k`` rows; ``k`` returned. No arrays are made: the per-step
        path of the self-collision push."""
        pin.updateGeometryPlacements(model, data, self.geometry_model, self.geometry_data)
        return self._measure(candidates, pair, distance, point, other_point, normal)

    def _measure(self, candidates, pair, dist, point, other, normal) -> int:  # type: ignore[no-untyped-def]
        """coal's distance for each of ``candidates`` (geometry placements up to date), the pairs
        within the influence distance kept in the buffers' first rows; their number returned."""
        gm, gd, results, compute = self.geometry_model, self.geometry_data, self._results, pin.computeDistance
        influence, octree, second = self.influence, self._octree, self._second
        m = 0
        for k in candidates.tolist():
            results[k].clear()
            res = compute(gm, gd, k)
            d = res.min_distance
            if d < influence:
                pair[m], dist[m] = k, d
                if octree is not None and octree[second[k]]:  # coal's witnesses of an octree corrected
                    point[m], other[m], normal[m] = witnesses(res, True)
                else:
                    point[m] = res.getNearestPoint1()
                    other[m] = res.getNearestPoint2()
                    normal[m] = res.normal
                m += 1
        self.n_pairs_checked = len(candidates)
        return m

    @property
    def body_support(self) -> np.ndarray:
        """(B, n): 1.0 where joint ``k`` moves body ``b`` (all 0 for an obstacle or the fixed base)."""
        return self._support

    def near_at(self, q: np.ndarray) -> PairDistances:
        """:meth:`near` at configuration ``q`` (forward kinematics on this object's own data)."""
        pin.forwardKinematics(self._model, self._data, q)
        return self.near(self._model, self._data)

    @property
    def radius(self) -> np.ndarray:
        """Radius of each robot geometry's bounding sphere [m] (its local box's half diagonal)."""
        return self._radius

    @property
    def pair_bodies(self) -> tuple[np.ndarray, np.ndarray]:
        """The first and second body of every pair (P,), geometry indices."""
        return self._first, self._second

    def self_candidates(self, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """Indices of the pairs whose bounding spheres lie closer than :attr:`influence`, the
        joints placed at ``rotation`` (J, 3, 3) and ``translation`` (J, 3) [m] (pinocchio's
        ``data.oMi``); only for a model of self pairs (``obstacle_pairs=False``). What
        :meth:`near` culls to, in numpy (the compiled push culls tighter, with capsules:
        :attr:`body_segment`, ``_compiled.capsules_within``)."""
        if self.n_obstacles:
            raise ValueError("self_candidates culls self pairs only: build the model with obstacle_pairs=False")
        j = self.body_joint
        centre = np.einsum("bij,bj->bi", rotation[j], self.body_centre) + translation[j]
        first, second = self._first, self._second
        bound = np.linalg.norm(centre[first] - centre[second], axis=1) - self._radius[first] - self._radius[second]
        return np.flatnonzero(bound < self.influence)

    def near(self, model: Any, data: Any, candidates: np.ndarray | None = None) -> PairDistances:
        """The pairs closer than :attr:`influence` with the robot placed as in ``data`` (joint
        placements ``data.oMi`` up to date: after ``kin.update(q)``). ``candidates``: the pairs
        that a bounding volume leaves (:meth:`self_candidates`) when the caller culled already."""
        gm, gd = self.geometry_model, self.geometry_data
        pin.updateGeometryPlacements(model, data, gm, gd)
        n_robot = self.n_robot
        rotation, translation = self._rotation.copy(), self._translation.copy()
        rotation[:n_robot] = [M.rotation for M in self._oMg]
        translation[:n_robot] = [M.translation for M in self._oMg]
        first, second = self._first, self._second
        if candidates is None:
            candidates = self._cull(rotation[:n_robot], translation[:n_robot])
        m = len(candidates)
        pair, dist, point, other, normal = np.empty(m, dtype=np.intp), np.empty(m), *np.empty((3, m, 3))
        k = self._measure(candidates, pair, dist, point, other, normal)
        pair, dist, point, other, normal = pair[:k], dist[:k], point[:k], other[:k], normal[:k]
        return PairDistances(
            self.n_pairs,
            pair=pair,
            distance=dist,
            point=point,
            other_point=other,
            normal=normal,
            first=first[pair],
            second=second[pair],
            support=self._support[first[pair]],
            other_support=self._support[second[pair]],
            rotation=rotation,
            translation=translation,
        )
