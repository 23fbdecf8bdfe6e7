"""OMPL baselines: collision checks per second, where a check's time goes, and MBM success/time.

Usage::

    python benchmarks/ompl_checks.py checks [--problems mbm:*/0001-0003] [--n 2000]
    python benchmarks/ompl_checks.py mbm [--problems mbm:*/0001-0010] [--planner ompl-rrtconnect] [--time-limit 5]
    python benchmarks/ompl_checks.py sweep [--problems mbm:*/0001-0010] [--ranges 0,0.25,0.5,1]

``checks`` times, in one run and on the same random configurations: the checker without broadphase
(every pair to coal), with broadphase (``CollisionChecker.in_collision``), the same configurations
as one batch (``SegmentChecker``: how the OMPL planners check motions, one pinocchio call per
motion), against the occupancy grid as an octree and as merged boxes, the Python validity-callback
overhead (state -> array), and the rate reached inside an OMPL RRTConnect solve (checks / solve
time). Where a check's time goes, in pinocchio's own steps on the same configurations: forward
kinematics, + geometry placements, + the broadphase's AABB-tree update, and the rest (the
broadphase traversal and coal's narrowphase) = the full batch check minus those. Medians over
problems.

``sweep`` runs ``ompl-rrtconnect`` (seed 0, 5 s) with each ``range`` (0: OMPL's own default) on the
problems, one range after the other, and prints validated successes and the median planning time.

``mbm`` and ``sweep`` run through ``planbench.bench`` (isolated workers, certified validation).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
from _bench import run_suite

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.problems.datasets import load_problems


def _per_call(fn, Q) -> float:  # type: ignore[no-untyped-def]
    t = time.perf_counter()
    for q in Q:
        fn(q)
    return (time.perf_counter() - t) / len(Q) * 1e6


def split(checker: CollisionChecker, Q: np.ndarray) -> dict[str, float]:
    """Cumulative cost [us per configuration] of pinocchio's steps of a broadphase check."""
    import pinocchio as pin

    model, geom = checker.robot.model, checker.geometry_model
    data, gdata = model.createData(), pin.GeometryData(geom)
    manager = pin.BroadPhaseManager_DynamicAABBTreeCollisionManager(model, geom, gdata)

    def placements(q: np.ndarray) -> None:
        pin.updateGeometryPlacements(model, data, geom, gdata, q)

    def update(q: np.ndarray) -> None:
        pin.updateGeometryPlacements(model, data, geom, gdata, q)
        manager.update(False)

    return {
        "fk": _per_call(lambda q: pin.forwardKinematics(model, data, q), Q),
        "placements": _per_call(placements, Q),
        "bp_update": _per_call(update, Q),
    }


def checks(selector: str, n: int, with_boxes: bool) -> None:
    from ompl import base as ob

    from planbench_plugins.ompl_planners import RRTConnectPlanner
    from planbench_plugins.ompl_planners.grid import grid_checker, grid_for_scene
    from planbench_plugins.ompl_planners.motion import SegmentChecker

    rows = []
    space = ob.RealVectorStateSpace(7)
    state = space.allocState()
    for problem in load_problems(selector):
        robot = problem.robot
        checker = CollisionChecker(robot, problem.scene)
        grid = grid_for_scene(problem.scene, 0.02, padding=0.02)
        octree = grid_checker(robot, grid, "octree")
        boxes = grid_checker(robot, grid, "boxes") if with_boxes else None
        Q = np.random.default_rng(0).uniform(robot.lower, robot.upper, size=(n, robot.nq))
        segments = SegmentChecker(checker, 0.01)
        batch = segments._pool  # the batch check without stopping, for timing every configuration
        QT = np.asfortranarray(Q.T)
        import pinocchio as pin

        t = time.perf_counter()
        pin.computeCollisionsInParallel(1, batch, QT, True, False)
        batch_us = (time.perf_counter() - t) / len(Q) * 1e6
        row = {
            "all_pairs": _per_call(checker.in_collision_all_pairs, Q),
            "broadphase": _per_call(checker.in_collision, Q),
            "batch": batch_us,
            "octree": _per_call(octree.in_collision, Q),
            "boxes": _per_call(boxes.in_collision, Q[:300]) if boxes else float("nan"),
            "callback": _per_call(lambda q: np.array([state[i] for i in range(7)]), Q),
            "collide_frac": float(np.mean([checker.in_collision(q) for q in Q[:500]])),
            **split(checker, Q),
        }
        result = planbench.plan(problem, RRTConnectPlanner(simplify=False, verify=False), seed=0, time_limit=5.0)
        if "solve_time" in result.info and result.info["solve_time"] > 0.01:
            row["ompl_rate"] = result.info["collision_checks"] / result.info["solve_time"]
        rows.append(row)
        print(
            f"{problem.id:28s} all pairs {row['all_pairs']:6.1f} us  broadphase {row['broadphase']:5.1f} us  "
            f"batch {row['batch']:5.1f} us  octree {row['octree']:5.1f} us  boxes {row['boxes']:6.1f} us  "
            f"callback {row['callback']:4.1f} us  in OMPL {row.get('ompl_rate', float('nan')):8.0f} checks/s  "
            f"({row['collide_frac']:.0%} of random q collide)"
        )

    def med(key: str) -> float:
        return statistics.median(r[key] for r in rows if key in r)

    print(f"\nmedians over {len(rows)} problems, {n} random configurations each:")
    keys = ["all_pairs", "broadphase", "batch", "octree"] + (["boxes"] if with_boxes else [])
    for key in keys:
        print(f"  {key:10s} {med(key):6.1f} us/check = {1e6 / med(key):8.0f} checks/s")
    fk, pl, up, full = med("fk"), med("placements"), med("bp_update"), med("batch")
    print(
        f"  split of a batch check ({full:.1f} us): forward kinematics {fk:.1f} us, geometry placements "
        f"{pl - fk:.1f} us, broadphase AABB-tree update {up - pl:.1f} us, broadphase traversal + "
        f"narrowphase {full - up:.1f} us; in_collision's Python call adds {med('broadphase') - full:.1f} us"
    )
    print(
        f"  broadphase speed-up over all pairs (median of per-problem ratios): "
        f"{statistics.median(r['all_pairs'] / r['broadphase'] for r in rows):.1f}x"
    )
    print(f"  Python callback (OMPL state -> numpy array): {med('callback'):.1f} us")
    print(f"  inside an OMPL RRTConnect solve (incl. OMPL's own work): {med('ompl_rate'):.0f} checks/s")


def mbm(selector: str, planner: str, time_limit: float) -> None:
    """``planner`` on every problem, run and validated by ``planbench.bench`` (benchmarks/_bench.py)."""
    rows = run_suite("ompl-checks-mbm", [selector], [planner], time_limit=time_limit)
    by_family: dict[str, list[tuple[bool, float, float]]] = {}
    for r in rows:
        info = json.loads(r["info"] or "{}")
        by_family.setdefault(r["family"], []).append(
            (bool(r["success"]), r["planning_time"] or float("nan"), r["joint_path_length"] or float("nan"))
        )
        print(
            f"{r['problem']:28s} {r['status']:10s} valid={bool(r['success'])!s:5s} {r['planning_time']:6.3f} s "
            f"solve {info.get('solve_time', float('nan')):.3f} s "
            f"simplify {info.get('simplify_time', float('nan')):.3f} s"
            + (f"  {(r['failure'] or '')[:60]}" if not r["success"] else "")
        )
    print(f"\n{planner}, time limit {time_limit} s")
    print("family              solved   median time [s] (solved)   median joint length [rad]")
    everything = []
    for fam, fam_rows in sorted(by_family.items()):
        everything += fam_rows
        ok = [x for x in fam_rows if x[0]]
        t = statistics.median(x[1] for x in ok) if ok else float("nan")
        length = statistics.median(x[2] for x in ok) if ok else float("nan")
        print(f"{fam:20s} {len(ok):3d}/{len(fam_rows):<3d}  {t:10.3f}                 {length:8.2f}")
    ok = [x for x in everything if x[0]]
    t_all = statistics.median(x[1] for x in ok) if ok else float("nan")
    print(f"{'all':20s} {len(ok):3d}/{len(everything):<3d}  {t_all:10.3f}")


def sweep(selector: str, ranges: list[float], time_limit: float) -> None:
    """``ompl-rrtconnect`` with each ``range``, one suite (one label per range) run by ``planbench.bench``."""
    planners = {f"range-{value:g}": ("ompl-rrtconnect", {"params": {"range": value}}) for value in ranges}
    rows = run_suite("ompl-checks-sweep", [selector], planners, time_limit=time_limit)
    for label in planners:
        mine = [r for r in rows if r["planner"] == label]
        times = [r["planning_time"] for r in mine if r["success"]]
        failed = [f"{r['problem']} ({r['status']})" for r in mine if not r["success"]]
        median = statistics.median(times) if times else float("nan")
        print(f"{label}: {len(times)}/{len(mine)} validated, median {median:.3f} s; failed: {failed}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("checks")
    c.add_argument("--problems", default="mbm:*/0001-0003")
    c.add_argument("--n", type=int, default=2000)
    c.add_argument("--boxes", action="store_true", help="also time the grid as merged boxes (slower than the octree)")
    m = sub.add_parser("mbm")
    m.add_argument("--problems", default="mbm:*/0001-0010")
    m.add_argument("--planner", default="ompl-rrtconnect")
    m.add_argument("--time-limit", type=float, default=5.0)
    w = sub.add_parser("sweep")
    w.add_argument("--problems", default="mbm:*/0001-0010")
    w.add_argument("--ranges", default="0,0.25,0.5,1")
    w.add_argument("--time-limit", type=float, default=5.0)
    args = parser.parse_args()
    if args.command == "checks":
        checks(args.problems, args.n, args.boxes)
    elif args.command == "sweep":
        sweep(args.problems, [float(x) for x in args.ranges.split(",")], args.time_limit)
    else:
        mbm(args.problems, args.planner, args.time_limit)


if __name__ == "__main__":
    main()
