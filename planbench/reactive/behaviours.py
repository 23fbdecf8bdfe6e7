"""The moving obstacles of the generated ``dynamic`` set, one draw per behaviour.

Every draw is placed relative to the end effector's straight path from start to goal
(:class:`PathFrame`) and takes its numbers from one seeded ``numpy`` generator, in a fixed order,
so a draw is reproducible from its seed alone. The behaviours and their parameter ranges are
listed in :mod:`planbench.reactive.generator`; this module only builds them. Lengths are rounded to
0.1 mm (:func:`p`, :func:`r`) so float round-off elsewhere cannot change a generated file.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from planbench.reactive.motion import Motion
from planbench.reactive.scenario import MovingObstacle
from planbench.scene import Obstacle

__all__ = ["BEHAVIOURS", "PathFrame", "draw", "p", "r"]

BEHAVIOURS = ("crossing", "swinging", "sliding", "blocking", "appearing", "pair", "reaching", "occluded")
"""In the order of their seeds: a behaviour's index is part of its generator's seed, so new ones
are appended (the first three are the 108-scenario set's, drawn as they were)."""

_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class PathFrame:
    """Where a behaviour is placed [m]: the end effector's start ``ps`` and goal ``pg`` positions,
    the unit direction ``u`` between them, its horizontal normal ``w = u x z``, the goal's approach
    axis ``approach`` (the end-effector frame's z at the goal: the hand moves along it into the
    goal), the depth camera's optical centre ``camera``, and the horizon [s]."""

    ps: np.ndarray
    pg: np.ndarray
    u: np.ndarray
    w: np.ndarray
    approach: np.ndarray
    camera: np.ndarray
    horizon: float

    @property
    def m(self) -> np.ndarray:
        """The path's midpoint [m]."""
        return 0.5 * (self.ps + self.pg)

    def along(self, fraction: float) -> np.ndarray:
        return self.ps + (self.pg - self.ps) * fraction


def draw(behaviour: str, speed: float, f: PathFrame, rng: np.random.Generator) -> tuple[MovingObstacle, ...]:
    """The obstacles of one ``behaviour`` whose fastest point peaks at ``speed`` [m/s]."""
    if behaviour == "crossing":
        return (_crossing(speed, f, rng),)
    if behaviour == "swinging":
        return (_swinging(speed, f, rng),)
    if behaviour == "sliding":
        return (_sliding(speed, f, rng),)
    if behaviour == "blocking":
        return (_blocking(speed, f, rng),)
    if behaviour == "appearing":
        return (_appearing(speed, f, rng),)
    if behaviour == "pair":
        return _pair(speed, f, rng)
    if behaviour == "reaching":
        return (_reaching(speed, f, rng),)
    if behaviour == "occluded":
        return _occluded(speed, f, rng)
    raise ValueError(f"unknown behaviour {behaviour!r}; use one of {BEHAVIOURS}")


# --- the 108-scenario set's behaviours (their draws unchanged) -----------------------------------


def _crossing(
    speed: float, f: PathFrame, rng: np.random.Generator, side: float | None = None, t_pass: float | None = None
) -> MovingObstacle:
    """A ball or box flying across the path; ``side`` and ``t_pass`` given (a pair's second
    obstacle) are used instead of drawn."""
    centre = f.along(rng.uniform(0.3, 0.7)) + rng.uniform(-0.03, 0.03, 3)
    turn = rng.uniform(-math.pi / 4, math.pi / 4)  # the flight's heading, off the path's normal
    w = math.cos(turn) * f.w + math.sin(turn) * np.cross(_Z, f.w)
    drawn_side = rng.choice([-1.0, 1.0])
    drawn_pass = rng.uniform(1.0, 2.5)  # when it passes the centre [s]
    side = float(drawn_side) if side is None else side
    t_pass = float(drawn_pass) if t_pass is None else t_pass
    start = centre - side * w * speed * t_pass
    if rng.random() < 0.5:
        shape = Obstacle("crossing_ball", "sphere", p(start), radius=r(rng.uniform(0.05, 0.08)))
    else:
        shape = Obstacle("crossing_box", "box", p(start), size=p(rng.uniform(0.08, 0.14, 3)))
    gone = r(t_pass + 1.0 / speed)  # 1 m past the centre: out of the way
    return MovingObstacle(shape, Motion("velocity", velocity=p(side * w * speed)), disappear=gone)


def _swinging(speed: float, f: PathFrame, rng: np.random.Generator) -> MovingObstacle:
    radius, length = rng.uniform(0.04, 0.06), rng.uniform(0.25, 0.35)
    pivot = f.m + _Z * rng.uniform(0.30, 0.40) + f.w * rng.normal(0.0, 0.03)
    centre = pivot - _Z * (0.5 * length + 0.02)  # hanging, its top 2 cm below the pivot
    amplitude = rng.uniform(0.7, 1.0)
    tip = length + 0.02 + radius  # pivot to the far tip [m]
    motion = Motion(
        "swing",
        pivot=p(pivot),
        axis=p(f.u),
        amplitude=r(amplitude),
        frequency=speed / (2 * math.pi * amplitude * tip),
        phase=r(rng.uniform(0, 2 * math.pi)),
    )
    forearm = Obstacle("forearm", "capsule", p(centre), radius=r(radius), length=r(length))
    return MovingObstacle(forearm, motion, disappear=0.5 * f.horizon)  # the person withdraws


def _sliding(speed: float, f: PathFrame, rng: np.random.Generator) -> MovingObstacle:
    size = rng.uniform([0.08, 0.08, 0.06], [0.14, 0.14, 0.10])
    low, high = (f.ps, f.pg) if f.ps[2] <= f.pg[2] else (f.pg, f.ps)
    centre = low + (high - low) * rng.uniform(0.30, 0.50)
    centre[2] = low[2] - 0.5 * size[2] - rng.uniform(0.12, 0.18)  # top below the hand at the path's low end
    amplitude = rng.uniform(0.20, 0.30)
    motion = Motion(
        "sinusoid",
        amplitude=p(f.w * amplitude),
        frequency=speed / (2 * math.pi * amplitude),
        phase=r(rng.uniform(0, 2 * math.pi)),
    )
    return MovingObstacle(Obstacle("sliding_box", "box", p(centre), size=p(size)), motion)


# --- the behaviours added with the third robot ---------------------------------------------------


def _blocking(speed: float, f: PathFrame, rng: np.random.Generator) -> MovingObstacle:
    """Arrives at the goal down its approach corridor, parks there, leaves the way it came."""
    back = _tilted(-f.approach, rng.uniform(0.0, 0.35), rng.uniform(0, 2 * math.pi))  # where it comes from
    park = f.pg + back * rng.uniform(0.0, 0.03)  # on the goal, or just over it
    if rng.random() < 0.5:
        shape = Obstacle("blocking_ball", "sphere", p(park), radius=r(rng.uniform(0.06, 0.09)))
    else:
        shape = Obstacle("blocking_box", "box", p(park), size=p(rng.uniform(0.10, 0.16, 3)))
    distance = rng.uniform(0.30, 0.50)  # its way in [m]
    travel = distance / speed
    arrive = max(travel, rng.uniform(0.8, 1.5))  # [s]: before a fast arm gets there
    leave = arrive + rng.uniform(2.0, 5.0)
    away = p(back * distance)
    motion = Motion(
        "waypoints",
        times=(r(arrive - travel), r(arrive), r(leave), r(leave + travel)),
        offsets=(away, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), away),
    )
    return MovingObstacle(shape, motion, disappear=r(leave + travel))


def _appearing(speed: float, f: PathFrame, rng: np.random.Generator) -> MovingObstacle:
    """Appears beside the path, drifts a short way along it, stays."""
    side = float(rng.choice([-1.0, 1.0]))
    lift = rng.uniform(-0.5, 0.5)  # the offset's direction: w tilted up or down [rad]
    out = math.cos(lift) * side * f.w + math.sin(lift) * _Z
    if rng.random() < 0.5:
        half = rng.uniform(0.05, 0.08)
        shape = Obstacle("appearing_ball", "sphere", (0.0, 0.0, 0.0), radius=r(half))
    else:
        size = rng.uniform(0.08, 0.14, 3)
        half = 0.5 * float(np.max(size))
        shape = Obstacle("appearing_box", "box", (0.0, 0.0, 0.0), size=p(size))
    centre = f.along(rng.uniform(0.3, 0.7)) + out * (half + rng.uniform(0.10, 0.20))
    appear = rng.uniform(0.5, 2.0)  # [s]
    drift = rng.uniform(0.10, 0.25) * rng.choice([-1.0, 1.0])  # along the path [m]
    velocity = p(f.u * speed * np.sign(drift))
    motion = Motion("velocity", velocity=velocity, start=r(appear), stop=r(appear + abs(drift) / speed))
    return MovingObstacle(dataclasses.replace(shape, position=p(centre)), motion, appear=r(appear))


def _pair(speed: float, f: PathFrame, rng: np.random.Generator) -> tuple[MovingObstacle, ...]:
    """A crossing obstacle and a sliding one, or two crossing from both sides, the second later."""
    first = _crossing(speed, f, rng)
    if rng.random() < 0.5:
        return first, _sliding(speed, f, rng)
    first_side = float(np.sign(np.dot(first.motion.velocity, f.w))) or 1.0  # the way the first flies
    side = -first_side  # the second comes from the other side
    t_pass = rng.uniform(1.5, 3.5)  # the second passes its centre 0-2.5 s after the first at the earliest
    second = _crossing(speed, f, rng, side=side, t_pass=t_pass)
    renamed = dataclasses.replace(second.obstacle, name=second.obstacle.name + "_2")
    return first, dataclasses.replace(second, obstacle=renamed)


def _reaching(speed: float, f: PathFrame, rng: np.random.Generator) -> MovingObstacle:
    """A forearm reaching in from one side until its fingertips are near the path, then withdrawing."""
    radius, length = rng.uniform(0.04, 0.06), rng.uniform(0.25, 0.35)
    side = float(rng.choice([-1.0, 1.0]))
    turn = rng.uniform(-0.5, 0.5)  # heading off -w [rad]
    down = rng.uniform(-0.2, 0.5)  # reaching down (positive) or slightly up [rad]
    heading = math.cos(turn) * -side * f.w + math.sin(turn) * f.u
    direction = math.cos(down) * heading - math.sin(down) * _Z  # of the reach, elbow to fingertips
    tip = f.along(rng.uniform(0.3, 0.7)) - direction * rng.uniform(0.0, 0.08)  # stops 0-8 cm short
    centre = tip - direction * (0.5 * length + radius)
    distance = rng.uniform(0.35, 0.50)  # of the reach [m]
    start = rng.uniform(0.5, 2.0)  # [s]
    travel = distance / speed
    hold = rng.uniform(0.5, 1.5)
    away = p(-direction * distance)
    times = (r(start), r(start + travel), r(start + travel + hold), r(start + 2 * travel + hold))
    motion = Motion("waypoints", times=times, offsets=(away, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), away))
    quat = pin.Quaternion.FromTwoVectors(_Z, direction)  # the capsule's axis (local z) along the reach
    xyzw = _unit((quat.x, quat.y, quat.z, quat.w))
    forearm = Obstacle("reaching_forearm", "capsule", p(centre), xyzw, radius=r(radius), length=r(length))
    return MovingObstacle(forearm, motion, disappear=times[-1])  # the person steps back


def _occluded(speed: float, f: PathFrame, rng: np.random.Generator) -> tuple[MovingObstacle, ...]:
    """A static box beside the path and a board passing to and fro between it and the camera."""
    size = rng.uniform([0.08, 0.08, 0.10], [0.14, 0.14, 0.25])
    side = float(rng.choice([-1.0, 1.0]))
    hidden = f.along(rng.uniform(0.3, 0.7)) + side * f.w * (0.5 * size[1] + rng.uniform(0.03, 0.08))
    static = MovingObstacle(Obstacle("hidden_box", "box", p(hidden), size=p(size)))
    ray = f.camera - hidden
    at = hidden + ray * rng.uniform(0.45, 0.65)  # the board's centre on the camera's line of sight
    across = np.cross(ray, _Z)
    across /= np.linalg.norm(across)  # horizontal, across the line of sight
    board = rng.uniform([0.03, 0.25, 0.25], [0.05, 0.35, 0.40])  # thick, wide, tall [m]
    amplitude = rng.uniform(0.25, 0.40)
    yaw = math.atan2(ray[1], ray[0])  # the board faces the camera: its local x along the ray
    xyzw = _unit((0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)))
    motion = Motion(
        "sinusoid",
        amplitude=p(across * amplitude),
        frequency=speed / (2 * math.pi * amplitude),
        phase=r(rng.choice([0.0, math.pi])),  # on the line of sight at t = 0, moving off it
    )
    return static, MovingObstacle(Obstacle("occluding_board", "box", p(at), xyzw, size=p(board)), motion)


def _tilted(axis: np.ndarray, angle: float, spin: float) -> np.ndarray:
    """``axis`` (unit) turned by ``angle`` [rad] towards a direction at ``spin`` [rad] about it."""
    a = axis / np.linalg.norm(axis)
    e1 = np.cross(a, _Z if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0]))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return math.cos(angle) * a + math.sin(angle) * (math.cos(spin) * e1 + math.sin(spin) * e2)  # type: ignore[no-any-return]


def _unit(q: Sequence[float]) -> tuple[float, float, float, float]:
    """A quaternion rounded to 1e-6, renormalised."""
    v = np.round(np.asarray(q, dtype=float), 6)
    v = v / np.linalg.norm(v)
    return tuple(round(float(x), 8) for x in v)  # type: ignore[return-value]


def p(v: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """Rounded to 0.1 mm, so float round-off elsewhere does not change a generated file."""
    return tuple(round(float(x), 4) for x in v)  # type: ignore[return-value]


def r(x: float) -> float:
    return round(float(x), 4)
