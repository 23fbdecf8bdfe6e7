"""Seeded generators of planning problems in scene families of our own, for any arm.

Every size and place is derived from the arm itself (:func:`workspace`): ``r`` is its workspace
radius (the farthest the end effector gets from the shoulder, over sampled configurations), ``h``
the shoulder height, and directions are measured from the azimuth of its home end effector. So the
same family gives a Panda, a UR5 or a UR10 scenes of the same difficulty, scaled to each. Families
(all lengths are fractions of ``r``; the floor lies at ``h - 0.8 r`` in every scene):

- ``shelf``: a shelf unit (back, sides, boards, dividers, plinth to the floor) facing the robot,
  front ``0.40-0.60`` away, at ``0.3-1.9`` rad from the home direction, turned ``+-0.4`` rad; width
  ``0.55-1.10``, depth ``0.30-0.45``, 2-4 rows of ``0.25-0.38`` high, 1-3 columns at least ``0.30``
  wide. Goal: the end effector inside a compartment, ``0.15-0.55`` of the depth in, pointing in.
- ``window``: a wall ``0.35-0.50`` away (``0.6-1.9`` rad from home), ``1.2-1.8`` wide, from the
  floor to ``h + 0.6-0.9``, ``0.03-0.06`` thick, with a rectangular opening ``0.35-0.50`` by
  ``0.35-0.50`` centred ``+-0.2`` sideways and at ``h +- 0.25``. Goal: the end effector
  ``0.08-0.30`` beyond the wall, in line with the opening, pointing through it.
- ``pillars``: two pillars ``0.35-0.50`` away flanking a gap of ``0.28-0.40`` (``0.3-1.9`` rad from
  home), one pillar between the home direction and the gap, and 2-5 more anywhere ``0.30-0.85`` away;
  cylinders of radius ``0.03-0.07`` or boxes ``0.06-0.14`` wide, from the floor to ``h + 0.5-1.0``.
  Goal: the end effector ``0.10-0.30`` beyond the gap, at ``h - 0.45..+0.25``, pointing outwards.
- ``table_clutter``: pick and place. A table (top on 4 legs) ``0.20-0.35`` away (``0-1.2`` rad from
  home), ``0.9-1.4`` wide, ``0.55-0.80`` deep, top at ``h - 0.55..-0.30``; two spots on it at least
  ``0.35`` apart, each ringed (``0.12-0.22`` out) by 2-3 objects ``0.15-0.35`` tall, the first of
  them between the spot and the other one, and 2-5 objects ``0.08-0.35`` tall elsewhere (boxes and
  cylinders ``0.05-0.12`` across). Start and goal: the end effector ``0.08-0.22`` above a spot,
  pointing down (the start is found by IK too, not near home).

Goal directions are tilted by a few tenths of a radian at random. A problem:

- start: the home configuration plus ``N(0, 0.15 rad)`` per joint (within the limits), at least
  3 cm from every obstacle (table_clutter: like a goal, on its first spot);
- goal: a configuration from our own IK (damped least squares on the end-effector position and its
  approach axis, the frame's local z, from guesses near home turned towards the target and from
  random configurations) with the end effector on the target point, at least 1 cm from every
  obstacle, and, like the start, at least 5 mm from self-contact; of the first 3 such solutions,
  the one nearest the start;
- both pass :meth:`Problem.check`, and the straight joint-space line between them must collide
  (certified checker): no problem is solved by the straight line.

A scene whose start, IK or checks fail is drawn again (``attempts`` counts the draws). Problem
``index`` of ``(robot, family, seed)`` draws from its own generator, seeded with
``[seed, crc32("<robot>/<family>"), index]``, so every problem can be regenerated alone; lengths are
rounded to 0.1 mm and joint values to 1 urad, so files come out byte-identical.

The shipped set (``planbench/data/gen``, selector ``gen:<robot>_<family>/<range>``) is regenerated
with ``python -m planbench.problems.generate --out planbench/data/gen`` (its command line: :func:`main`).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import math
import sys
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.checking.collision import CollisionChecker, fresh_geometry_data
from planbench.errors import InvalidConfigError, PlanbenchError, UnknownNameError
from planbench.harness import plan
from planbench.problem import Problem
from planbench.problems.datasets import GEN_SEED, problem_from_record, shipped_problems, shipped_sets
from planbench.robot import Robot, load_robot
from planbench.scene import Obstacle, Scene
from planbench.validate import evaluate, verdict_checker

__all__ = [
    "FAMILIES",
    "GENERATOR",
    "GenerationError",
    "Workspace",
    "generate",
    "generate_problem",
    "shipped_problems",
    "shipped_sets",
    "solve_ik",
    "workspace",
]

GENERATOR_VERSION = 1
GENERATOR = f"planbench.generators/{GENERATOR_VERSION}"  # the generator's name in the files: kept across moves
FAMILIES = ("shelf", "window", "pillars", "table_clutter")
GEN_FORMAT = "planbench-gen/1"
MANIFEST_FORMAT = "planbench-gen-manifest/1"
SHIPPED_ROBOTS = ("panda", "ur5", "xarm7")
SHIPPED_COUNT = 25
SHIPPED_SEED = GEN_SEED
COMMAND = "python -m planbench.problems.generate --out planbench/data/gen"

START_NOISE = 0.15  # [rad] standard deviation of the start's offset from home, per joint
START_CLEARANCE = 0.03  # [m] from obstacles
GOAL_CLEARANCE = 0.01  # [m] from obstacles
SELF_CLEARANCE = 0.005  # [m] between the robot's own links (start and goal)
MAX_ATTEMPTS = 400
GOAL_CANDIDATES = 3  # valid IK solutions compared; the goal is the one nearest the start


class GenerationError(PlanbenchError):
    """No valid problem within the attempts allowed (the family does not suit this robot)."""


# --- the robot's workspace ------------------------------------------------------------------


@dataclass(frozen=True)
class Workspace:
    """What the generators scale and place by. Units: m, rad.

    ``shoulder``: the origin of the second joint at home; ``reach``: the farthest the end effector
    gets from it over 4000 random configurations; ``home_azimuth``: the direction of the home end
    effector about the base z axis. Rounded to mm and mrad (robust to round-off across machines).
    """

    shoulder: tuple[float, float, float]
    reach: float
    home_azimuth: float

    @property
    def height(self) -> float:
        return self.shoulder[2]

    @property
    def floor(self) -> float:
        """Height [m] of the floor's top surface."""
        return round(self.height - 0.8 * self.reach, 4)

    def to_dict(self) -> dict[str, Any]:
        return {"shoulder": list(self.shoulder), "reach": self.reach, "home_azimuth": self.home_azimuth}


@functools.lru_cache(maxsize=16)
def workspace(robot: Robot) -> Workspace:
    """The robot's :class:`Workspace` (computed once per robot)."""
    model = robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, np.asarray(robot.home))
    shoulder = np.array(data.oMi[min(2, model.njoints - 1)].translation)
    rng = np.random.default_rng(0)
    reach = 0.0
    for _ in range(4000):
        pin.framesForwardKinematics(model, data, rng.uniform(robot.lower, robot.upper))
        reach = max(reach, float(np.linalg.norm(data.oMf[robot.ee_frame_id].translation - shoulder)))
    pin.framesForwardKinematics(model, data, np.asarray(robot.home))
    p = data.oMf[robot.ee_frame_id].translation
    azimuth = math.atan2(p[1], p[0]) if math.hypot(p[0], p[1]) > 1e-3 else 0.0
    x, y, z = (round(float(v), 3) + 0.0 for v in shoulder)  # + 0.0: no -0.0
    return Workspace((x, y, z), round(reach, 3), round(azimuth, 3) + 0.0)


# --- geometry helpers -------------------------------------------------------------------------


def _round(v: Any, digits: int = 4) -> tuple[float, ...]:
    return tuple(round(float(x), digits) + 0.0 for x in v)  # + 0.0: no -0.0 in the files


def _vec3(v: Any) -> tuple[float, float, float]:
    x, y, z = _round(v)
    return x, y, z


def _yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


@dataclass(frozen=True)
class _Frame:
    """A horizontal frame: origin (x, y, z) [m] and yaw [rad] (local x turned by yaw about z)."""

    origin: tuple[float, float, float]
    yaw: float

    def point(self, local: Sequence[float]) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x, y, z = local
        return np.array([self.origin[0] + c * x - s * y, self.origin[1] + s * x + c * y, self.origin[2] + z])

    def direction(self, local: Sequence[float]) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x, y, z = local
        return np.array([c * x - s * y, s * x + c * y, z])


def _radial(azimuth: float, distance: float) -> _Frame:
    """The frame at ``distance`` from the base axis in direction ``azimuth``, x pointing away."""
    return _Frame((distance * math.cos(azimuth), distance * math.sin(azimuth), 0.0), azimuth)


def _box(name: str, frame: _Frame, lo: Sequence[float], hi: Sequence[float], yaw: float = 0.0) -> Obstacle:
    """A box spanning local corners ``lo``-``hi`` of ``frame`` (turned by ``yaw`` about its centre)."""
    centre = frame.point(0.5 * (np.asarray(lo) + np.asarray(hi)))
    size = np.abs(np.asarray(hi, dtype=float) - np.asarray(lo, dtype=float))
    angle = round(math.remainder(frame.yaw + yaw, math.tau), 4)
    return Obstacle(name, "box", _vec3(centre), _yaw_quat(angle), size=_vec3(size))


def _cylinder(name: str, centre: np.ndarray, radius: float, length: float) -> Obstacle:
    return Obstacle(name, "cylinder", _vec3(centre), radius=round(radius, 4), length=round(length, 4))


def _tilted(rng: np.random.Generator, axis: np.ndarray, max_tilt: float) -> np.ndarray:
    """``axis`` turned by up to ``max_tilt`` [rad] towards a random direction (a unit vector)."""
    axis = axis / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    phi, tilt = rng.uniform(-math.pi, math.pi), rng.uniform(0.0, max_tilt)
    out = math.cos(tilt) * axis + math.sin(tilt) * (math.cos(phi) * u + math.sin(phi) * v)
    return np.array(_round(out / np.linalg.norm(out), 6))


def _offset(rng: np.random.Generator, lo: float, hi: float) -> float:
    """An azimuth offset [rad] from home of ``lo``-``hi``, to either side."""
    return float(rng.uniform(lo, hi) * rng.choice([-1.0, 1.0]))


def _floor(ws: Workspace) -> Obstacle:
    r = ws.reach
    t = 0.02 * r
    return _box("floor", _Frame((0.0, 0.0, 0.0), 0.0), (-1.1 * r, -1.1 * r, ws.floor - t), (1.1 * r, 1.1 * r, ws.floor))


# --- families -----------------------------------------------------------------------------------


@dataclass
class _Layout:
    """One draw of a family: obstacles, the goal's target point [m] and approach axis, parameters."""

    obstacles: list[Obstacle]
    target: np.ndarray
    approach: np.ndarray
    params: dict[str, Any] = field(default_factory=dict)
    start_target: np.ndarray | None = None  # the start is IK onto this, not near home, when given
    start_approach: np.ndarray | None = None


def _shelf(rng: np.random.Generator, ws: Workspace) -> _Layout:
    r = ws.reach
    width, depth, t = rng.uniform(0.55, 1.10) * r, rng.uniform(0.30, 0.45) * r, rng.uniform(0.02, 0.03) * r
    rows = int(rng.integers(2, 5))
    heights = rng.uniform(0.25, 0.38, rows) * r
    cols = int(rng.integers(1, min(3, int(width / (0.30 * r))) + 1))
    azimuth = ws.home_azimuth + _offset(rng, 0.3, 1.9)
    front = rng.uniform(0.40, 0.60) * r
    turn = rng.uniform(-0.4, 0.4)
    base = ws.floor + rng.uniform(0.0, 0.3) * r  # top of the plinth = bottom of the lowest board
    f = _Frame(_radial(azimuth, front).origin, azimuth + turn)
    w2 = width / 2
    tops = base + t + np.cumsum(heights + t)  # top of each row's upper board
    top = float(tops[-1])
    obstacles = [_floor(ws)]
    if round(base - ws.floor, 4) > 0:  # a plinth thinner than the files' 0.1 mm is none (not a 0-high box)
        obstacles.append(_box("plinth", f, (0.0, -w2 - t, ws.floor), (depth + t, w2 + t, base)))
    obstacles += [
        _box("back", f, (depth, -w2 - t, base), (depth + t, w2 + t, top)),
        _box("left", f, (0.0, w2, base), (depth, w2 + t, top)),
        _box("right", f, (0.0, -w2 - t, base), (depth, -w2, top)),
        _box("board0", f, (0.0, -w2, base), (depth, w2, base + t)),
    ]
    for i in range(rows):
        obstacles.append(_box(f"board{i + 1}", f, (0.0, -w2, tops[i] - t), (depth, w2, tops[i])))
    col_w = (width - (cols - 1) * t) / cols
    for j in range(1, cols):
        y = -w2 + j * col_w + (j - 1) * t
        obstacles.append(_box(f"divider{j}", f, (0.0, y, base + t), (depth, y + t, top - t)))
    row, col = int(rng.integers(rows)), int(rng.integers(cols))
    floor_z = float(tops[row] - t - heights[row])
    local = (
        rng.uniform(0.15, 0.55) * depth,
        -w2 + col * (col_w + t) + col_w * rng.uniform(0.3, 0.7),
        floor_z + heights[row] * rng.uniform(0.35, 0.65),
    )
    target = f.point(local)
    approach = _tilted(rng, f.direction((1.0, 0.0, 0.0)), 0.3)
    params = {"rows": rows, "columns": cols, "compartment": [row, col], "azimuth": round(azimuth, 4)}
    return _Layout(obstacles, target, approach, params)


def _window(rng: np.random.Generator, ws: Workspace) -> _Layout:
    r, h = ws.reach, ws.height
    azimuth = ws.home_azimuth + _offset(rng, 0.6, 1.9)
    dist, t = rng.uniform(0.35, 0.50) * r, rng.uniform(0.03, 0.06) * r
    w2, top = rng.uniform(0.6, 0.9) * r, h + rng.uniform(0.6, 0.9) * r
    ow, oh = rng.uniform(0.35, 0.50) * r, rng.uniform(0.35, 0.50) * r
    oy, oz = rng.uniform(-0.2, 0.2) * r, h + rng.uniform(-0.25, 0.25) * r
    f = _radial(azimuth, dist)
    y0, y1, z0, z1 = oy - ow / 2, oy + ow / 2, oz - oh / 2, oz + oh / 2
    obstacles = [
        _floor(ws),
        _box("wall_left", f, (0.0, y1, ws.floor), (t, w2, top)),
        _box("wall_right", f, (0.0, -w2, ws.floor), (t, y0, top)),
        _box("wall_below", f, (0.0, y0, ws.floor), (t, y1, z0)),
        _box("wall_above", f, (0.0, y0, z1), (t, y1, top)),
    ]
    local = (t + rng.uniform(0.08, 0.30) * r, oy + rng.uniform(-0.3, 0.3) * ow, oz + rng.uniform(-0.3, 0.3) * oh)
    target = f.point(local)
    approach = _tilted(rng, f.direction((1.0, 0.0, 0.0)), 0.25)
    params = {"opening": [round(ow, 4), round(oh, 4)], "azimuth": round(azimuth, 4)}
    return _Layout(obstacles, target, approach, params)


def _pillar(rng: np.random.Generator, name: str, xy: np.ndarray, ws: Workspace, size: float) -> Obstacle:
    """A pillar from the floor up, ``size`` [m] its half width (radius of a cylinder)."""
    top = ws.height + rng.uniform(0.5, 1.0) * ws.reach
    if rng.random() < 0.5:
        return _cylinder(name, np.array([xy[0], xy[1], (ws.floor + top) / 2]), size, top - ws.floor)
    lo, hi = (-size, -size, ws.floor), (size, size, top)
    return _box(name, _Frame((float(xy[0]), float(xy[1]), 0.0), 0.0), lo, hi, float(rng.uniform(0, math.pi / 2)))


def _pillars(rng: np.random.Generator, ws: Workspace) -> _Layout:
    r, h = ws.reach, ws.height
    offset = _offset(rng, 0.3, 1.9)
    azimuth = ws.home_azimuth + offset
    dist, gap = rng.uniform(0.35, 0.50) * r, rng.uniform(0.28, 0.40) * r
    f = _radial(azimuth, dist)
    sizes = [rng.uniform(0.03, 0.07) * r for _ in range(2)]
    centres = [f.point((0.0, gap / 2 + sizes[0], 0.0))[:2], f.point((0.0, -gap / 2 - sizes[1], 0.0))[:2]]
    between = ws.home_azimuth + offset * rng.uniform(0.35, 0.65)
    sizes.append(rng.uniform(0.03, 0.07) * r)
    centres.append(_radial(between, rng.uniform(0.35, 0.60) * r).point((0.0, 0.0, 0.0))[:2])
    for _ in range(int(rng.integers(2, 6))):
        size = rng.uniform(0.03, 0.07) * r
        for _try in range(20):
            xy = _radial(rng.uniform(-math.pi, math.pi), rng.uniform(0.30, 0.85) * r).point((0.0, 0.0, 0.0))[:2]
            if all(np.linalg.norm(xy - c) > s + size + 0.25 * r for c, s in zip(centres, sizes, strict=True)):
                centres.append(xy)
                sizes.append(size)
                break
    pillars = [_pillar(rng, f"pillar{i}", c, ws, s) for i, (c, s) in enumerate(zip(centres, sizes, strict=True))]
    obstacles = [_floor(ws), *pillars]
    local = (rng.uniform(0.10, 0.30) * r, rng.uniform(-0.15, 0.15) * gap, h + rng.uniform(-0.45, 0.25) * r)
    target = f.point(local)
    approach = _tilted(rng, f.direction((1.0, 0.0, 0.0)), 0.3)
    params = {"pillars": len(centres), "gap": round(gap, 4), "azimuth": round(azimuth, 4)}
    return _Layout(obstacles, target, approach, params)


def _table_clutter(rng: np.random.Generator, ws: Workspace) -> _Layout:
    r, h = ws.reach, ws.height
    azimuth = ws.home_azimuth + _offset(rng, 0.0, 1.2)
    near, width, depth = rng.uniform(0.20, 0.35) * r, rng.uniform(0.9, 1.4) * r, rng.uniform(0.55, 0.80) * r
    z_top, t, leg = h + rng.uniform(-0.55, -0.30) * r, 0.04 * r, 0.03 * r
    f = _Frame(_radial(azimuth, near).origin, azimuth + rng.uniform(-0.3, 0.3))
    w2 = width / 2
    obstacles = [_floor(ws), _box("table_top", f, (0.0, -w2, z_top - t), (depth, w2, z_top))]
    for i, (x, y) in enumerate([(leg, -w2 + leg), (leg, w2 - leg), (depth - leg, -w2 + leg), (depth - leg, w2 - leg)]):
        c = f.point((x, y, (ws.floor + z_top - t) / 2))
        obstacles.append(_cylinder(f"leg{i}", c, leg, z_top - t - ws.floor))

    def spot() -> np.ndarray:
        return np.array([rng.uniform(0.15, 0.6) * depth, rng.uniform(-0.4, 0.4) * width])

    pick = spot()
    place = spot()
    for _try in range(20):
        if np.linalg.norm(place - pick) >= 0.35 * r:
            break
        place = spot()
    placed: list[tuple[np.ndarray, float, float]] = []  # centre, width, height

    def put(xy: np.ndarray, size: float, tall: float, keep_off: float) -> bool:
        inside = size / 2 <= xy[0] <= depth - size / 2 and abs(xy[1]) <= w2 - size / 2
        apart = all(np.linalg.norm(xy - c) > (size + w) / 2 + 0.02 * r for c, w, _ in placed)
        clear = min(np.linalg.norm(xy - pick), np.linalg.norm(xy - place)) >= keep_off * r + size / 2
        ok = bool(inside and apart and clear)
        if ok:
            placed.append((xy, size, tall))
        return ok

    for here, there in ((place, pick), (pick, place)):  # objects around both spots, one between them
        n_near = int(rng.integers(2, 4))
        towards = math.atan2(*(there - here)[::-1])
        for k in range(n_near):
            size, tall = rng.uniform(0.05, 0.12) * r, rng.uniform(0.15, 0.35) * r
            for _try in range(20):
                angle = towards + k * math.tau / n_near + rng.uniform(-0.4, 0.4)
                xy = here + rng.uniform(0.12, 0.22) * r * np.array([math.cos(angle), math.sin(angle)])
                if put(xy, size, tall, 0.05):
                    break
    for _ in range(int(rng.integers(2, 6))):
        size, tall = rng.uniform(0.05, 0.12) * r, rng.uniform(0.08, 0.35) * r
        for _try in range(20):
            if put(np.array([rng.uniform(0.0, depth), rng.uniform(-w2, w2)]), size, tall, 0.15):
                break
    for i, (xy, size, tall) in enumerate(placed):
        if rng.random() < 0.5:
            lo, hi = (xy[0] - size / 2, xy[1] - size / 2, z_top), (xy[0] + size / 2, xy[1] + size / 2, z_top + tall)
            obstacles.append(_box(f"object{i}", f, lo, hi, float(rng.uniform(0, math.pi / 2))))
        else:
            obstacles.append(_cylinder(f"object{i}", f.point((xy[0], xy[1], z_top + tall / 2)), size / 2, tall))
    down = np.array([0.0, 0.0, -1.0])
    start_target = f.point((pick[0], pick[1], z_top + rng.uniform(0.08, 0.22) * r))
    start_approach = _tilted(rng, down, 0.35)
    target = f.point((place[0], place[1], z_top + rng.uniform(0.08, 0.22) * r))
    approach = _tilted(rng, down, 0.35)
    params = {"objects": len(placed), "start_target": list(_round(start_target)), "azimuth": round(azimuth, 4)}
    return _Layout(obstacles, target, approach, params, start_target, start_approach)


_FAMILIES: dict[str, Callable[[np.random.Generator, Workspace], _Layout]] = {
    "shelf": _shelf,
    "window": _window,
    "pillars": _pillars,
    "table_clutter": _table_clutter,
}


# --- inverse kinematics ---------------------------------------------------------------------------


def solve_ik(
    robot: Robot,
    target: np.ndarray,
    approach: np.ndarray,
    guesses: Sequence[np.ndarray],
    iterations: int = 200,
    damping: float = 1e-4,
    max_step: float = 0.3,
) -> Iterator[np.ndarray]:
    """Configurations putting the end effector at ``target`` [m] with its local z axis along the
    unit vector ``approach`` (rotation about it free), one per initial guess that converges (to
    0.1 mm and 1 mrad): damped least squares on the 6 errors (position, axis), each step at most
    ``max_step`` [rad] per joint, joints clipped to their limits."""
    model = robot.model
    data = model.createData()
    fid = robot.ee_frame_id
    target = np.asarray(target, dtype=float)
    approach = np.asarray(approach, dtype=float)
    eye = np.eye(6)
    for guess in guesses:
        q = np.clip(np.asarray(guess, dtype=float), robot.lower, robot.upper)
        for _ in range(iterations):
            J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
            M = data.oMf[fid]
            z = M.rotation[:, 2]
            err = np.concatenate([M.translation - target, z - approach])
            if np.linalg.norm(err[:3]) < 1e-4 and np.linalg.norm(err[3:]) < 1e-3:
                yield q
                break
            A = np.vstack([J[:3], -pin.skew(z) @ J[3:]])
            dq = -A.T @ np.linalg.solve(A @ A.T + damping * eye, err)
            dq *= min(1.0, max_step / max(float(np.abs(dq).max()), 1e-300))
            q = np.clip(q + dq, robot.lower, robot.upper)


# --- problems --------------------------------------------------------------------------------------


class _Distances:
    """Smallest distances [m] at q: robot to obstacles, and robot to itself (every checked pair)."""

    def __init__(self, checker: CollisionChecker) -> None:
        self.model = checker.robot.model
        self.data = self.model.createData()
        self.geometry_model = checker.geometry_model
        self.geometry_data = fresh_geometry_data(checker.geometry_model)
        n = checker.n_robot_geoms
        self.obstacle = np.array([max(p.first, p.second) >= n for p in checker.geometry_model.collisionPairs])

    def __call__(self, q: np.ndarray) -> tuple[float, float]:
        pin.computeDistances(self.model, self.data, self.geometry_model, self.geometry_data, q)
        d = np.array([res.min_distance for res in self.geometry_data.distanceResults])
        obstacles, own = d[self.obstacle], d[~self.obstacle]
        return (float(obstacles.min()) if obstacles.size else math.inf, float(own.min()) if own.size else math.inf)


def _rng(robot: Robot, family: str, seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(f"{robot.name}/{family}".encode()), index])


def problem_id(robot_name: str, family: str, index: int, seed: int = SHIPPED_SEED) -> str:
    """``gen:<robot>_<family>/<index>`` (``gen-s<seed>:...`` for a seed other than the shipped one)."""
    prefix = "gen" if seed == SHIPPED_SEED else f"gen-s{seed}"
    return f"{prefix}:{robot_name}_{family}/{index:04d}"


def _reach_into(
    robot: Robot,
    target: np.ndarray,
    approach: np.ndarray,
    near: np.ndarray,
    rng: np.random.Generator,
    checker: CollisionChecker,
    distances: _Distances,
) -> tuple[np.ndarray | None, str]:
    """An IK configuration onto ``target`` that is free with the margins, the nearest to ``near`` of
    up to GOAL_CANDIDATES; guesses: home turned towards the target, perturbed, then random."""
    ws = workspace(robot)
    turned = np.array(robot.home)
    turned[0] += math.remainder(math.atan2(target[1], target[0]) - ws.home_azimuth, math.tau)
    guesses = [turned] + [turned + rng.normal(0.0, 0.1 * k, robot.nq) for k in range(1, 8)]
    guesses += [rng.uniform(robot.lower, robot.upper) for _ in range(6)]
    found = []
    converged = False
    for q in solve_ik(robot, target, approach, guesses):
        converged = True
        q = np.round(q, 6) + 0.0
        if robot.limit_violations(q) or checker.in_collision(q):
            continue
        d_obstacle, d_self = distances(q)
        if d_obstacle >= GOAL_CLEARANCE and d_self >= SELF_CLEARANCE:
            found.append(q)
            if len(found) == GOAL_CANDIDATES:
                break
    if not found:
        return None, "collision" if converged else "ik"
    return min(found, key=lambda q: float(np.linalg.norm(q - near))), ""


def _attempt(robot: Robot, family: str, rng: np.random.Generator, reasons: Counter[str]) -> tuple[Any, ...] | None:
    ws = workspace(robot)
    layout = _FAMILIES[family](rng, ws)
    targets = [layout.target] if layout.start_target is None else [layout.start_target, layout.target]
    if any(np.linalg.norm(t - np.array(ws.shoulder)) > 0.85 * ws.reach for t in targets):
        reasons["target_out_of_reach"] += 1
        return None
    scene = Scene(tuple(layout.obstacles), family)
    checker = CollisionChecker(robot, scene)
    distances = _Distances(checker)
    start = None
    if layout.start_target is not None and layout.start_approach is not None:
        home = np.asarray(robot.home)
        start, why = _reach_into(robot, layout.start_target, layout.start_approach, home, rng, checker, distances)
    else:
        for _ in range(5):
            q = np.clip(robot.home + rng.normal(0.0, START_NOISE, robot.nq), robot.lower, robot.upper)
            q = np.round(q, 6) + 0.0
            if not checker.in_collision(q):
                d_obstacle, d_self = distances(q)
                if d_obstacle >= START_CLEARANCE and d_self >= SELF_CLEARANCE:
                    start = q
                    break
        why = "collision"
    if start is None:
        reasons[f"start_{why}"] += 1
        return None
    goal, why = _reach_into(robot, layout.target, layout.approach, start, rng, checker, distances)
    if goal is None:
        reasons[f"goal_{why}"] += 1
        return None
    return layout, scene, start, goal


def generate_problem(
    robot: Robot | str, family: str, index: int, seed: int = SHIPPED_SEED, max_attempts: int = MAX_ATTEMPTS
) -> Problem:
    """Problem ``index`` (from 1) of ``family`` for ``robot`` with ``seed``: the same arguments
    always give the same problem. Raises :class:`GenerationError` after ``max_attempts`` draws."""
    problem, _ = _generate(robot, family, index, seed, max_attempts)
    return problem


def _generate(
    robot: Robot | str, family: str, index: int, seed: int, max_attempts: int
) -> tuple[Problem, Counter[str]]:
    if isinstance(robot, str):
        robot = load_robot(robot)
    if family not in _FAMILIES:
        raise UnknownNameError("generator family", family, FAMILIES)
    rng = _rng(robot, family, seed, index)
    reasons: Counter[str] = Counter()
    for attempt in range(1, max_attempts + 1):
        found = _attempt(robot, family, rng, reasons)
        if found is None:
            continue
        layout, scene, start, goal = found
        metadata = {
            "set": "gen",
            "family": family,
            "robot": robot.name,
            "index": index,
            "seed": seed,
            "generator": GENERATOR,
            "attempts": attempt,
            "target": list(_round(layout.target)),
            "approach": list(_round(layout.approach, 6)),
            **layout.params,
        }
        pid = problem_id(robot.name, family, index, seed)
        scene = Scene(scene.obstacles, pid)
        problem = Problem.create(robot, scene, start, goal, id=pid, metadata=metadata)
        if not problem.check().ok:
            reasons["check"] += 1
            continue
        if verdict_checker(problem).check_path(np.stack([problem.start, problem.goal.q])).free:  # type: ignore[list-item]
            reasons["straight_line"] += 1
            continue
        return problem, reasons
    raise GenerationError(
        f"no valid {family} problem for robot {robot.name!r} (index {index}, seed {seed}) in {max_attempts} "
        f"attempts; rejected: {dict(reasons)}"
    )


def generate(robot: Robot | str, family: str, n: int, seed: int = SHIPPED_SEED, first: int = 1) -> list[Problem]:
    """Problems ``first`` .. ``first + n - 1`` of ``family`` for ``robot`` (see :func:`generate_problem`)."""
    return [generate_problem(robot, family, i, seed) for i in range(first, first + n)]


# --- the shipped set -----------------------------------------------------------------------------


def _record(problem: Problem) -> dict[str, Any]:
    meta = dict(problem.metadata)
    record = {"id": problem.id.partition(":")[2], "index": meta.pop("index"), "attempts": meta.pop("attempts")}
    for key in ("set", "family", "robot", "seed", "generator"):
        meta.pop(key)
    record.update(
        start=problem.start.tolist(),
        goal=problem.goal.q.tolist(),  # type: ignore[union-attr]
        params=meta,
        obstacles=[o.to_dict() for o in problem.scene.obstacles],
    )
    return record


def family_file(robot: Robot, family: str, n: int, seed: int = SHIPPED_SEED) -> tuple[str, dict[str, Any]]:
    """The text of one ``<robot>_<family>.json`` file and its manifest entry."""
    reasons: Counter[str] = Counter()
    records = []
    for i in range(1, n + 1):
        problem, why = _generate(robot, family, i, seed, MAX_ATTEMPTS)
        reasons.update(why)
        records.append(_record(problem))
    header = {
        "format": GEN_FORMAT,
        "set": "gen",
        "name": f"{robot.name}_{family}",
        "robot": robot.name,
        "family": family,
        "generator": GENERATOR,
        "seed": seed,
        "joint_names": list(robot.joint_names),
        "units": {"length": "m", "angle": "rad"},
        "quaternion_order": "xyzw",
        "workspace": workspace(robot).to_dict(),
    }
    head = json.dumps(header, indent=1)[:-2]  # without the closing "\n}"
    lines = ",\n".join("  " + json.dumps(rec, separators=(",", ":")) for rec in records)
    text = f'{head},\n "problems": [\n{lines}\n ]\n}}\n'
    counts = [len(rec["obstacles"]) for rec in records]
    entry = {
        "file": f"{robot.name}_{family}.json",
        "robot": robot.name,
        "family": family,
        "problems": n,
        "obstacles_per_problem": [min(counts), max(counts)],
        "attempts": sum(rec["attempts"] for rec in records),
        "rejected": dict(sorted(reasons.items())),
        "sha256": hashlib.sha256(text.encode()).hexdigest(),
    }
    return text, entry


def write_set(
    out: Path,
    robots: Sequence[str] = SHIPPED_ROBOTS,
    families: Sequence[str] = FAMILIES,
    n: int = SHIPPED_COUNT,
    seed: int = SHIPPED_SEED,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Generate ``n`` problems per robot and family into ``out`` (one file each, plus manifest.json)."""
    out.mkdir(parents=True, exist_ok=True)
    sets = {}
    for name in robots:
        robot = load_robot(name)
        for family in families:
            t0 = time.perf_counter()
            text, entry = family_file(robot, family, n, seed)
            (out / entry["file"]).write_text(text)
            sets[f"{name}_{family}"] = entry
            log(f"{entry['file']}: {n} problems, {entry['attempts']} draws, {time.perf_counter() - t0:.1f} s")
    manifest = {
        "format": MANIFEST_FORMAT,
        "generator": GENERATOR,
        "seed": seed,
        "command": COMMAND,
        "sets": sets,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


def write_problem_files(
    out: Path,
    robots: Sequence[str],
    families: Sequence[str] = FAMILIES,
    n: int = SHIPPED_COUNT,
    seed: int = SHIPPED_SEED,
    log: Callable[[str], None] = print,
) -> list[Path]:
    """Generate ``n`` problems per robot (a shipped name or a settings .toml) and family into
    ``out``, one planbench problem file each (``<robot>_<family>_<index>.json``, the robot named as
    :meth:`Problem.save` names it: a settings file by its path relative to ``out``)."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in robots:
        robot = load_robot(name)
        for family in families:
            t0 = time.perf_counter()
            for problem in generate(robot, family, n, seed):
                path = out / f"{robot.name}_{family}_{problem.metadata['index']:04d}.json"
                problem.save(path)
                written.append(path)
            log(f"{robot.name}_{family}: {n} problem files, {time.perf_counter() - t0:.1f} s")
    return written


# --- solvability --------------------------------------------------------------------------------


def solvability(problems: Sequence[Problem], time_limit: float = 5.0, log: Callable[[str], None] = print) -> dict:
    """Per problem: does OMPL RRT-Connect (seed 0, ``time_limit`` [s]) and the straight line solve it
    (``planbench.plan`` + ``planbench.evaluate``)? Timing-dependent, so kept apart from the set."""
    rows: dict[str, dict[str, Any]] = {}
    for p in problems:
        row: dict[str, Any] = {}
        for planner in ("ompl-rrtconnect", "straight-line"):
            result = plan(p, planner, seed=0, time_limit=time_limit)
            ev = evaluate(p, result)
            row[planner] = bool(ev.success)
            if planner == "ompl-rrtconnect":
                row["rrtconnect_time"] = round(float(result.planning_time), 3)
        rows[p.id] = row
        log(f"{p.id}: {row}")
    return rows


def _summary(rows: dict[str, dict[str, Any]]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for pid, row in rows.items():
        name = pid.partition(":")[2].partition("/")[0]
        s = out.setdefault(name, {"problems": 0, "ompl-rrtconnect": 0, "straight-line": 0})
        s["problems"] += 1
        s["ompl-rrtconnect"] += row["ompl-rrtconnect"]
        s["straight-line"] += row["straight-line"]
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m planbench.problems.generate",
        description="Generate planbench's own problem sets (shelf, window, pillars, table_clutter).",
    )
    ap.add_argument("--out", type=Path, required=True, help="output folder (the shipped set: planbench/data/gen)")
    ap.add_argument("--robots", default=",".join(SHIPPED_ROBOTS), help="robot names, comma-separated")
    ap.add_argument("--families", default=",".join(FAMILIES), help="families, comma-separated")
    ap.add_argument("-n", type=int, default=SHIPPED_COUNT, help="problems per robot and family")
    ap.add_argument("--seed", type=int, default=SHIPPED_SEED)
    ap.add_argument(
        "--problem-files",
        action="store_true",
        help="write each problem as a planbench problem file, <out>/<robot>_<family>_<index>.json, which "
        "`planbench plan --problem <out>` and `planbench bench --problems <out>` read; needed for a robot given "
        "as a settings .toml (one that planbench does not ship)",
    )
    ap.add_argument(
        "--solvability",
        type=float,
        metavar="SECONDS",
        help="instead of generating: plan every problem in --out with RRT-Connect (this time limit) and "
        "the straight line, write solvability.json there and print a table",
    )
    args = ap.parse_args(argv)
    try:
        return _main(args)
    except PlanbenchError as exc:
        print(f"python -m planbench.problems.generate: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("python -m planbench.problems.generate: interrupted", file=sys.stderr)
        return 130


def _main(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.out.is_dir():
        raise InvalidConfigError(f"--out {args.out} is not a folder")
    if args.solvability is not None:
        if not (math.isfinite(args.solvability) and args.solvability > 0):
            raise InvalidConfigError(f"--solvability must be a finite number of seconds > 0, got {args.solvability}")
        manifest = _read_json(args.out / "manifest.json", "its generated set's manifest")
        if not isinstance(manifest, dict) or not isinstance(manifest.get("sets"), dict):
            raise PlanbenchError(f"{args.out / 'manifest.json'}: not a planbench generated-set manifest")
        rows: dict[str, dict[str, Any]] = {}
        for name in manifest["sets"]:
            data = _read_json(args.out / f"{name}.json", "a generated set")
            problems = [problem_from_record(rec, data) for rec in data["problems"]]
            rows.update(solvability(problems, args.solvability))
        summary = _summary(rows)
        report = {"time_limit": args.solvability, "summary": summary, "problems": rows}
        (args.out / "solvability.json").write_text(json.dumps(report, indent=1) + "\n")
        print(f"{'set':<22} {'problems':>8} {'rrt-connect':>11} {'straight line':>13}")
        for name, s in summary.items():
            print(f"{name:<22} {s['problems']:>8} {s['ompl-rrtconnect']:>11} {s['straight-line']:>13}")
        return 0
    families = args.families.split(",")
    for family in families:
        if family not in _FAMILIES:
            raise UnknownNameError("generator family", family, FAMILIES)
    if args.n < 1:
        raise InvalidConfigError(f"-n must be >= 1 (problems per robot and family), got {args.n}")
    if not 0 <= args.seed < 2**63:
        raise InvalidConfigError(f"--seed must be an integer with 0 <= seed < 2**63, got {args.seed}")
    robots = args.robots.split(",")
    for name in robots:
        load_robot(name)  # an unknown robot before any generating
        if name.endswith(".toml") and not args.problem_files:
            raise InvalidConfigError(
                f"--robots {name}: a robot planbench does not ship needs --problem-files (the set's files name "
                "their robot by its shipped name)"
            )
    if args.problem_files:
        write_problem_files(args.out, robots, families, args.n, args.seed)
    else:
        write_set(args.out, robots, families, args.n, args.seed)
    return 0


def _read_json(path: Path, what: str) -> Any:
    from planbench.files.inputs import InputFileError, read_json

    try:
        return read_json(path)
    except InputFileError as exc:
        raise PlanbenchError(f"{exc} ({what}; generate one with --out first)") from None
