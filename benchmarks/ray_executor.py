"""The Ray executor against the local one: wall time, Ray's overhead per run, the driver's cost per
row, and a check that the rows are identical (times aside: the rows' times and a planner's own
``*_time`` entries in ``info``), on this machine only (loopback).

    python benchmarks/ray_executor.py                 # smoke, then mbm:*/0001-0010 x 3 planners
    python benchmarks/ray_executor.py --suites smoke

Each suite runs three times: ``--executor local`` (``--jobs`` = CPUs), Ray on one node with CPUs
CPUs, Ray on ``CPUs`` simulated nodes of one CPU each (``ray.cluster_utils.Cluster``; the nodes
share this machine's cores). Per run, Ray's overhead is the time from handing the run to an actor
to its record being decoded in the driver, minus the run's own ``elapsed`` in the actor's slot. The
driver's throughput is measured twice: its CPU time per row over a whole benchmark (Ray's client
threads, decoding, writing), and the rate at which it writes the same records into a fresh
results file (the SQLite part alone).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"  # read when Ray is imported: loopback only

import numpy as np

from planbench.bench.benchmark import run_benchmark, select
from planbench.bench.db import ResultsDB
from planbench.bench.ray_executor import RayStats
from planbench.bench.runner import default_jobs
from planbench.bench.suite import parse_suite

MBM10 = """
[suite]
name = "mbm10"
problems = ["mbm:*/0001-0010"]
seeds = [0]
time_limit = 5.0
[[planners]]
planner = "straight-line"
[[planners]]
planner = "matrix-field"
[[planners]]
planner = "ompl-rrtconnect"
"""
VARIABLE = {"id", "planning_time", "setup_time", "wall_time", "validation_time", "elapsed", "worker_pid"}
VARIABLE |= {"host", "finished", "tick_time_median", "tick_time_p99", "field_update_time", "stalled_time"}


def _rows(path: Path) -> list[dict]:
    with ResultsDB(path) as db:
        return sorted(db.rows(with_arrays=True), key=lambda r: (r["problem"], r["planner"], r["seed"]))


def _key(row: dict) -> dict:
    out = {k: v for k, v in row.items() if k not in VARIABLE and k not in ("path", "times")}
    if isinstance(out.get("info"), str):  # a planner's own timings in info are times too
        info = json.loads(out["info"])
        out["info"] = {k: v for k, v in info.items() if not k.endswith("_time")}
    for k in ("path", "times"):
        out[k] = None if row[k] is None else np.ascontiguousarray(row[k], "<f8").tobytes()
    return {k: ("nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in out.items()}


def _differences(a: list[dict], b: list[dict]) -> list[str]:
    if len(a) != len(b):
        return [f"{len(a)} rows against {len(b)}"]
    out = []
    for x, y in zip(a, b, strict=True):
        kx, ky = _key(x), _key(y)
        if kx != ky:
            fields = sorted(k for k in kx if kx[k] != ky.get(k))
            deltas = [f"{k} {kx[k] - ky[k]:+.3g}" if isinstance(kx[k], float) else k for k in fields]
            out.append(f"{x['problem']} {x['planner']}: {', '.join(deltas)}")
    return out


def _write_rate(rows: list[dict], tmp: Path) -> float:
    """Rows per second written into a fresh results file, as the driver writes them (one commit each)."""
    with ResultsDB(tmp / "rewrite.db") as db:
        t0 = time.perf_counter()
        for r in rows:
            fields = {k: r[k] for k in ("suite", "problem", "family", "planner", "seed", "planner_name", "time_limit")}
            fields["planner_settings"], fields["planner_version"], fields["settings"] = {}, r["planner_version"], {}
            record = {
                "evaluation": {"success": bool(r["success"]), "failure": r["failure"], "status": r["status"]},
                "message": r["message"],
                "traceback": r["traceback"],
                "path": r["path"],
                "times": r["times"],
                "info": {},
                "wall_time": r["wall_time"],
                "validation_time": r["validation_time"],
                "elapsed": r["elapsed"],
                "pid": r["worker_pid"],
                "host": r["host"],
            }
            db.add_run(fields, record)
        return len(rows) / (time.perf_counter() - t0)


def _ray_run(suite, db: Path, nodes: int, cpus: int) -> tuple[float, float, RayStats]:
    import ray
    from ray.cluster_utils import Cluster

    from planbench.bench.ray_executor import RayExecutor

    t0 = time.perf_counter()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": cpus // nodes})
    try:
        for _ in range(nodes - 1):
            cluster.add_node(num_cpus=cpus // nodes)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, logging_level=logging.WARNING, log_to_driver=False)
        start = time.perf_counter() - t0
        executor = RayExecutor()
        t1 = time.perf_counter()
        run_benchmark(suite, db, executor=executor)
        return start, time.perf_counter() - t1, executor.stats
    finally:
        ray.shutdown()
        cluster.shutdown()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suites", nargs="+", default=["smoke", "mbm10"])
    parser.add_argument("--cpus", type=int, default=default_jobs())
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for name in args.suites:
            suite = parse_suite(MBM10, "mbm10.toml") if name == "mbm10" else select(name)
            t0 = time.perf_counter()
            local = run_benchmark(suite, tmp / f"{name}-local.db", jobs=args.cpus)
            wall_local = time.perf_counter() - t0
            base = _rows(tmp / f"{name}-local.db")
            iso = np.array([r["elapsed"] - r["wall_time"] for r in base], float)
            print(f"\nsuite {name}: {local.ran} runs")
            print(
                f"  local, --jobs {args.cpus}: {wall_local:.1f} s wall; isolation per run (median) "
                f"{1e3 * np.nanmedian(iso):.1f} ms"
            )
            for nodes in (1, args.cpus):
                db = tmp / f"{name}-ray{nodes}.db"
                start, wall, stats = _ray_run(suite, db, nodes, args.cpus)
                rows = _rows(db)
                diff = _differences(base, rows)
                over = np.array(stats.overhead)
                print(
                    f"  ray, {nodes} node(s) x {args.cpus // nodes} CPU: cluster start {start:.1f} s, benchmark "
                    f"{wall:.1f} s wall; Ray overhead per run median {1e3 * np.median(over):.1f} ms "
                    f"(p90 {1e3 * np.percentile(over, 90):.1f}); driver CPU {1e3 * stats.driver_cpu / stats.rows:.1f} "
                    f"ms per row; rows identical to local: {'yes' if not diff else 'NO'}"
                )
                for line in diff[:10]:
                    print(f"    differs: {line}")
            print(f"  driver writes (SQLite, one commit per row): {_write_rate(base, tmp):.0f} rows/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
