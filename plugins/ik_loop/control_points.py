"""Control points on the arm, where the repulsive field is sampled (docs/method.md, section 4, step 5).

Automatic placement, from the robot's collision geometry: the geometries of each link (pinocchio
names them ``<link>_<k>``) are bounded by one box in the frame of the joint that carries them. The
points lie on the box's long axis, through its centre, evenly spaced at most ``spacing`` apart,
inset from both ends by the link's radius (half the larger cross-section extent) so that spheres
of that radius around the points span the link. Links on the fixed base (joint 0) get none: the
planner cannot move them. ``overrides`` replaces the points of named links (coordinates in the
link frame [m]); an empty list removes a link's points.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ControlPoints", "place_control_points"]


@dataclass(frozen=True, eq=False)
class ControlPoints:
    """N points rigidly attached to the robot.

    ``joint`` (N,) pinocchio joint index carrying each point; ``local`` (N, 3) position in that
    joint's frame [m]; ``radius`` (N,) half-thickness of the link around the point [m] (0 for
    user-given points); ``link`` (N,) link names.
    """

    joint: np.ndarray
    local: np.ndarray
    radius: np.ndarray
    link: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.joint)

    def world(self, robot: Any, q: np.ndarray) -> np.ndarray:
        """World positions (N, 3) [m] at configuration ``q`` (slow path, for plots and tests)."""
        import pinocchio as pin

        data = robot.model.createData()
        pin.forwardKinematics(robot.model, data, np.asarray(q, dtype=float))
        return np.array([data.oMi[int(j)].act(p) for j, p in zip(self.joint, self.local, strict=True)]).reshape(-1, 3)


def _link_name(geometry_name: str) -> str:
    base, _, idx = geometry_name.rpartition("_")
    return base if base and idx.isdigit() else geometry_name


def _link_boxes(robot: Any) -> dict[str, tuple[int, Any, np.ndarray, np.ndarray]]:
    """Per link: (joint, box frame in the joint frame, lower and upper corner in the box frame).

    The box frame is the placement of the link's largest geometry, so a geometry mounted at an
    angle (the Panda's hand, at 45 degrees) still gets a tight box.
    """
    corners01 = np.array(list(np.ndindex(2, 2, 2)), dtype=float)
    per_link: dict[str, list[tuple[int, Any, np.ndarray]]] = {}
    for g in robot.collision_model.geometryObjects:
        if g.parentJoint == 0:
            continue
        geom = g.geometry
        geom.computeLocalAABB()
        lo, hi = np.array(geom.aabb_local.min_), np.array(geom.aabb_local.max_)
        corners = lo + corners01 * (hi - lo)
        pl = g.placement
        in_joint = corners @ pl.rotation.T + pl.translation
        per_link.setdefault(_link_name(g.name), []).append((int(g.parentJoint), pl, in_joint))
    boxes = {}
    for link, items in per_link.items():
        j, frame, _ = max(items, key=lambda it: float(np.prod(np.ptp(it[2], axis=0))))
        pts = np.concatenate([c for _, _, c in items]) if all(it[0] == j for it in items) else items[0][2]
        in_box = (pts - frame.translation) @ frame.rotation
        boxes[link] = (j, frame, in_box.min(0), in_box.max(0))
    return boxes


def place_control_points(
    robot: Any, spacing: float = 0.12, overrides: Sequence[tuple[str, Sequence[Sequence[float]]]] | None = None
) -> ControlPoints:
    """Control points along every moving link of ``robot`` (see the module docstring).

    ``spacing`` [m] is the largest gap between neighbouring points of one link. ``overrides``:
    ``[(link, [[x, y, z], ...]), ...]`` in the link frame [m] (a pinocchio frame name).
    """
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be > 0 [m], got {spacing}")
    model = robot.model
    over = dict(overrides or ())
    joints: list[int] = []
    local: list[np.ndarray] = []
    radius: list[float] = []
    links: list[str] = []
    for link, (j, frame, lo, hi) in _link_boxes(robot).items():
        if link in over:
            continue
        ext = hi - lo
        centre = 0.5 * (lo + hi)
        a = int(np.argmax(ext))
        r = 0.5 * float(max(ext[b] for b in range(3) if b != a))
        half = max(0.5 * float(ext[a]) - r, 0.0)
        n = int(math.ceil(2 * half / spacing - 1e-9)) + 1 if 2 * half > 0.1 * spacing else 1
        offsets = np.linspace(-half, half, n) if n > 1 else np.zeros(1)
        for s in offsets:
            p = centre.copy()
            p[a] += s
            joints.append(j)
            local.append(frame.act(p))
            radius.append(r)
            links.append(link)
    for link, pts in over.items():
        if not model.existFrame(link):
            from planbench.errors import UnknownNameError

            raise UnknownNameError("link (frame) for control points", link, [f.name for f in model.frames])
        fr = model.frames[model.getFrameId(link)]
        for p in pts:
            joints.append(int(fr.parentJoint))
            local.append(fr.placement.act(np.asarray(p, dtype=float)))
            radius.append(0.0)
            links.append(link)
    joint_arr = np.array(joints, dtype=int)
    if np.any(joint_arr == 0):
        raise ValueError("control points on the fixed base (joint 0) cannot be moved by the planner")
    return ControlPoints(joint_arr, np.array(local, dtype=float).reshape(-1, 3), np.array(radius), tuple(links))
