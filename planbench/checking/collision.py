"""Exact collision and distance queries of a robot against a scene's true geometry (coal).

The robot's collision geometry (from its URDF) and the scene's obstacles go into one
``pinocchio.GeometryModel``: self-collision pairs (the robot's, SRDF pairs removed) plus every
robot-geometry / obstacle pair. pinocchio's C++ loops then run the coal queries, which keeps the
per-configuration cost low enough for sampling planners and for dense path validation.

``in_collision`` goes through a broadphase (pinocchio's ``BroadPhaseManager`` over coal's dynamic
AABB tree): only the collision pairs whose world-axis-aligned bounding boxes overlap reach coal's
exact narrowphase, and pairs off the list (the ignore list) are skipped as before. An AABB contains
its geometry, so two geometries whose boxes are apart cannot touch: the answer is the same as
checking every pair, about 5x faster on the MotionBenchMaker scenes (~20 us instead of ~120 us).
``collisions`` and ``clearance`` still visit every pair.
"""

from __future__ import annotations

import functools
import warnings
import weakref
from collections.abc import Generator
from typing import Any

import coal
import numpy as np
import pinocchio as pin

from planbench.robot import Robot, link_of
from planbench.scene import Scene

__all__ = ["CollisionChecker", "fresh_geometry_data", "octree_distance_swapped", "witnesses"]

_CHECKERS: weakref.WeakKeyDictionary[Any, CollisionChecker] = weakref.WeakKeyDictionary()


@functools.cache
def octree_distance_swapped() -> bool:
    """Whether coal reports a shape's distance to a ``coal.OcTree`` given second as if the octree
    came first: nearest points swapped and the normal reversed (coal 3.0.3 does, for boxes,
    spheres and convex hulls alike). Probed once, on a box 0.15 m beside one cell, so that a
    release that fixes it is followed."""
    octree = coal.makeOctree(np.array([[0.51, 0.01, 0.01]]), 0.02)
    result = coal.DistanceResult()
    beside = coal.Transform3s(np.eye(3), np.array([0.3, 0.0, 0.0]))
    coal.distance(coal.Box(0.1, 0.1, 0.1), beside, octree, coal.Transform3s(), coal.DistanceRequest(), result)
    return bool(result.normal[0] < 0)  # from the box (first) towards the cell is +x


def witnesses(result: Any, octree_second: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest point on the first body, on the second, and the unit normal from the first
    towards the second, of a coal distance ``result``; ``octree_second``: the second body is a
    ``coal.OcTree`` (:func:`octree_distance_swapped` corrected)."""
    p1, p2, n = np.array(result.getNearestPoint1()), np.array(result.getNearestPoint2()), np.array(result.normal)
    if octree_second and octree_distance_swapped():
        return p2, p1, -n
    return p1, p2, n


def fresh_geometry_data(geometry_model: Any, distances: bool = True) -> Any:
    """``pin.GeometryData`` whose coal queries start GJK from its default guess every time, never
    from the previous query's answer, so that a distance does not depend on what was asked before
    (a verdict or a path on the order of runs). pinocchio's requests come with coal's deprecated
    ``enable_cached_gjk_guess`` set, which overrides ``gjk_initial_guess``; with it a convex pair's
    distance moved by up to 1.4 um with the query history. ``distances``: set the distance
    requests too (False: data for collision checks only; setting a request costs about 1 us, and a
    checker of a depth frame's octree pieces has hundreds of pairs)."""
    data = pin.GeometryData(geometry_model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        for requests in (data.distanceRequests, data.collisionRequests) if distances else (data.collisionRequests,):
            for request in requests:
                request.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess
                request.enable_cached_gjk_guess = False
    return data


class CollisionChecker:
    """Collision and clearance queries for one robot in one scene. Not thread-safe (own buffers)."""

    def __init__(self, robot: Robot, scene: Scene) -> None:
        for _ in self._build(robot, scene):
            pass

    @classmethod
    def in_steps(cls, robot: Robot, scene: Scene) -> Generator[None, None, CollisionChecker]:
        """The checker built in three steps, a ``yield`` between them (the geometry model, its
        data, the broadphase: each a fraction of a millisecond), for a control loop that spreads
        its work over ticks; ``yield from`` it."""
        checker = cls.__new__(cls)
        yield from cls._build(checker, robot, scene)
        return checker

    def _build(self, robot: Robot, scene: Scene) -> Generator[None, None, None]:
        self.robot = robot
        self.scene = scene
        geom = pin.GeometryModel(robot.collision_model)  # copy: the robot stays untouched
        self.n_robot_geoms = geom.ngeoms
        for obstacle in scene.obstacles:
            obj = pin.GeometryObject(
                f"obstacle:{obstacle.name}", 0, 0, obstacle.placement(), obstacle.collision_geometry()
            )
            gid = geom.addGeometryObject(obj)
            for rid in range(self.n_robot_geoms):
                geom.addCollisionPair(pin.CollisionPair(rid, gid))
        self.geometry_model = geom
        self._model = robot.model
        yield
        # Broadphase for in_collision, built now: the one query every planner makes.
        self._bp_data = robot.model.createData()
        self._bp_geom_data = fresh_geometry_data(geom, distances=False)
        yield
        self._broadphase = pin.BroadPhaseManager_DynamicAABBTreeCollisionManager(robot.model, geom, self._bp_geom_data)
        # The data of collisions() and of clearance() (its distances only between robot and
        # obstacles, never robot-robot), each built when first asked: a checker built per sensor
        # frame (a controller's) asks only in_collision, and each costs as much as the broadphase's.
        self._all_pairs: tuple[Any, Any] | None = None
        self._distances: Any = None
        self._obstacle_pairs = [
            k
            for k, pair in enumerate(geom.collisionPairs)
            if pair.second >= self.n_robot_geoms or pair.first >= self.n_robot_geoms
        ]
        self.n_checks = 0

    @classmethod
    def for_problem(cls, problem: Any) -> CollisionChecker:
        """The checker for a problem's robot and scene, built once and cached on the problem."""
        checker = _CHECKERS.get(problem)
        if checker is None:
            checker = _CHECKERS[problem] = cls(problem.robot, problem.scene)
        return checker

    def in_collision(self, q: np.ndarray) -> bool:
        """True when the robot at ``q`` touches an obstacle or itself (the ignore list aside)."""
        self.n_checks += 1
        return bool(
            pin.computeCollisions(self._model, self._bp_data, self._broadphase, np.asarray(q, dtype=float), True)
        )

    def in_collision_all_pairs(self, q: np.ndarray) -> bool:
        """``in_collision`` without the broadphase: every pair goes to coal's narrowphase (the
        reference that the broadphase is checked against; slower)."""
        self.n_checks += 1
        data, geom_data = self._all_pairs_data()
        return bool(
            pin.computeCollisions(self._model, data, self.geometry_model, geom_data, np.asarray(q, dtype=float), True)
        )

    def collisions(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Every colliding pair at ``q`` as (robot link, link or ``obstacle:<name>``)."""
        data, geom_data = self._all_pairs_data()
        pin.computeCollisions(self._model, data, self.geometry_model, geom_data, np.asarray(q, dtype=float), False)
        out = []
        objs = self.geometry_model.geometryObjects
        for k, pair in enumerate(self.geometry_model.collisionPairs):
            if geom_data.collisionResults[k].isCollision():
                a, b = objs[pair.first].name, objs[pair.second].name
                out.append((_display(a), _display(b)))
        return out

    def contacts(self, q: np.ndarray) -> list[tuple[str, str, np.ndarray]]:
        """Every colliding pair at ``q`` as in :meth:`collisions`, each with one contact point [m]
        (coal's, base frame) per contact coal reports."""
        data, geom_data = self._all_pairs_data()
        for request in geom_data.collisionRequests:
            request.enable_contact = True
        pin.computeCollisions(self._model, data, self.geometry_model, geom_data, np.asarray(q, dtype=float), False)
        out: list[tuple[str, str, np.ndarray]] = []
        objs = self.geometry_model.geometryObjects
        for k, pair in enumerate(self.geometry_model.collisionPairs):
            result = geom_data.collisionResults[k]
            if result.isCollision():
                a, b = _display(objs[pair.first].name), _display(objs[pair.second].name)
                out.extend((a, b, np.array(c.pos, dtype=float)) for c in result.getContacts())
        return out

    def clearance(self, q: np.ndarray) -> float:
        """Smallest robot-obstacle distance [m] at ``q`` (negative or zero when penetrating;
        ``inf`` in an empty scene). Self-distances are not included."""
        if not self._obstacle_pairs:
            return float("inf")
        if self._distances is None:
            self._distances = fresh_geometry_data(self.geometry_model)
            obstacle = set(self._obstacle_pairs)
            for k in range(len(self.geometry_model.collisionPairs)):
                if k in obstacle:
                    self._distances.activateCollisionPair(k)
                else:
                    self._distances.deactivateCollisionPair(k)
        data, _ = self._all_pairs_data()
        pin.computeDistances(self._model, data, self.geometry_model, self._distances, np.asarray(q, dtype=float))
        results = self._distances.distanceResults
        return float(min(results[k].min_distance for k in self._obstacle_pairs))

    def _all_pairs_data(self) -> tuple[Any, Any]:
        """The model's data and the every-pair geometry data, built when first asked."""
        if self._all_pairs is None:
            self._all_pairs = (self._model.createData(), fresh_geometry_data(self.geometry_model))
        return self._all_pairs


def _display(geometry_name: str) -> str:
    return geometry_name if geometry_name.startswith("obstacle:") else link_of(geometry_name)
