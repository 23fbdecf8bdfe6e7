"""planbench robots and scenes as VAMP sees them: which compiled VAMP robot a planbench robot is, and
a scene as VAMP's collision primitives.

Robots. VAMP plans only for robots compiled into it (its sphere models); of those planbench ships the
Panda and the UR5. A planbench robot is taken as VAMP's when its name and planned joints match and the
two forward kinematics agree (:func:`vamp_robot`, checked at three configurations to 1 mm), so a
different URDF under a shipped name is refused rather than planned with the wrong model. VAMP's UR5
stands in a world frame of its own (its URDF's ``offset_joint``: base 0.9144 m up, turned 1.57 rad
about z) and carries a Robotiq 85 gripper that planbench's UR5 has not: obstacles are moved into
that frame, and the gripper makes VAMP's UR5 more conservative than planbench's.

Obstacles (all conservative: VAMP's shape holds planbench's):

- box: a VAMP cuboid (centre, Euler XYZ angles, half extents), exact;
- sphere: a VAMP sphere, exact;
- cylinder: the cylinder's bounding box (``cylinders="box"``, the default: out by up to 0.41 x the
  radius along the diagonals, not at the ends), what VAMP's own MotionBenchMaker script does on the
  ``box`` family, whose top-down grasps a capsule's caps block; or a VAMP capsule along the same
  axis (``cylinders="capsule"``, VAMP's own primitive: it sticks out by the radius at both ends);
- capsule: a VAMP capsule, exact;
- mesh: its surface as a point cloud: the mesh's triangles subdivided until no edge is longer than
  ``mesh_spacing``, every vertex a point of radius ``0.6 mesh_spacing`` (no point of a triangle is
  farther than ``edge / sqrt(3)`` from its nearest corner, so the spheres cover the surface). The
  inside of a closed mesh is not filled: a robot sphere wholly inside it is not seen;
- point cloud: planbench's geometry of a cloud is the lattice cubes of edge ``2 radius`` that hold
  a point; each cube becomes a VAMP point at its centre with radius ``sqrt(3) radius``, the cube's
  half diagonal.

VAMP's point clouds are searched with its CAPT structure, built when the cloud is added
(:meth:`vamp.Environment.add_pointcloud`, told the robot's smallest and largest sphere radius).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
import vamp
from scipy.spatial.transform import Rotation

from planbench.errors import PlanbenchError
from planbench.robot import Robot
from planbench.scene import Obstacle, Scene

__all__ = ["VampRobot", "UnsupportedRobotError", "vamp_robot", "environment", "SUPPORTED_ROBOTS"]

CYLINDER_MODES = ("capsule", "box")
FK_TOLERANCE = 1e-3  # [m] largest disagreement of the two forward kinematics accepted


@dataclass(frozen=True)
class _RobotMatch:
    """How a planbench robot maps onto one of VAMP's: VAMP's module name, where planbench's base
    frame stands in VAMP's world (a 4x4), and a planbench frame with the fixed offset (a 4x4) from
    it to VAMP's end-effector frame, for the kinematics check."""

    module: str
    base: np.ndarray
    frame: str
    to_vamp_ee: np.ndarray


def _pose(xyz: Sequence[float], yaw: float = 0.0) -> np.ndarray:
    return pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, yaw), np.array(xyz, dtype=float)).homogeneous  # type: ignore[no-any-return]


# planbench robot name -> VAMP's robot. The offsets are read off VAMP's URDFs (resources/<robot>/):
# panda_grasptarget is 0.105 m along panda_hand's z; robotiq_85_base_link 0.035 m along tool0's z;
# VAMP's UR5 base is its URDF's offset_joint (0.9144 m up, 1.57 rad about z).
_MATCHES = {
    "panda": _RobotMatch("panda", np.eye(4), "panda_hand", _pose((0.0, 0.0, 0.105))),
    "ur5": _RobotMatch("ur5", _pose((0.0, 0.0, 0.9144), 1.57), "tool0", _pose((0.0, 0.0, 0.035))),
}
SUPPORTED_ROBOTS: tuple[str, ...] = tuple(_MATCHES)
"""planbench robots that VAMP has a compiled model of (those VAMP ships that planbench has)."""


class UnsupportedRobotError(PlanbenchError, ValueError):
    """A VAMP planner asked to plan for a robot VAMP has no compiled model of (or whose model does
    not match planbench's robot of that name): names the robot, the reason and the robots it can."""

    def __init__(self, robot: str, reason: str) -> None:
        self.robot = robot
        self.reason = reason
        super().__init__(
            f"VAMP cannot plan for robot {robot!r}: {reason}. VAMP planners plan for "
            f"{', '.join(SUPPORTED_ROBOTS)} (the robots VAMP ships a sphere model of that planbench has)"
        )


@dataclass
class VampRobot:
    """A planbench robot's VAMP counterpart: ``module`` (``vamp.panda`` ...), ``base`` (4x4, planbench's
    base frame in VAMP's world) and VAMP's own joint limits (``lower``, ``upper`` [rad])."""

    name: str
    module: Any
    base: np.ndarray
    lower: np.ndarray = field(repr=False)
    upper: np.ndarray = field(repr=False)

    @property
    def radii(self) -> tuple[float, float]:
        """VAMP's smallest and largest robot sphere radius [m] (what its point clouds are built for)."""
        lo, hi = self.module.min_max_radii()
        return float(lo), float(hi)


def vamp_robot(robot: Robot) -> VampRobot:
    """VAMP's model of ``robot``, or :class:`UnsupportedRobotError` (see the module docstring)."""
    match = _MATCHES.get(robot.name)
    if match is None:
        raise UnsupportedRobotError(robot.name, "VAMP has no model of it")
    if match.module not in vamp.robots:
        raise UnsupportedRobotError(
            robot.name, f"this vamp-planner build has no {match.module!r} module (it has {', '.join(vamp.robots)})"
        )
    module = getattr(vamp, match.module)
    if tuple(module.joint_names()) != tuple(robot.joint_names):
        raise UnsupportedRobotError(
            robot.name, f"VAMP's joints {list(module.joint_names())} are not planbench's {list(robot.joint_names)}"
        )
    lower = np.maximum(robot.lower, -math.pi)
    upper = np.minimum(robot.upper, math.pi)
    for k in range(3):  # three fixed configurations within both robots' limits
        q = lower + (0.25 + 0.25 * k) * (upper - lower)
        ours = match.base @ robot.frame_pose(q, match.frame).homogeneous @ match.to_vamp_ee
        theirs = np.asarray(module.eefk(q.astype(np.float32)), dtype=float)
        gap = float(np.linalg.norm(ours[:3, 3] - theirs[:3, 3]))
        if not gap <= FK_TOLERANCE:
            raise UnsupportedRobotError(
                robot.name,
                f"VAMP's kinematics differ from this robot's by {gap * 1e3:.1f} mm at q={np.round(q, 3).tolist()}",
            )
    return VampRobot(
        robot.name,
        module,
        match.base,
        np.asarray(module.lower_bounds(), dtype=float),
        np.asarray(module.upper_bounds(), dtype=float),
    )


def _transform(base: np.ndarray, obstacle: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """The obstacle's rotation (3x3) and position (3,) in VAMP's world frame."""
    R = base[:3, :3] @ obstacle.rotation
    p = base[:3, :3] @ np.asarray(obstacle.position, dtype=float) + base[:3, 3]
    return R, p


def _euler_xyz(R: np.ndarray) -> list[float]:
    """VAMP's Euler XYZ angles of ``R`` (its factories build ``Rz(c) Ry(b) Rx(a)`` from ``[a, b, c]``:
    scipy's extrinsic ``"xyz"``)."""
    return [float(a) for a in Rotation.from_matrix(R).as_euler("xyz")]


def mesh_surface_points(obstacle: Obstacle, spacing: float) -> np.ndarray:
    """Points on a mesh obstacle's surface, in its local frame (scaled), no two neighbours on a
    triangle farther apart than ``spacing`` [m]: the vertices of the mesh subdivided to that edge."""
    import trimesh

    mesh: Any = trimesh.load(str(obstacle.path), force="mesh")
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * np.asarray(obstacle.scale, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    v, _ = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=spacing, max_iter=30)
    return np.unique(np.asarray(v, dtype=np.float64), axis=0)


def environment(
    scene: Scene,
    robot: VampRobot,
    *,
    cylinders: str = "box",
    mesh_spacing: float = 0.01,
) -> tuple[Any, dict[str, int]]:
    """``scene`` as a ``vamp.Environment`` for ``robot`` (module docstring), and how many VAMP
    primitives of each kind it holds (``cuboids``, ``spheres``, ``capsules``, ``cloud_points``)."""
    if cylinders not in CYLINDER_MODES:
        raise ValueError(f"cylinders must be one of {CYLINDER_MODES}, got {cylinders!r}")
    env = vamp.Environment()
    counts = {"cuboids": 0, "spheres": 0, "capsules": 0, "cloud_points": 0}
    r_min, r_max = robot.radii
    for ob in scene.obstacles:
        R, p = _transform(robot.base, ob)
        if ob.type == "box" or (ob.type == "cylinder" and cylinders == "box"):
            half = ob.local_half_extents()
            env.add_cuboid(vamp.Cuboid(p.tolist(), _euler_xyz(R), half.tolist()))
            counts["cuboids"] += 1
        elif ob.type == "sphere":
            env.add_sphere(vamp.Sphere(p.tolist(), float(ob.radius)))  # type: ignore[arg-type]
            counts["spheres"] += 1
        elif ob.type in ("cylinder", "capsule"):
            # centre, Euler angles, radius, length: the segment along the local z axis. (VAMP 0.6.4's
            # two-endpoint constructor writes into an unconstructed object and crashes the process.)
            capsule = vamp.Cylinder(p.tolist(), _euler_xyz(R), float(ob.radius), float(ob.length))  # type: ignore[arg-type]
            env.add_capsule(capsule)
            counts["capsules"] += 1
        else:  # a mesh's surface or a point cloud's cubes, as points
            if ob.type == "mesh":
                local, radius = mesh_surface_points(ob, mesh_spacing), 0.6 * mesh_spacing
            else:
                cloud = ob.cloud()
                local, radius = (cloud.cells + 0.5) * cloud.cell, 0.5 * math.sqrt(3.0) * cloud.cell
            points = local @ R.T + p
            env.add_pointcloud(points.astype(np.float32).tolist(), r_min, r_max, float(radius))
            counts["cloud_points"] += len(points)
    return env, counts
