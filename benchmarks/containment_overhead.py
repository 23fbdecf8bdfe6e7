"""What containment costs (issue 28): `planbench bench` of this checkout against a baseline checkout
(the commit before containment), alternated in one run, on the smoke suite and on MotionBenchMaker
0001-0010 (all families) with straight-line, matrix-field and ompl-rrtconnect (a fresh process per
run in both).

    git worktree add /tmp/planbench-base 6d96a81        # the commit before containment
    python benchmarks/containment_overhead.py --base /tmp/planbench-base [--repeats 3] [--jobs 2]

Prints per suite and checkout: the median wall time of the whole command, the workers it started
(distinct worker pids), and the median per-run overhead (dispatch to record, less planning and
validation: worker start where one started, setup, hand-offs), with the ratio contained/baseline.
Both checkouts run with numba's cache warm (one untimed run of each first).
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SUITES = {
    "smoke": ["--suite", "smoke"],
    "mbm 0001-0010": [
        *("--suite", "mbm", "--problems", "mbm:*/0001-0010"),
        *("--planners", "straight-line,matrix-field,ompl-rrtconnect"),
    ],
}


def bench(tree: Path, args: list[str], jobs: int) -> tuple[float, int, float, int]:
    """(wall [s], workers started, median per-run overhead [s], runs) of one `planbench bench`."""
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "r.db"
        env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
        command = [sys.executable, "-m", "planbench.cli.main", "bench", *args, "--out", str(db), "--jobs", str(jobs)]
        t0 = time.perf_counter()
        subprocess.run([*command, "--no-progress"], env=env, cwd=tmp, check=True, capture_output=True)
        wall = time.perf_counter() - t0
        with sqlite3.connect(db) as conn:
            rows = conn.execute("SELECT worker_pid, elapsed, planning_time, validation_time FROM runs").fetchall()
    workers = len({r[0] for r in rows})
    overhead = [e - (p or 0.0) - (v or 0.0) for _, e, p, v in rows if e is not None]
    return wall, workers, statistics.median(overhead), len(rows)


ENTER = """
import json, tempfile, time
from planbench.bench import procs, sandbox
t0 = time.perf_counter()
cgroups = procs.Cgroups()
path = cgroups.make("probe-cost")
t1 = time.perf_counter()
state = sandbox.enter(tempfile.mkdtemp(), True)
t2 = time.perf_counter()
cgroups.close()
print(json.dumps({"cgroup": t1 - t0, "enter": t2 - t1, "state": state}))
"""


def entry_cost(repeats: int) -> None:
    """What a worker pays to enter its containment: make its cgroup (in the parent), seed its numba
    cache and enter the sandbox (in the worker), medians of fresh processes."""
    import json

    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    env.update({name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})
    runs = []
    for _ in range(repeats):
        out = subprocess.run([sys.executable, "-c", ENTER], env=env, capture_output=True, text=True, check=True)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    cgroup = statistics.median(r["cgroup"] for r in runs)
    enter = statistics.median(r["enter"] for r in runs)
    print(
        f"worker containment, {repeats} fresh processes (medians): cgroup {1000 * cgroup:.1f} ms, "
        f"sandbox entry with numba cache seed {1000 * enter:.1f} ms ({runs[0]['state']})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", type=Path, required=True, help="a checkout of the commit before containment")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    trees = {"baseline": args.base.resolve(), "contained": ROOT}
    entry_cost(max(5, args.repeats))
    for name, suite in SUITES.items():
        for tree in trees.values():  # warm numba's cache and the OS's file cache, untimed
            bench(tree, suite, args.jobs)
        results: dict[str, list[tuple[float, int, float, int]]] = {k: [] for k in trees}
        for _ in range(args.repeats):
            for label, tree in trees.items():
                results[label].append(bench(tree, suite, args.jobs))
        print(f"\n{name}, --jobs {args.jobs}, {args.repeats} repeats (medians)")
        print(f"{'':>10} {'wall [s]':>9} {'workers':>8} {'per-run overhead [ms]':>22} {'runs':>5}")
        medians = {}
        for label, rows in results.items():
            wall = statistics.median(r[0] for r in rows)
            workers = statistics.median(r[1] for r in rows)
            overhead = statistics.median(r[2] for r in rows)
            medians[label] = (wall, overhead)
            print(f"{label:>10} {wall:9.2f} {workers:8.0f} {1000 * overhead:22.1f} {rows[0][3]:5d}")
        (bw, bo), (cw, co) = medians["baseline"], medians["contained"]
        print(f"{'ratio':>10} {cw / bw:9.2f}x {'':>8} {co / bo:21.2f}x")


if __name__ == "__main__":
    main()
