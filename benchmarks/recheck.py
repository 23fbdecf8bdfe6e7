"""Re-check every path planbench validated with an independent dense checker.

Runs each planner on each problem with ``planbench.bench`` (isolated workers, the certified
validation; benchmarks/_bench.py), then re-checks every *accepted* path with a plain dense
collision check (pinocchio + coal, every pair, no broadphase, configurations at most
``--resolution`` rad apart, default 1e-4). Prints, per planner, the runs, the validated successes
and how many of those the dense check finds colliding (which must be zero). Problems:
MotionBenchMaker selectors, plus generated scenes the repository does not ship (random boxes,
spheres, cylinders and thin plates around the arm) for the Panda and the UR5.

    python benchmarks/recheck.py --mbm "mbm:*/0021-0022" --generated 6 --time-limit 2 --seed 1
"""

from __future__ import annotations

import argparse
import math
import tempfile
from collections import defaultdict

import numpy as np
from _bench import run_suite, write_problems

import planbench
from planbench import Problem, Scene
from planbench.checking.collision import CollisionChecker
from planbench.metrics import densify
from planbench.scene import Obstacle

PLANNERS = (
    "straight-line,matrix-field,matrix-field-qp,distance-field,edt-field,"
    "ompl-rrtconnect,ompl-rrtstar,ompl-bitstar,ompl-prmstar,ompl-kpiece"
)


def _obstacle(rng: np.random.Generator, name: str, reach: float) -> Obstacle:
    r = rng.uniform(0.25, 0.9) * reach
    phi, z = rng.uniform(-math.pi, math.pi), rng.uniform(0.0, 0.9 * reach)
    position = (r * math.cos(phi), r * math.sin(phi), z)
    q = rng.normal(size=4)
    a, b, c, d = (float(x) for x in q / np.linalg.norm(q))
    quat = (a, b, c, d)
    kind = rng.choice(["box", "sphere", "cylinder", "plate"])
    if kind == "box":
        return Obstacle(name, "box", position, quat, size=tuple(rng.uniform(0.04, 0.3, 3)))
    if kind == "plate":  # thin: what sampled checking misses
        size = (float(rng.uniform(0.002, 0.006)), float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.1, 0.4)))
        return Obstacle(name, "box", position, quat, size=size)
    if kind == "sphere":
        return Obstacle(name, "sphere", position, radius=float(rng.uniform(0.03, 0.12)))
    return Obstacle(
        name, "cylinder", position, quat, radius=float(rng.uniform(0.02, 0.08)), length=float(rng.uniform(0.1, 0.5))
    )


def generated_problems(robot_name: str, n: int, seed: int) -> list[Problem]:
    """``n`` clutter problems: 4-8 random obstacles, start and goal random free configurations."""
    robot = planbench.load_robot(robot_name)
    rng = np.random.default_rng(seed)
    reach = robot.reach()
    out: list[Problem] = []
    while len(out) < n:
        scene = Scene(tuple(_obstacle(rng, f"o{i}", reach) for i in range(int(rng.integers(4, 9)))))
        checker = CollisionChecker(robot, scene)
        free = []
        for _ in range(200):
            q = rng.uniform(robot.lower, robot.upper)
            if not checker.in_collision(q):
                free.append(q)
            if len(free) == 2:
                break
        if len(free) == 2:
            out.append(Problem.create(robot, scene, free[0], free[1], id=f"gen-{robot_name}/{len(out):04d}"))
    return out


def dense_collides(problem: Problem, path: np.ndarray, resolution: float) -> bool:
    checker = CollisionChecker(problem.robot, problem.scene)  # fresh: no state from planbench's checks
    dense, _ = densify(path, resolution)
    return any(checker.in_collision_all_pairs(q) for q in dense)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mbm", default="mbm:*/0021-0022", help="MotionBenchMaker selector ('' for none)")
    ap.add_argument("--generated", type=int, default=6, help="generated problems per robot (Panda, UR5)")
    ap.add_argument("--planners", default=PLANNERS)
    ap.add_argument("--time-limit", type=float, default=2.0)
    ap.add_argument("--resolution", type=float, default=1e-4, help="dense re-check resolution [rad]")
    ap.add_argument("--seed", type=int, default=1, help="seed of the generated scenes")
    args = ap.parse_args()

    generated: list[Problem] = []
    for robot in ("panda", "ur5"):
        generated += generated_problems(robot, args.generated, seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        selectors = ([args.mbm] if args.mbm else []) + ([write_problems(generated, tmp)] if generated else [])
        rows = run_suite("recheck", selectors, args.planners.split(","), time_limit=args.time_limit)
        problems = {p.id: p for sel in selectors for p in planbench.load_problems(sel)}
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0])
    bad: list[str] = []
    for row in rows:  # validated by the benchmark; re-checked here densely with a fresh checker
        c = counts[row["planner"]]
        c[0] += 1
        if row["success"] and row["path"] is not None:
            c[1] += 1
            if dense_collides(problems[row["problem"]], row["path"], args.resolution):
                c[2] += 1
                bad.append(f"{row['planner']} {row['problem']}")
    print(f"\n{len(problems)} problems; dense re-check every {args.resolution:g} rad")
    print(f"{'planner':<18} {'runs':>5} {'validated':>9} {'dense collides':>14}")
    for planner, (runs, ok, hit) in counts.items():
        print(f"{planner:<18} {runs:>5} {ok:>9} {hit:>14}")
    for line in bad:
        print("COLLIDING ACCEPTED PATH:", line)


if __name__ == "__main__":
    main()
