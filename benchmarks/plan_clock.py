"""How much work a time-limited OMPL plan does on an idle and on a loaded machine, by clock.

    python benchmarks/plan_clock.py                        # 0.5 s plans, 5 each, 0 and 2 busy processes
    python benchmarks/plan_clock.py --limit 1.0 --repeat 7 --busy 0 2 4

The closed loop charges a controller the CPU time of its process (docs/reactive.md). A plan whose
limit counts elapsed time (``clock = "wall"``) gets less CPU, so less search, when other
processes share the cores, and it is charged less; one whose limit counts this process's CPU time
(``clock = "cpu"``, ``ompl-replan``'s ``plan_clock`` default) does the same work on both and takes
longer. The workload is RRT-Connect on the conformance checker's blocked problem with every motion
refused, so that each plan runs to its limit: printed are the medians of its CPU time (the
compute the closed loop charges and the work the search does), of its elapsed time and of the
collision checks of configurations it made, and the CPU time's ratio to the first load's per
clock. (The checks a CPU second makes moved by a third between runs on the shared VM: the CPU
time is the steadier measure of work.)
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

import planbench
from planbench.conformance import blocked_problem
from planbench.planner import PlanStatus
from planbench_plugins.ompl_planners import RRTConnectPlanner
from planbench_plugins.ompl_planners.motion import SegmentChecker

BUSY = "while True: pass"


def plans(problem: planbench.Problem, clock: str, limit: float, repeat: int) -> tuple[float, float, float]:
    """Medians of (configuration checks, elapsed [s], CPU [s]) over ``repeat`` plans run to ``limit``."""
    checks, wall, cpu = [], [], []
    for k in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        result = planbench.plan(problem, RRTConnectPlanner, seed=k, time_limit=limit, clock=clock)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
        assert result.status is PlanStatus.TIMEOUT, result.message
        checks.append(result.info["collision_checks"])
    return statistics.median(checks), statistics.median(wall), statistics.median(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--limit", type=float, default=0.5, help="each plan's time limit [s]")
    ap.add_argument("--repeat", type=int, default=5, help="plans per clock and load")
    ap.add_argument("--busy", type=int, nargs="+", default=[0, 2], help="busy processes beside the plans")
    args = ap.parse_args()
    problem = blocked_problem()
    SegmentChecker.motion_free = lambda self, a, b: False  # type: ignore[method-assign]  # every motion refused
    planbench.plan(problem, RRTConnectPlanner, seed=0, time_limit=0.2)  # imports and caches warm
    rows: list[tuple[int, str, tuple[float, float, float]]] = []
    for busy in args.busy:
        procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(busy)]
        try:
            time.sleep(0.5 if busy else 0.0)
            for clock in ("wall", "cpu"):
                rows.append((busy, clock, plans(problem, clock, args.limit, args.repeat)))
        finally:
            for p in procs:
                p.kill()
                p.wait()
    first = {clock: measured[2] for busy, clock, measured in rows[:2]}
    print(f"RRT-Connect plans of {args.limit} s run to the limit, medians of {args.repeat}")
    print(f"| busy processes | clock | CPU [s] | elapsed [s] | configuration checks | CPU / with {args.busy[0]} busy |")
    print("| --- | --- | --- | --- | --- | --- |")
    for busy, clock, (checks, wall, cpu) in rows:
        print(f"| {busy} | {clock} | {cpu:.3f} | {wall:.3f} | {checks:.0f} | {cpu / first[clock]:.2f} |")


if __name__ == "__main__":
    main()
