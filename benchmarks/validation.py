"""Certified path validation against the sampled check it replaced, on the same paths, in one run.

Runs the given planners on MotionBenchMaker problems with ``planbench.bench`` (seed 0;
benchmarks/_bench.py), then validates every path a planner claimed with both checkers,
``--repeats`` times each, and prints per planner the median time per path [ms], the ratio
certified / sampled (median of per-path ratios), the distance queries the certified check needed,
and the verdicts on which the two disagree.

The sampled check is planbench's former validation: configurations 0.01 rad apart along every
segment, each checked for collision (coal, broadphase), plus the clearance every 0.05 rad.

    python benchmarks/validation.py --problems "mbm:*/0001-0003" --planners ompl-rrtconnect,matrix-field
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from _bench import run_suite

import planbench
from planbench.checking.certified import CertifiedChecker
from planbench.checking.collision import CollisionChecker
from planbench.metrics import densify
from planbench.validate import ValidationSettings


def sampled_check(checker: CollisionChecker, path: np.ndarray) -> tuple[bool, float]:
    """The former validation: (free at 0.01 rad samples, min clearance at 0.05 rad samples)."""
    dense, _ = densify(path, 0.01)
    free = not any(checker.in_collision(q) for q in dense)
    coarse, _ = densify(path, 0.05)
    return free, min(checker.clearance(q) for q in coarse)


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", default="mbm:*/0001-0003")
    ap.add_argument("--planners", default="ompl-rrtconnect,matrix-field")
    ap.add_argument("--time-limit", type=float, default=5.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--per-path", action="store_true", help="also print every path's timings and queries")
    args = ap.parse_args()

    problems = {p.id: p for p in planbench.load_problems(args.problems)}
    planners = args.planners.split(",")
    runs = run_suite("validation", [args.problems], planners, time_limit=args.time_limit)
    settings = ValidationSettings().certification()
    print(f"{len(problems)} problems, planners {args.planners}, {args.repeats} repeats per check")
    print(
        f"{'planner':<18} {'paths':>5} {'certified ms':>12} {'sampled ms':>10} {'ratio':>6} "
        f"{'queries':>8} {'exact':>6} {'sampled-only free':>17}"
    )
    for planner in planners:
        rows = []
        for run in runs:
            if run["planner"] != planner or run["path"] is None or len(run["path"]) == 0:
                continue
            if run["status"] != "success":  # the planner's own claim; both checkers then judge the path
                continue
            p, path = problems[run["problem"]], run["path"]
            certified = CertifiedChecker(p.robot, p.scene, settings)
            sampled = CollisionChecker(p.robot, p.scene)
            verdict = certified.check_path(path)  # warm both, and keep one verdict
            sampled_free, _ = sampled_check(sampled, path)
            t_cert = median_time(lambda c=certified, x=path: c.check_path(x), args.repeats)
            t_samp = median_time(lambda c=sampled, x=path: sampled_check(c, x), args.repeats)
            rows.append((t_cert, t_samp, verdict.queries, verdict.exact_queries, verdict.free, sampled_free))
            if args.per_path:
                print(
                    f"  {planner} {p.id}: {len(path)} waypoints, certified {t_cert * 1e3:.1f} ms "
                    f"({'free' if verdict.free else 'rejected'}, {verdict.queries} queries, "
                    f"{verdict.exact_queries} exact), sampled {t_samp * 1e3:.1f} ms "
                    f"({'free' if sampled_free else 'rejected'})"
                )
        if not rows:
            print(f"{planner:<18} no solved paths")
            continue
        cert = [r[0] * 1e3 for r in rows]
        samp = [r[1] * 1e3 for r in rows]
        ratio = [r[0] / r[1] for r in rows]
        only_sampled = sum(1 for r in rows if r[5] and not r[4])
        print(
            f"{planner:<18} {len(rows):>5} {statistics.median(cert):>12.1f} {statistics.median(samp):>10.1f} "
            f"{statistics.median(ratio):>6.2f} {statistics.median(r[2] for r in rows):>8.0f} "
            f"{statistics.median(r[3] for r in rows):>6.0f} {only_sampled:>17}"
        )


if __name__ == "__main__":
    main()
