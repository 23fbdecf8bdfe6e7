"""The sensing models of the reactive benchmark: what the controller observes of the true scene.

``truth`` voxelises the exact scene at each sensor frame (rule ``"any"``, the grid every planner
uses) and hands the scene itself along, for controllers that measure distances to geometry.

``depth`` simulates depth cameras (pinhole, one ray per pixel) and builds the grid from the points
they return. A depth camera sees only the first surface along each ray: the front faces of the
obstacles, never what lies behind them, so an obstacle appears as a shell on the camera's side
and the cells it hides stay free. Each pixel's range (the distance along its ray, not
the z-depth) gets Gaussian noise of ``noise_std`` [m] *along the ray*, as time-of-flight and stereo
errors lie mainly in range; a pixel whose ray hits nothing within ``max_range`` [m] returns nothing,
and each pixel drops out independently with probability ``dropout`` (specular, dark or grazing
surfaces). The noise and dropout of every pixel are drawn from the frame's ``rng`` for all pixels,
hit or not, so with one seed the same pixel gets the same error whatever the arm does: controllers
compared on one seed see the same sensor errors.

A real camera sees the robot too. The rays are cast against the obstacles *and* the robot's own
collision geometry at the current configuration; then the robot is removed "by its geometry", as
a self filter does: a point whose ray hit a robot triangle is dropped, and so is any point closer
than ``robot_margin`` [m] to the robot's collision surface (noisy points on the arm's edge, objects
held against it). That distance test is conservative: each collision mesh is subdivided once until
every edge is at most :data:`ROBOT_EDGE` [m] long, and a point is dropped when a vertex of the
subdivided mesh lies within ``robot_margin + e / sqrt(3)`` (``e`` the longest edge), since every
point of a triangle with edges <= ``e`` lies within ``e / sqrt(3)`` of one of its corners. So no
point within ``robot_margin`` of the surface survives, and points up to ``e / sqrt(3)`` (5.8 mm)
farther may be dropped too. The vertices sit in one k-d tree per collision object in its own frame
(built once); each frame only the points inside an object's bounding box, grown by the threshold,
are moved into its frame and queried.

Ray casting is Intel Embree's, through trimesh and embreex (``RayMeshIntersector``): a 15 MB
install, against Open3D's 400 MB wheel with many dependencies, for the same Embree kernels. Shapes
are triangulated with ``trimesh.creation`` (spheres, cylinders and capsules inscribed, their
surface within 0.5 % of the radius of the true one) and placed at their poses; the triangles of an
obstacle that has not moved since the previous frame are reused. The Embree structure is rebuilt
every frame over all triangles (obstacles and arm), which costs little next to the casting
(measured on ``mbm:box/0001`` with the Panda, 2,700 triangles: building 1.3 ms, casting
160x120 rays 2 ms and 320x240 rays 8 ms; whole frames in ``docs/sensing.md``).

Both models keep one grid shape for a whole run: by default the cube of half side
``robot.reach() + 0.1`` m around the base, its corners on multiples of the resolution.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin
import trimesh
from scipy.spatial import cKDTree
from trimesh.ray.ray_pyembree import RayMeshIntersector

from planbench.geometry.occupancy import OccupancyGrid, cover_block, grid_shape
from planbench.geometry.occupancy_map import OccupancyMap
from planbench.geometry.views import mark_seen
from planbench.reactive.body import ArmBody
from planbench.reactive.controller import Observation
from planbench.reactive.meshes import Triangles, geometry_triangles, obstacle_triangles, placed, stack
from planbench.reactive.scenario import CameraSettings, SensingSettings, default_bounds
from planbench.robot import Robot
from planbench.scene import Obstacle, Scene

__all__ = ["ROBOT_EDGE", "Sensor", "camera_frame", "camera_rays"]

ROBOT_EDGE = 0.01
"""Longest edge of the subdivided robot meshes of the margin test [m] (the test may drop points
up to ``ROBOT_EDGE / sqrt(3)`` beyond ``robot_margin``)."""


# --- cameras --------------------------------------------------------------------------------------
def camera_frame(camera: CameraSettings) -> tuple[np.ndarray, np.ndarray, float]:
    """The optical centre (3,) [m], the axes (3, 3: rows forward, right, up) and the pixel size at
    unit focal length of a pinhole camera."""
    origin = np.asarray(camera.position, dtype=float)
    forward = np.asarray(camera.look_at, dtype=float) - origin
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera.up, dtype=float))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    pixel = 2.0 * math.tan(math.radians(camera.fov) / 2.0) / int(camera.height)
    return origin, np.stack([forward, right, up]), pixel


def camera_rays(camera: CameraSettings) -> tuple[np.ndarray, np.ndarray]:
    """The optical centre (3,) [m] and unit ray directions (height * width, 3) of a pinhole camera,
    pixels row by row from the top-left corner, each ray through its pixel's centre."""
    origin, (forward, right, up), pixel = camera_frame(camera)
    w, h = int(camera.width), int(camera.height)
    x = (np.arange(w) + 0.5 - w / 2.0) * pixel
    y = (h / 2.0 - np.arange(h) - 0.5) * pixel
    xx, yy = np.meshgrid(x, y)  # (h, w): rows top to bottom
    d = forward + xx.reshape(-1, 1) * right + yy.reshape(-1, 1) * up
    return origin, d / np.linalg.norm(d, axis=1, keepdims=True)


# --- the robot's own geometry ---------------------------------------------------------------------
@dataclass(frozen=True)
class _RobotPart:
    """One collision object of the robot in its own frame: triangles for the rays, and the
    subdivided mesh's vertices (k-d tree) and bounding box for the margin test."""

    triangles: Triangles
    tree: cKDTree
    center: np.ndarray  # of the local bounding box [m]
    half: np.ndarray  # its half extents [m]
    edge: float  # longest edge of the subdivided mesh [m]


def _robot_part(tri: Triangles) -> _RobotPart:
    v, f = trimesh.remesh.subdivide_to_size(tri[0], tri[1], max_edge=ROBOT_EDGE, max_iter=20)
    edges = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)
    lo, hi = tri[0].min(axis=0), tri[0].max(axis=0)
    return _RobotPart(tri, cKDTree(v), 0.5 * (lo + hi), 0.5 * (hi - lo), float(edges.max()))


@functools.lru_cache(maxsize=8)
def _robot_parts(robot: Robot) -> tuple[_RobotPart, ...]:
    """The robot's collision objects, in ``collision_model`` order (built once per robot)."""
    return tuple(_robot_part(geometry_triangles(obj)) for obj in robot.collision_model.geometryObjects)


# --- the sensor -----------------------------------------------------------------------------------
class Sensor:
    """Turns the true scene at a time into what the controller observes (module docstring)."""

    def __init__(
        self, settings: SensingSettings, robot: Robot, bounds: tuple[np.ndarray, np.ndarray] | None = None
    ) -> None:
        """``bounds``: lower and upper corner of the observed grid [m], the same for every frame;
        default :func:`default_bounds`."""
        self.settings = settings
        self.robot = robot
        self.bounds = default_bounds(robot, settings.resolution) if bounds is None else _checked_bounds(bounds)
        # truth: the grid of the obstacles unchanged since the previous frame, painted once
        self._previous: frozenset[Obstacle] = frozenset()
        self._base_set: frozenset[Obstacle] = frozenset()
        self._base: np.ndarray | None = None
        # depth: rays, the robot's local meshes (built on first use) and the triangles of unmoved obstacles
        self._rays = [camera_rays(c) for c in settings.cameras]
        self._frames = [camera_frame(c) for c in settings.cameras]
        self._triangles: dict[Obstacle, Triangles] = {}
        self._data = robot.model.createData()
        self._geometry_data = pin.GeometryData(robot.collision_model)
        self._shape = grid_shape(self.bounds[0], self.bounds[1], settings.resolution)
        depth = settings.model == "depth"
        self._body = ArmBody(robot, self.bounds[0], self._shape, settings.resolution) if depth else None
        self._map = (
            OccupancyMap(self.bounds[0], self._shape, settings.resolution, settings.map)
            if depth and settings.memory == "map"
            else None
        )

    def capture(self, scene: Scene, q: np.ndarray, t: float, frame: int, rng: np.random.Generator) -> Observation:
        """The observation of ``scene`` captured at time ``t`` [s] with the arm at ``q`` [rad]
        (the arm hides what is behind it from a camera); ``rng`` draws the sensor's noise."""
        q = self._checked_q(q)
        if self.settings.model == "truth":
            return Observation(time=t, grid=self.truth_grid(scene), frame=frame, points=None, scene=scene)
        cloud, free = self.sense(scene, q, rng)
        res = self.settings.resolution
        seen = np.zeros(self._shape, dtype=bool)
        for camera, (origin, axes, pixel), lengths in zip(self.settings.cameras, self._frames, free, strict=True):
            mark_seen(seen, self.bounds[0], res, origin, axes, pixel, camera.width, camera.height, lengths)
        assert self._body is not None  # made for depth sensing
        body = self._body.mark(np.zeros(self._shape, dtype=bool), q)  # no obstacle is where the arm is
        if self._map is not None:
            self._map.integrate(seen, self._map.cells_of(cloud), known=body)
            grid = self._map.grid()
        else:
            seen |= body
            grid = OccupancyGrid.from_points(cloud, res, bounds=(self.bounds[0].copy(), self.bounds[1]), known=seen)
        # float32, as depth drivers deliver points (0.2 um at 3 m): half the bytes a controller receives
        return Observation(time=t, grid=grid, frame=frame, points=cloud.astype(np.float32), scene=None)

    # --- truth ----------------------------------------------------------------------------------
    def truth_grid(self, scene: Scene) -> OccupancyGrid:
        """``OccupancyGrid.from_scene(scene, resolution, bounds, rule="any")``, cell for cell, at the
        cost of the obstacles that moved: those unchanged since the previous call sit in a cached
        grid, copied and painted over with the others (on a MotionBenchMaker scene 2-3 ms per frame
        instead of 10 ms)."""
        current = frozenset(scene.obstacles)
        unchanged = current & self._previous
        if self._base is None or not self._base_set <= unchanged:  # a cached obstacle moved or left
            self._base = self._blank().data
            self._base_set = frozenset()
        self._paint(self._base, unchanged - self._base_set)
        self._base_set = unchanged
        self._previous = current
        data = self._base.copy()
        self._paint(data, [o for o in scene.obstacles if o not in unchanged])
        return OccupancyGrid(data, self.bounds[0].copy(), self.settings.resolution)

    def _blank(self) -> OccupancyGrid:
        return OccupancyGrid.empty(self.bounds[0], self.bounds[1], self.settings.resolution)

    def _paint(self, data: np.ndarray, obstacles: Any) -> None:
        """Voxelise ``obstacles`` into ``data`` exactly as ``OccupancyGrid.from_scene`` does."""
        origin, res, shape = self.bounds[0], self.settings.resolution, np.array(data.shape)
        for o in obstacles:
            lo, hi = o.aabb()
            i0 = np.clip(np.floor((lo - origin) / res).astype(int), 0, shape)
            i1 = np.clip(np.floor((hi - origin) / res).astype(int) + 1, 0, shape)
            if np.any(i1 <= i0):
                continue
            block = cover_block(o, origin, res, i0, i1, "any", 4)
            view = data[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]]
            np.maximum(view, block, out=view)

    # --- depth ----------------------------------------------------------------------------------
    @property
    def _parts(self) -> tuple[_RobotPart, ...]:
        return _robot_parts(self.robot)

    def point_cloud(self, scene: Scene, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The (N, 3) points [m] all cameras return, the robot removed (module docstring)."""
        return self.sense(scene, q, rng)[0]

    def sense(self, scene: Scene, q: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, list[np.ndarray]]:
        """The point cloud, and per camera the length [m] from the optical centre that each pixel
        saw free (docs/sensing.md, "What a frame knows"): up to the point it returned; up to
        ``max_range`` when nothing was in range; up to ``robot_margin`` short of the arm, or of a
        point the robot filter removed; nothing for a pixel that dropped out."""
        q = self._checked_q(q)
        poses = self._robot_poses(q)
        scene_tri = self._scene_triangles(scene)
        robot_tri = stack([placed(part.triangles, R, p) for part, (R, p) in zip(self._parts, poses, strict=True)])
        ranges, robot_hit = self._cast(stack([scene_tri, robot_tri]), len(scene_tri[1]))
        margin = self.settings.robot_margin
        clouds, rays, start = [], [], 0
        for camera, (origin, dirs) in zip(self.settings.cameras, self._rays, strict=True):
            r = ranges[start : start + len(dirs)]
            robot = robot_hit[start : start + len(dirs)]
            in_range = np.isfinite(r) & (r <= camera.max_range)  # before the noise
            keep, returned = self._measure(camera, r, robot, rng)
            free = np.where(keep, r, 0.0)
            free[returned & robot] = np.maximum(r[returned & robot] - margin, 0.0)
            free[returned & ~in_range] = camera.max_range  # nothing within range: all of it seen free
            points = origin + r[keep, None] * dirs[keep]
            if margin > 0 and len(points):
                near = self._near_robot(points, poses)
                pixels = np.flatnonzero(keep)[near]
                free[pixels] = np.maximum(r[pixels] - margin, 0.0)
                points = points[~near]
            clouds.append(points)
            rays.append(free)
            start += len(dirs)
        cloud = np.concatenate(clouds) if clouds else np.zeros((0, 3))
        return cloud, rays

    def _scene_triangles(self, scene: Scene) -> Triangles:
        """All obstacles' triangles in the scene frame; an obstacle equal to one of the previous
        frame reuses its triangles."""
        placed = {o: self._triangles.get(o) or obstacle_triangles(o) for o in scene.obstacles}
        self._triangles = placed
        return stack(list(placed.values()))

    def _robot_poses(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """(rotation, translation) of each robot collision object at ``q``."""
        pin.updateGeometryPlacements(self.robot.model, self._data, self.robot.collision_model, self._geometry_data, q)
        return [(np.array(M.rotation), np.array(M.translation)) for M in self._geometry_data.oMg]

    def _cast(self, tri: Triangles, n_scene: int) -> tuple[np.ndarray, np.ndarray]:
        """First-hit range [m] of every pixel of every camera (inf: no hit), and whether it hit the
        robot (triangles from ``n_scene`` on)."""
        n = sum(len(d) for _, d in self._rays)
        ranges, robot_hit = np.full(n, np.inf), np.zeros(n, dtype=bool)
        if n == 0 or len(tri[1]) == 0:
            return ranges, robot_hit
        origins = np.concatenate([np.broadcast_to(o, d.shape) for o, d in self._rays])
        dirs = np.concatenate([d for _, d in self._rays])
        mesh = trimesh.Trimesh(tri[0], tri[1], process=False, validate=False)
        index_tri, index_ray, hits = RayMeshIntersector(mesh).intersects_id(
            origins, dirs, multiple_hits=False, return_locations=True
        )
        ranges[index_ray] = np.einsum("ij,ij->i", hits - origins[index_ray], dirs[index_ray])
        robot_hit[index_ray] = index_tri >= n_scene
        return ranges, robot_hit

    @staticmethod
    def _measure(
        camera: CameraSettings, ranges: np.ndarray, robot_hit: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Which pixels return a point, and which did not drop out; adds the range noise to
        ``ranges`` in place. Noise and dropout are drawn for every pixel, so the stream does not
        depend on what was hit."""
        keep = np.isfinite(ranges) & (ranges <= camera.max_range) & ~robot_hit
        returned = np.ones(len(ranges), dtype=bool)
        if camera.noise_std > 0:
            ranges += rng.normal(0.0, camera.noise_std, len(ranges))
            keep &= ranges > 0
        if camera.dropout > 0:
            returned = rng.random(len(ranges)) >= camera.dropout
            keep &= returned
        return keep, returned

    def _near_robot(self, points: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Points [m] within ``robot_margin`` of the robot's surface (and a few mm beyond: module
        docstring)."""
        margin = self.settings.robot_margin
        reach = [margin + part.edge / math.sqrt(3.0) for part in self._parts]
        centers = np.array([R @ part.center + p for part, (R, p) in zip(self._parts, poses, strict=True)])
        halves = np.array(
            [np.abs(R) @ (part.half + r) for part, (R, _), r in zip(self._parts, poses, reach, strict=True)]
        )
        # one box around the whole arm first: most points are far from it
        lo, hi = (centers - halves).min(axis=0), (centers + halves).max(axis=0)
        close = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))
        near = np.zeros(len(points), dtype=bool)
        for part, (R, p), r, c, h in zip(self._parts, poses, reach, centers, halves, strict=True):
            candidates = close[np.all(np.abs(points[close] - c) <= h, axis=1) & ~near[close]]
            if len(candidates):
                dist, _ = part.tree.query((points[candidates] - p) @ R, distance_upper_bound=r)
                near[candidates[dist < r]] = True
        return near

    def _checked_q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.robot.nq,):
            raise ValueError(f"q must have shape ({self.robot.nq},) for robot {self.robot.name!r}, got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"q must be finite, got {q}")
        return q


def _checked_bounds(bounds: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = (np.asarray(b, dtype=float) for b in bounds)
    if lower.shape != (3,) or upper.shape != (3,) or not (np.isfinite(lower).all() and np.isfinite(upper).all()):
        raise ValueError(f"bounds must be two corners of 3 finite numbers [m], got {bounds}")
    if np.any(upper <= lower):
        raise ValueError(f"bounds must have upper > lower, got {lower} and {upper}")
    return lower, upper
