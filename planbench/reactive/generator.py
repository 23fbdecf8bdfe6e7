"""Seeded generator of dynamic scenarios: static problems with obstacles that move through them.

Each scenario takes a static problem (its robot, scene, start and goal) and adds one moving
obstacle whose motion is placed relative to the end effector's straight path from start to goal
(midpoint ``m``, direction ``u``, horizontal normal ``w = u x z``):

- ``crossing``: a ball (radius 5-8 cm) or box (8-14 cm edges) flies horizontally across the path
  (heading within ± 45° of ``w``) through a point 30-70 % along it (± 3 cm), passing it 1.0-2.5 s
  after the start; it disappears 1 m past it.
- ``swinging``: a capsule like a person's forearm (radius 4-6 cm, 25-35 cm long) hangs from a
  pivot 30-40 cm above ``m`` and swings across the path about ``u``, ± 0.7-1.0 rad, for the
  first half of the horizon (then the person withdraws).
- ``sliding``: a box (8-14 × 8-14 × 6-10 cm) slides back and forth along ``w`` (± 20-30 cm),
  its top 12-18 cm below the lower end of the path (a hand's length), 30-50 % of the way along it.

Every behaviour comes at three speeds, the peak speed of the obstacle's fastest point: ``slow``
0.2 m/s, ``medium`` 0.5 m/s, ``fast`` 1.0 m/s, and with two sensing models: ``truth`` (exact
geometry, 30 Hz, no latency) and ``depth`` (one 160 × 120 camera 1.3 m in front of ``m`` and 0.6 m
above it, 30 Hz, 30 ms latency, 5 mm range noise, 5 % dropout). The obstacle's shape and placement
are drawn once per (problem, behaviour), so the speeds and sensing models of one problem and
behaviour are paired: they differ in nothing else.

A draw is kept only if the moving obstacle never comes within 5 cm (checked every 0.1 s) of the
links only the first joint moves (the base and link 1: the arm cannot move them out of its way), the arm at its start
is at least 5 cm from it during the first 0.5 s, and the arm at the goal configuration is at least
2 cm from it at every sampled time (every 50 ms) of the horizon's second half (the goal can be
reached and held), at every speed; otherwise it is drawn again (at most 100 times). Draws come
from ``numpy.random.default_rng([seed, crc32(problem ref), behaviour index, k])`` alone, so a
scenario does not depend on which others are generated.

The shipped set (``planbench/data/scenarios/dynamic.json``, 6 problems x 18 = 108 scenarios,
horizon 20 s at 100 Hz; :data:`BASE_PROBLEMS`) is
written by ``python -m planbench.reactive.generator`` (seed 0); lengths are rounded to 0.1 mm so
float round-off elsewhere cannot change it.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from planbench.errors import PlanbenchError
from planbench.problem import Problem
from planbench.problems.datasets import load_problem
from planbench.reactive.checker import TickChecker
from planbench.reactive.motion import Motion
from planbench.reactive.scenario import CameraSettings, MovingObstacle, Scenario, SensingSettings
from planbench.scene import Obstacle, Scene

__all__ = ["BEHAVIOURS", "GENERATOR_VERSION", "SENSING", "SPEEDS", "dynamic_scenarios", "scenario"]

GENERATOR_VERSION = 1
SET_FORMAT = "planbench-scenario-set/1"
BEHAVIOURS = ("crossing", "swinging", "sliding")
SPEEDS = {"slow": 0.2, "medium": 0.5, "fast": 1.0}
"""Peak speed [m/s] of the moving obstacle's fastest point."""
SENSING = ("truth", "depth")
HORIZON = 20.0  # [s]
CONTROL_RATE = 100.0  # [Hz]

BASE_PROBLEMS = (
    "mbm:box/0001",
    "mbm:bookshelf_tall/0001",
    "gen:panda_table_clutter/0003:bare",
    "gen:ur5_table_clutter/0002:bare",
    "gen:ur5_table_clutter/0003:bare",
    "gen:ur5_table_clutter/0004:bare",
)
"""The static problems of the ``dynamic`` set, three per robot. ``:bare``: the problem with its
table's clutter removed (obstacles named ``object*``: the table, its legs and the floor stay), so
that a box sliding on the table is the challenge. Chosen as problems whose static scene a field
controller solves in closed loop (truth sensing, no compute charged; docs/reactive.md), so that a
failure in a dynamic scenario is the moving obstacle's doing; the MotionBenchMaker ones from the
tuning range (0001-0020)."""


def base_problem(ref: str) -> Problem:
    """The problem ``ref`` names, ``":bare"`` removing the obstacles named ``object*``."""
    name, _, bare = ref.partition(":bare")
    problem = load_problem(name)
    if ref.endswith(":bare"):
        kept = tuple(o for o in problem.scene.obstacles if not o.name.startswith("object"))
        problem = dataclasses.replace(problem, scene=Scene(kept, problem.scene.name + "-bare"))
    return problem


def dynamic_scenarios(refs: Sequence[str] = BASE_PROBLEMS, seed: int = 0) -> list[Scenario]:
    """Every behaviour x speed x sensing model on each problem of ``refs``: 18 per problem."""
    out = []
    for i, ref in enumerate(refs, start=1):
        problem = base_problem(ref)
        for behaviour in BEHAVIOURS:
            for speed in SPEEDS:
                for sensing in SENSING:
                    out.append(scenario(problem, ref, behaviour, speed, sensing, seed, index=i))
    return out


def scenario(
    problem: Problem, ref: str, behaviour: str, speed: str, sensing: str, seed: int = 0, index: int = 1
) -> Scenario:
    """One scenario (module docstring); raises :class:`PlanbenchError` when no valid draw is found."""
    if behaviour not in BEHAVIOURS or speed not in SPEEDS or sensing not in SENSING:
        raise ValueError(f"behaviour, speed, sensing must be in {BEHAVIOURS}, {tuple(SPEEDS)}, {SENSING}")
    robot = problem.robot.name
    name = f"dynamic:{robot}_{behaviour}_{speed}_{sensing}/{index:04d}"
    ps, pg, u, w = _path_frame(problem)
    sense = _sensing(sensing, 0.5 * (ps + pg))
    k = _paired_draw(problem, ref, behaviour, seed)
    moving = _draw(behaviour, SPEEDS[speed], ps, pg, u, w, _rng(seed, ref, behaviour, k))
    metadata = {
        "set": "dynamic",
        "family": f"{robot}_{behaviour}",
        "robot": robot,
        "behaviour": behaviour,
        "speed": speed,
        "sensing": sensing,
        "base": ref,
        "draw": k,
        "generator": GENERATOR_VERSION,
    }
    # a problem changed from its reference (":bare") is written out whole
    return Scenario(
        problem, (moving,), sense, CONTROL_RATE, HORIZON, name, metadata, None if ref.endswith(":bare") else ref
    )


def _rng(seed: int, ref: str, behaviour: str, k: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(ref.encode()), BEHAVIOURS.index(behaviour), k])


@functools.lru_cache(maxsize=64)
def _paired_draw(problem: Problem, ref: str, behaviour: str, seed: int) -> int:
    """The first draw valid at every speed (so the speeds of a problem and behaviour differ in
    nothing else)."""
    ps, pg, u, w = _path_frame(problem)
    for k in range(100):
        if all(
            _valid(
                Scenario(problem, (_draw(behaviour, v, ps, pg, u, w, _rng(seed, ref, behaviour, k)),), horizon=HORIZON)
            )
            for v in SPEEDS.values()
        ):
            return k
    raise PlanbenchError(f"{ref}: no draw of a {behaviour} obstacle valid at every speed in 100 tries")


def _path_frame(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The end effector's start and goal positions [m], the unit direction between them and its
    horizontal normal."""
    ps = problem.robot.frame_pose(problem.start, problem.goal.pose.frame).translation.copy()
    pg = np.asarray(problem.goal.pose.position, dtype=float)
    d = pg - ps
    u = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-6 else np.array([1.0, 0.0, 0.0])
    w = np.cross(u, [0.0, 0.0, 1.0])
    w = w / np.linalg.norm(w) if np.linalg.norm(w) > 1e-6 else np.array([0.0, 1.0, 0.0])
    return ps, pg, u, w


def _draw(
    behaviour: str, speed: float, ps: np.ndarray, pg: np.ndarray, u: np.ndarray, w: np.ndarray, rng: np.random.Generator
) -> MovingObstacle:
    """One moving obstacle of ``behaviour`` whose fastest point peaks at ``speed`` [m/s]."""
    z = np.array([0.0, 0.0, 1.0])
    m = 0.5 * (ps + pg)
    if behaviour == "crossing":
        centre = ps + (pg - ps) * rng.uniform(0.3, 0.7) + rng.uniform(-0.03, 0.03, 3)
        turn = rng.uniform(-math.pi / 4, math.pi / 4)  # the flight's heading, off the path's normal
        w = math.cos(turn) * w + math.sin(turn) * np.cross(z, w)
        side = rng.choice([-1.0, 1.0])
        t_pass = rng.uniform(1.0, 2.5)  # when it passes the centre [s]
        start = centre - side * w * speed * t_pass
        if rng.random() < 0.5:
            shape = Obstacle("crossing_ball", "sphere", _p(start), radius=_r(rng.uniform(0.05, 0.08)))
        else:
            shape = Obstacle("crossing_box", "box", _p(start), size=_p(rng.uniform(0.08, 0.14, 3)))
        gone = _r(t_pass + 1.0 / speed)  # 1 m past the centre: out of the way
        return MovingObstacle(shape, Motion("velocity", velocity=_p(side * w * speed)), disappear=gone)
    if behaviour == "swinging":
        radius, length = rng.uniform(0.04, 0.06), rng.uniform(0.25, 0.35)
        pivot = m + z * rng.uniform(0.30, 0.40) + w * rng.normal(0.0, 0.03)
        centre = pivot - z * (0.5 * length + 0.02)  # hanging, its top 2 cm below the pivot
        amplitude = rng.uniform(0.7, 1.0)
        tip = length + 0.02 + radius  # pivot to the far tip [m]
        motion = Motion(
            "swing",
            pivot=_p(pivot),
            axis=_p(u),
            amplitude=_r(amplitude),
            frequency=speed / (2 * math.pi * amplitude * tip),
            phase=_r(rng.uniform(0, 2 * math.pi)),
        )
        forearm = Obstacle("forearm", "capsule", _p(centre), radius=_r(radius), length=_r(length))
        return MovingObstacle(forearm, motion, disappear=0.5 * HORIZON)  # the person withdraws
    size = rng.uniform([0.08, 0.08, 0.06], [0.14, 0.14, 0.10])
    low, high = (ps, pg) if ps[2] <= pg[2] else (pg, ps)
    centre = low + (high - low) * rng.uniform(0.30, 0.50)
    centre[2] = low[2] - 0.5 * size[2] - rng.uniform(0.12, 0.18)  # top below the hand at the path's low end
    amplitude = rng.uniform(0.20, 0.30)
    motion = Motion(
        "sinusoid",
        amplitude=_p(w * amplitude),
        frequency=speed / (2 * math.pi * amplitude),
        phase=_r(rng.uniform(0, 2 * math.pi)),
    )
    return MovingObstacle(Obstacle("sliding_box", "box", _p(centre), size=_p(size)), motion)


def _sensing(model: str, m: np.ndarray) -> SensingSettings:
    if model == "truth":
        return SensingSettings("truth", rate=30.0)
    out = np.array([m[0], m[1], 0.0])
    out = out / np.linalg.norm(out) if np.linalg.norm(out) > 1e-6 else np.array([1.0, 0.0, 0.0])
    camera = CameraSettings(position=_p(m + 1.3 * out + [0.0, 0.0, 0.6]), look_at=_p(m), noise_std=0.005, dropout=0.05)
    return SensingSettings("depth", rate=30.0, latency=0.03, cameras=(camera,))


def _valid(s: Scenario) -> bool:
    """The start is 5 cm clear of the moving obstacle for 0.5 s, the goal 2 cm clear over the
    second half of the horizon."""
    alone = Scenario(dataclasses.replace(s.problem, scene=Scene()), s.moving)  # the moving obstacle only
    checker = TickChecker(alone)
    start = np.asarray(s.problem.start)
    if min(checker.clearance(start, t) for t in np.arange(0.0, 0.5, 0.05)) < 0.05:
        return False
    if min(_base_clearance(checker, start, t) for t in np.arange(0.0, s.horizon, 0.1)) < 0.05:
        return False
    goal = s.problem.goal.q
    if goal is None:
        return True
    times = np.arange(0.5 * s.horizon, s.horizon, 0.05)
    return min(checker.clearance(np.asarray(goal), t) for t in times) >= 0.02


def _base_clearance(checker: TickChecker, q: np.ndarray, t: float) -> float:
    """Distance [m] at time ``t`` from the moving obstacle to the links no joint but the first
    moves (the base and the first link: the arm cannot take them out of the way)."""
    c = checker.checker
    checker.place(t)
    gm = c.geometry_model
    n = c.n_robot_geoms
    base = {i for i in range(n) if gm.geometryObjects[i].parentJoint <= 1}
    pairs = [k for k, (a, b) in enumerate(c.pairs) if (a in base or b in base) and max(a, b) >= n]
    data, gdata = c.robot.model.createData(), pin.GeometryData(gm)
    pin.computeDistances(c.robot.model, data, gm, gdata, q)
    return min((gdata.distanceResults[k].min_distance for k in pairs), default=np.inf)


def _p(v: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """Rounded to 0.1 mm, so float round-off elsewhere does not change a generated file."""
    return tuple(round(float(x), 4) for x in v)  # type: ignore[return-value]


def _r(x: float) -> float:
    return round(float(x), 4)


SMOKE = (
    "dynamic:panda_crossing_medium_truth/0001",
    "dynamic:panda_swinging_medium_depth/0003",
    "dynamic:ur5_sliding_medium_truth/0004",
    "dynamic:ur5_crossing_medium_depth/0005",
)
"""The ``dynamic-smoke`` set: both robots, three behaviours, both sensing models, medium speed."""


def write_set(out: str | Path, seed: int = 0) -> Path:
    """Write the ``dynamic`` set as one JSON file in folder ``out`` (``dynamic.json``)."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    data = {
        "format": SET_FORMAT,
        "name": "dynamic",
        "generator": GENERATOR_VERSION,
        "seed": seed,
        "base_problems": list(BASE_PROBLEMS),
        "smoke": list(SMOKE),
        "scenarios": [s.to_dict() for s in dynamic_scenarios(BASE_PROBLEMS, seed)],
    }
    path = folder / "dynamic.json"
    path.write_text(json.dumps(data, indent=1) + "\n")
    return path


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="write planbench's dynamic scenario set")
    parser.add_argument("--out", default="planbench/data/scenarios", help="folder (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    print(write_set(parser.parse_args().out, parser.parse_args().seed))
