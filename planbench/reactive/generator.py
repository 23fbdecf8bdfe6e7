"""Seeded generator of dynamic scenarios: static problems with obstacles that move through them.

Each scenario takes a static problem (its robot, scene, start and goal) and adds moving obstacles
placed relative to the end effector's straight path from start to goal (midpoint ``m``, direction
``u``, horizontal normal ``w = u x z``; :mod:`planbench.reactive.behaviours` builds them):

- ``crossing``: a ball (radius 5-8 cm) or box (8-14 cm edges) flies horizontally across the path
  (heading within ± 45° of ``w``) through a point 30-70 % along it (± 3 cm), passing it 1.0-2.5 s
  after the start; it disappears 1 m past it.
- ``swinging``: a capsule like a person's forearm (radius 4-6 cm, 25-35 cm long) hangs from a
  pivot 30-40 cm above ``m`` and swings across the path about ``u``, ± 0.7-1.0 rad, for the
  first half of the horizon (then the person withdraws).
- ``sliding``: a box (8-14 × 8-14 × 6-10 cm) slides back and forth along ``w`` (± 20-30 cm),
  its top 12-18 cm below the lower end of the path (a hand's length), 30-50 % of the way along it.
- ``blocking``: a ball (radius 6-9 cm) or box (10-16 cm edges) comes 30-50 cm down the goal's
  approach corridor (the reverse of the end effector's z axis at the goal, tilted up to 0.35 rad),
  arrives at 0.8-1.5 s (later when the way in takes longer at its speed), parks on the goal point
  or up to 3 cm over it for 2-5 s, so the goal configuration is in collision, then leaves the way it
  came and disappears: the goal is blocked for a while.
- ``appearing``: a ball (radius 5-8 cm) or box (8-14 cm edges) appears suddenly, 0.5-2.0 s after
  the start, beside the path (30-70 % along it, its surface 10-20 cm from it, to either side along
  ``w`` tilted up or down by up to 0.5 rad), drifts 10-25 cm along ``u`` and stays.
- ``pair``: two obstacles at once: a crossing one and a sliding one (half the draws), or two
  crossing ones from opposite sides, the second passing its own point 1.5-3.5 s after the start.
- ``reaching``: a person's forearm (capsule, radius 4-6 cm, 25-35 cm long) reaches in from one side
  (heading within ± 0.5 rad of ``∓w``, 0.2 rad up to 0.5 rad down) 35-50 cm along its axis, from
  0.5-2.0 s, until its fingertips are 0-8 cm short of a point 30-70 % along the path, holds there
  0.5-1.5 s, withdraws the way it came and disappears.
- ``occluded``: a static box (8-14 × 8-14 × 10-25 cm) beside the path (30-70 % along it, its side
  3-8 cm from it) and a board (3-5 cm thick, 25-35 cm wide, 25-40 cm tall) facing the depth
  camera, 45-65 % of the way from the box to the camera on its line of sight, that moves to and
  fro across that line (± 25-40 cm): on it at the start, the box is hidden from the camera until
  the board moves off, and again whenever it passes.

Every behaviour comes at three speeds, the peak speed of the obstacles' fastest point: ``slow``
0.2 m/s, ``medium`` 0.5 m/s, ``fast`` 1.0 m/s, and with two sensing models: ``truth`` (exact
geometry, 30 Hz, no latency) and ``depth`` (two 160 × 120 cameras, 30 Hz, 30 ms latency, 5 mm
range noise, 5 % dropout, fused in the map with its defaults: one facing the arm from 1.3 m beyond
``m``, away from the base, and 0.6 m above it, which sees what comes at the arm and is the
``occluded`` behaviour's camera; one over the arm's shoulder, 0.5 m behind the base and 1 m above
``m``, which sees the faces of the scene the arm works at, where the first sees their backs; the
``occluded`` behaviour has the front camera alone, as the shoulder camera would see its box).
The obstacles' shapes and places are drawn once per (problem, behaviour), so the speeds and
sensing models of one problem and behaviour are paired: they differ in nothing else.

A draw is kept only if, at every speed, no moving obstacle comes within 5 cm (checked every
0.1 s) of the links only the first joint moves (the base and link 1: the arm cannot move them out
of its way), the arm at its start is at least 5 cm from them during the first 0.5 s, and the arm
at the goal configuration is at least 2 cm from them at every sampled time (every 50 ms) of the
horizon's second half (the goal can be reached and held after any obstacle has left); besides,
a ``blocking`` obstacle must put the goal configuration in collision halfway through its hold, an
``appearing`` one appear at least 5 cm from the arm at its start, and an ``occluded`` board hide
the box's centre from the camera at the start. Otherwise it is drawn again (at most 100 times).
Draws come from ``numpy.random.default_rng([seed, crc32(problem ref), behaviour index, k])``
alone, so a scenario does not depend on which others are generated, and the first three
behaviours on the first six problems are the 108 scenarios of generator version 1, unchanged.

The shipped set (``planbench/data/scenarios/dynamic.json``, :data:`BASE_PROBLEMS`: 9 problems,
3 per robot, x 8 behaviours x 3 speeds x 2 sensing models = 432 scenarios, horizon 20 s at 100 Hz)
is written by ``python -m planbench.reactive.generator`` (seed 0); lengths are rounded to 0.1 mm so
float round-off elsewhere cannot change it. It is split by base problem (:data:`TUNE_PROBLEMS`):
``dynamic-tune``, one problem per robot, is where a controller's defaults may be tuned;
``dynamic-test`` holds the rest, whose scenes the defaults have not seen. Solvability
certificates are a separate step over the written file (:mod:`planbench.reactive.certify_set`).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from planbench.errors import PlanbenchError
from planbench.problem import Problem
from planbench.problems.datasets import load_problem
from planbench.reactive.behaviours import BEHAVIOURS, PathFrame, draw, p
from planbench.reactive.checker import TickChecker
from planbench.reactive.scenario import CameraSettings, Scenario, SensingSettings
from planbench.scene import Obstacle, Scene

__all__ = [
    "BASE_PROBLEMS",
    "BEHAVIOURS",
    "GENERATOR_VERSION",
    "SENSING",
    "SPEEDS",
    "SPLITS",
    "TUNE_PROBLEMS",
    "dynamic_scenarios",
    "hides",
    "scenario",
    "split_of",
]

GENERATOR_VERSION = 3
SET_FORMAT = "planbench-scenario-set/1"
SPEEDS = {"slow": 0.2, "medium": 0.5, "fast": 1.0}
"""Peak speed [m/s] of the moving obstacles' fastest point."""
SENSING = ("truth", "depth")
HORIZON = 20.0  # [s]
CONTROL_RATE = 100.0  # [Hz]
MAX_DRAWS = 100

BASE_PROBLEMS = (
    "mbm:box/0001",
    "mbm:bookshelf_tall/0001",
    "gen:panda_table_clutter/0003:bare",
    "gen:ur5_table_clutter/0002:bare",
    "gen:ur5_table_clutter/0003:bare",
    "gen:ur5_table_clutter/0004:bare",
    "gen:xarm7_table_clutter/0001:bare",
    "gen:xarm7_table_clutter/0003:bare",
    "gen:xarm7_table_clutter/0007:bare",
)
"""The static problems of the ``dynamic`` set, three per robot; a problem's place here (from 1) is
the index in its scenarios' names. ``:bare``: the problem with its table's clutter removed
(obstacles named ``object*``: the table, its legs and the floor stay), so that a box sliding on the
table is the challenge; scenarios refer to their problem by this reference. Chosen as problems
whose static scene a field controller solves in closed loop (truth sensing, no compute charged;
docs/reactive.md; the xArm7's: ``matrix-field`` and ``distance-field`` both reach the goal, and
0002 was passed over: no swinging draw on it is valid at every speed), so that
a failure in a dynamic scenario is the moving obstacles' doing; the MotionBenchMaker ones from the
tuning range (0001-0020)."""

TUNE_PROBLEMS = ("mbm:box/0001", "gen:ur5_table_clutter/0002:bare", "gen:xarm7_table_clutter/0001:bare")
"""The base problems of ``dynamic-tune``, one per robot (a third of them); the others are
``dynamic-test``'s."""
SPLITS = ("tune", "test")


def split_of(ref: str) -> str:
    """``"tune"`` for a problem of :data:`TUNE_PROBLEMS`, else ``"test"``."""
    return "tune" if ref in TUNE_PROBLEMS else "test"


def base_problem(ref: str) -> Problem:
    """The problem ``ref`` names (``":bare"``: without its clutter; :mod:`planbench.problems.datasets`)."""
    return load_problem(ref)


def dynamic_scenarios(
    refs: Sequence[str] = BASE_PROBLEMS,
    seed: int = 0,
    behaviours: Sequence[str] = BEHAVIOURS,
    refused: Mapping[tuple[str, str], Iterable[int]] | None = None,
) -> list[Scenario]:
    """Every behaviour x speed x sensing model on each problem of ``refs``: 6 per problem and
    behaviour; ``refused[(ref, behaviour)]``: draws not to use (their certification failed)."""
    out = []
    for i, ref in enumerate(refs, start=1):
        problem = base_problem(ref)
        for behaviour in behaviours:
            skip = tuple((refused or {}).get((ref, behaviour), ()))
            for speed in SPEEDS:
                for sensing in SENSING:
                    out.append(scenario(problem, ref, behaviour, speed, sensing, seed, index=i, refused=skip))
    return out


def scenario(
    problem: Problem,
    ref: str,
    behaviour: str,
    speed: str,
    sensing: str,
    seed: int = 0,
    index: int = 1,
    refused: Iterable[int] = (),
) -> Scenario:
    """One scenario (module docstring); ``refused``: draws not to use (their certification
    failed). Raises :class:`PlanbenchError` when no valid draw is found."""
    if behaviour not in BEHAVIOURS or speed not in SPEEDS or sensing not in SENSING:
        raise ValueError(f"behaviour, speed, sensing must be in {BEHAVIOURS}, {tuple(SPEEDS)}, {SENSING}")
    robot = problem.robot.name
    name = f"dynamic:{robot}_{behaviour}_{speed}_{sensing}/{index:04d}"
    frame = path_frame(problem)
    sense = _sensing(sensing, frame.m, behaviour)
    k = _paired_draw(problem, ref, behaviour, seed, tuple(sorted(refused)))
    moving = draw(behaviour, SPEEDS[speed], frame, _rng(seed, ref, behaviour, k))
    metadata = {
        "set": "dynamic",
        "split": split_of(ref),
        "family": f"{robot}_{behaviour}",
        "robot": robot,
        "behaviour": behaviour,
        "speed": speed,
        "sensing": sensing,
        "base": ref,
        "draw": k,
        "generator": GENERATOR_VERSION,
    }
    return Scenario(problem, moving, sense, CONTROL_RATE, HORIZON, name, metadata, ref)


def _rng(seed: int, ref: str, behaviour: str, k: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(ref.encode()), BEHAVIOURS.index(behaviour), k])


@functools.lru_cache(maxsize=256)
def _paired_draw(problem: Problem, ref: str, behaviour: str, seed: int, refused: tuple[int, ...] = ()) -> int:
    """The first draw valid at every speed (so the speeds of a problem and behaviour differ in
    nothing else), skipping ``refused``."""
    frame = path_frame(problem)
    for k in range(MAX_DRAWS):
        if k in refused:
            continue
        if all(
            _valid(
                Scenario(problem, draw(behaviour, v, frame, _rng(seed, ref, behaviour, k)), horizon=HORIZON),
                behaviour,
                frame,
            )
            for v in SPEEDS.values()
        ):
            return k
    raise PlanbenchError(
        f"{ref}: no draw of a {behaviour} obstacle valid at every speed in {MAX_DRAWS} tries: leave this "
        "behaviour out for this problem or choose another base problem"
    )


def path_frame(problem: Problem) -> PathFrame:
    """Where a problem's behaviours are placed (:class:`PathFrame`)."""
    ps = problem.robot.frame_pose(problem.start, problem.goal.pose.frame).translation.copy()
    pg = np.asarray(problem.goal.pose.position, dtype=float)
    d = pg - ps
    u = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-6 else np.array([1.0, 0.0, 0.0])
    w = np.cross(u, [0.0, 0.0, 1.0])
    w = w / np.linalg.norm(w) if np.linalg.norm(w) > 1e-6 else np.array([0.0, 1.0, 0.0])
    approach = np.asarray(problem.goal.pose.rotation, dtype=float)[:, 2].copy()
    return PathFrame(ps, pg, u, w, approach, np.asarray(_camera(0.5 * (ps + pg)).position), HORIZON)


def _outward(m: np.ndarray) -> np.ndarray:
    """The horizontal unit direction from the base toward ``m``."""
    out = np.array([m[0], m[1], 0.0])
    return out / np.linalg.norm(out) if np.linalg.norm(out) > 1e-6 else np.array([1.0, 0.0, 0.0])


def _camera(m: np.ndarray) -> CameraSettings:
    """The front depth camera: 1.3 m out from ``m`` (away from the base, horizontally), 0.6 m above it."""
    return CameraSettings(
        position=p(m + 1.3 * _outward(m) + [0.0, 0.0, 0.6]), look_at=p(m), noise_std=0.005, dropout=0.05
    )


def _shoulder_camera(m: np.ndarray) -> CameraSettings:
    """The camera over the arm's shoulder: 0.5 m behind the base (away from ``m``), 1 m above ``m``.
    Chosen on ``dynamic-tune`` (docs/reactive.md, "Two cameras"): with the front camera alone, the
    faces of shelves and boxes that the arm reaches into are never seen."""
    return CameraSettings(
        position=p(-0.5 * _outward(m) + [0.0, 0.0, m[2] + 1.0]), look_at=p(m), noise_std=0.005, dropout=0.05
    )


def _sensing(model: str, m: np.ndarray, behaviour: str) -> SensingSettings:
    """The scenario's sensing: the front camera and the shoulder one, but the front camera alone
    for ``occluded``, whose board hides the box from that camera only (the shoulder camera sees
    it in every drawn scenario): the behaviour is there to test what a controller remembers of
    an obstacle a moving one hides."""
    if model == "truth":
        return SensingSettings("truth", rate=30.0)
    cameras = (_camera(m),) if behaviour == "occluded" else (_camera(m), _shoulder_camera(m))
    return SensingSettings("depth", rate=30.0, latency=0.03, cameras=cameras)


def _valid(s: Scenario, behaviour: str, frame: PathFrame) -> bool:
    """The module docstring's rules: start and base clear, the goal clear over the second half of
    the horizon, and each behaviour's own promise."""
    alone = Scenario(dataclasses.replace(s.problem, scene=Scene()), s.moving)  # the moving obstacles only
    checker = TickChecker(alone)
    start = np.asarray(s.problem.start)
    if min(checker.clearance(start, t) for t in np.arange(0.0, 0.5, 0.05)) < 0.05:
        return False
    if _base_clearance(checker, start, np.arange(0.0, s.horizon, 0.1)) < 0.05:
        return False
    goal = s.problem.goal.q
    if goal is not None:
        times = np.arange(0.5 * s.horizon, s.horizon, 0.05)
        if min(checker.clearance(np.asarray(goal), t) for t in times) < 0.02:
            return False
    first = s.moving[0]
    if behaviour == "blocking":
        hold = first.motion.times[1:3]
        return goal is None or checker.clearance(np.asarray(goal), 0.5 * (hold[0] + hold[1])) < 0.0
    if behaviour == "appearing":
        return checker.clearance(start, first.appear) >= 0.05
    if behaviour == "occluded":
        return hides(s.moving[1].at(0.0), frame.camera, np.asarray(first.obstacle.position))
    return True


def hides(board: Obstacle, eye: np.ndarray, target: np.ndarray, samples: int = 200) -> bool:
    """Whether the box ``board`` cuts the line of sight from ``eye`` to ``target`` [m]."""
    M = board.placement()
    half = 0.5 * np.asarray(board.size, dtype=float)
    points = eye + np.linspace(0.0, 1.0, samples)[:, None] * (np.asarray(target) - eye)
    local = (points - M.translation) @ M.rotation  # into the board's frame
    return bool(np.any(np.all(np.abs(local) <= half, axis=1)))


def _base_clearance(checker: TickChecker, q: np.ndarray, times: np.ndarray) -> float:
    """Smallest distance [m] over ``times`` [s] from the moving obstacles to the links no joint but
    the first moves (the base and the first link: the arm cannot take them out of the way), the
    arm at ``q``. Only those pairs are computed (a tenth of the time of every pair)."""
    c = checker.checker
    gm = c.geometry_model
    n = c.n_robot_geoms
    base = {i for i in range(n) if gm.geometryObjects[i].parentJoint <= 1}
    pairs = [k for k, (a, b) in enumerate(c.pairs) if (a in base or b in base) and max(a, b) >= n]
    model = c.robot.model
    data, gdata = model.createData(), pin.GeometryData(gm)
    pin.forwardKinematics(model, data, q)
    best = np.inf
    for t in times:
        checker.place(float(t))
        pin.updateGeometryPlacements(model, data, gm, gdata)
        for k in pairs:
            best = min(best, pin.computeDistance(gm, gdata, k).min_distance)
    return float(best)


SMOKE = (
    "dynamic:panda_crossing_medium_truth/0001",
    "dynamic:panda_swinging_medium_depth/0003",
    "dynamic:ur5_sliding_medium_truth/0004",
    "dynamic:ur5_crossing_medium_depth/0005",
)
"""The ``dynamic-smoke`` set: both first robots, three behaviours, both sensing models, medium speed."""


def write_set(out: str | Path, seed: int = 0) -> Path:
    """Write the ``dynamic`` set as one JSON file in folder ``out`` (``dynamic.json``). Draws that
    an earlier certification refused (the file's ``refused_draws``, kept) are drawn again; the
    new file is not certified: ``python -m planbench.reactive.certify_set`` certifies it in place."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "dynamic.json"
    refused_draws = json.loads(path.read_text()).get("refused_draws", []) if path.is_file() else []
    refused: dict[tuple[str, str], list[int]] = {}
    for item in refused_draws:
        refused.setdefault((item["base"], item["behaviour"]), []).append(int(item["draw"]))
    data = {
        "format": SET_FORMAT,
        "name": "dynamic",
        "generator": GENERATOR_VERSION,
        "seed": seed,
        "base_problems": list(BASE_PROBLEMS),
        "splits": {split: [ref for ref in BASE_PROBLEMS if split_of(ref) == split] for split in SPLITS},
        "smoke": list(SMOKE),
        "certified": False,
        "refused_draws": refused_draws,
        "scenarios": [s.to_dict() for s in dynamic_scenarios(BASE_PROBLEMS, seed, refused=refused)],
    }
    path.write_text(json.dumps(data, indent=1) + "\n")
    return path


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="write planbench's dynamic scenario set")
    parser.add_argument("--out", default="planbench/data/scenarios", help="folder (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    print(write_set(parser.parse_args().out, parser.parse_args().seed))
