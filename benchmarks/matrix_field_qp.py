"""Benchmarks of the QP variant (``matrix-field-qp``) next to ``matrix-field``. Medians; single process.

    python benchmarks/matrix_field_qp.py step                        # per-step cost: building vs solving the QP
    python benchmarks/matrix_field_qp.py tune                        # settings grid on mbm:*/0001-0020
    python benchmarks/matrix_field_qp.py mbm "mbm:*" --json out.json # both planners on every problem

``step``: per-step medians from the planner's own diagnostics (``qp_build_time``: task terms,
QP matrices and their wrapping; ``qp_solve_time``: the backend's solve call) over a fixed number
of steps on one problem, for every installed backend, next to the matrix-field planner's whole step.

``mbm``: ``matrix-field`` and ``matrix-field-qp`` on every problem, one suite run by
``planbench.bench`` (isolated workers, every path validated by the certified check). Per
family: success, median planning time (all runs), median joint and end-effector path length and
minimum clearance (solved runs), failure reasons, median solver share of planning time; and over
ALL runs with a path (success or not) the largest joint-limit violation [rad] and velocity ratio
``|qd| / qd_max`` found by the harness.
With ``--report-from 21`` (default) the tables use problems 0021-0100 only, the violations all.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from _bench import run_suite

import planbench
from planbench_plugins.matrix_field import MatrixFieldPlanner
from planbench_plugins.matrix_field_qp import MatrixFieldQPPlanner, installed_solvers

PLANNERS = {"matrix-field": MatrixFieldPlanner, "matrix-field-qp": MatrixFieldQPPlanner}


def bench_step(problem_id: str = "mbm:box/0001", steps: int = 300) -> dict[str, dict[str, float]]:
    """Median per-step times [us] of the QP planner for every installed backend, and of matrix-field."""
    problem = planbench.load_problems(problem_id)[0]
    endless = dict(
        stall_ratio=0.0, max_steps=steps, collision_check_every=0, verify_path=False, goal_tolerance_scale=1e-9
    )
    out: dict[str, dict[str, float]] = {}
    for solver in installed_solvers():
        planner = MatrixFieldQPPlanner(solver=solver, **endless)
        planner.setup(problem)
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            r = planner.plan(problem, time_limit=600.0, rng=np.random.default_rng(0))
            runs.append(((time.perf_counter() - t0) / max(1, r.info["steps"]), r))
        per_step, r = sorted(runs, key=lambda x: x[0])[1]
        out[f"matrix-field-qp ({solver})"] = {
            "step": per_step * 1e6,
            "build": float(np.nanmedian(r.info["qp_build_time"])) * 1e6,
            "solve": float(np.nanmedian(r.info["qp_solve_time"])) * 1e6,
            "solve p95": float(np.nanpercentile(r.info["qp_solve_time"], 95)) * 1e6,
            # means add up: step (a mean) = build mean + solve mean + the rest of the loop
            "build mean": float(np.nanmean(r.info["qp_build_time"])) * 1e6,
            "solve mean": float(np.nanmean(r.info["qp_solve_time"])) * 1e6,
            "steps": float(r.info["steps"]),
        }
    mf = MatrixFieldPlanner(**endless)
    mf.setup(problem)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        r = mf.plan(problem, time_limit=600.0, rng=np.random.default_rng(0))
        times.append((time.perf_counter() - t0) / max(1, r.info["steps"]))
    out["matrix-field"] = {"step": statistics.median(times) * 1e6, "steps": float(r.info["steps"])}
    return out


def _row(r: dict[str, Any]) -> dict[str, Any]:
    """The script's row of one benchmark run (a ``ResultsDB`` row)."""
    nan = float("nan")

    def num(key: str) -> float:
        return float(r[key]) if r[key] is not None else nan

    info = json.loads(r["info"] or "{}")
    if r["success"]:
        reason = "success"
    elif r["status"] == "success":
        reason = "claimed success, invalid"
    else:
        reason = r["status"] or "?"
    return dict(
        planner=r["planner"],
        family=r["family"],
        id=r["problem"],
        number=int(r["problem"].rsplit("/", 1)[-1]),
        ok=bool(r["success"]),
        reason=reason,
        status=r["status"],
        message=(r["message"] or "")[:200],
        time=num("planning_time"),
        setup=num("setup_time"),
        qlen=num("joint_path_length"),
        eelen=num("ee_path_length"),
        clearance=num("min_clearance"),
        limit_violation=num("max_limit_violation"),
        velocity_ratio=num("max_velocity_ratio"),
        has_path=r["path"] is not None,
        steps=info.get("steps", 0),
        solver_time=info.get("solver_time", nan),
        build_time=info.get("build_time", nan),
    )


def _med(values: list[float]) -> float:
    vals = [v for v in values if np.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def summarize(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for fam in sorted({r["family"] for r in rows}) + ["all"]:
        rr = [r for r in rows if fam in ("all", r["family"])]
        ok = [r for r in rr if r["ok"]]
        out[fam] = dict(
            n=len(rr),
            success=len(ok) / len(rr),
            time_ms=1e3 * _med([r["time"] for r in rr]),
            qlen=_med([r["qlen"] for r in ok]),
            eelen=_med([r["eelen"] for r in ok]),
            clearance=_med([r["clearance"] for r in ok]),
            solver_share=_med([r["solver_time"] / r["time"] for r in rr if r["time"] > 0]),
            reasons=dict(Counter(r["reason"] for r in rr if not r["ok"])),
        )
    return out


def violations(rows: list[dict[str, Any]]) -> dict[str, float]:
    with_path = [r for r in rows if r["has_path"]]
    return dict(
        runs=len(rows),
        with_path=len(with_path),
        max_limit_violation=max((r["limit_violation"] for r in with_path), default=float("nan")),
        max_velocity_ratio=max((r["velocity_ratio"] for r in with_path), default=float("nan")),
    )


def run_mbm(
    selector: str,
    settings: dict[str, dict[str, Any]],
    planners: list[str],
    time_limit: float = 5.0,
    verbose: bool = False,
) -> list[dict[str, Any]]:
    """Every planner on every problem, run and validated by ``planbench.bench`` (benchmarks/_bench.py)."""
    entries = {name: (name, settings.get(name, {})) for name in planners}
    rows = [_row(r) for r in run_suite("matrix-field-qp", [selector], entries, time_limit=time_limit)]
    if verbose:
        for row in rows:
            print(row["id"], row["planner"], row["reason"], f"{row['time'] * 1e3:.0f} ms", flush=True)
    return rows


def print_table(rows: list[dict[str, Any]], report_from: int) -> None:
    for name in dict.fromkeys(r["planner"] for r in rows):
        mine = [r for r in rows if r["planner"] == name]
        shown = [r for r in mine if r["number"] >= report_from]
        print(f"\n{name}: problems {report_from:04d}-0100 ({len(shown)} runs)")
        print(
            f"{'family':18s} {'succ':>6s} {'t_med ms':>9s} {'q len':>6s} {'ee len':>7s} {'clear':>6s} "
            f"{'solver%':>7s}  failures"
        )
        for fam, s in summarize(shown).items() if shown else ():
            print(
                f"{fam:18s} {s['success']:6.1%} {s['time_ms']:9.1f} {s['qlen']:6.2f} {s['eelen']:7.2f} "
                f"{s['clearance']:6.3f} {s['solver_share']:7.0%}  {s['reasons']}"
            )
        print(f"over all {len(mine)} runs:", json.dumps(violations(mine)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    st = sub.add_parser("step")
    st.add_argument("--problem", default="mbm:box/0001")
    m = sub.add_parser("mbm")
    m.add_argument("selector", nargs="?", default="mbm:*")
    m.add_argument("--planners", default="matrix-field,matrix-field-qp")
    m.add_argument("--config", default="{}", help="JSON object of MatrixFieldQPConfig settings")
    m.add_argument("--report-from", type=int, default=21, help="tables over problems numbered from this one")
    m.add_argument("--json", help="write every row to this file")
    m.add_argument("-v", action="store_true")
    tu = sub.add_parser("tune")
    tu.add_argument("--selector", default="mbm:*/0001-0020")
    tu.add_argument(
        "--grid",
        default='[{"solver": "daqp"}, {"solver": "daqp", "velocity_dampers": true}]',
        help="JSON list of MatrixFieldQPConfig settings to compare",
    )
    args = ap.parse_args(argv)
    if args.cmd == "step":
        for label, res in bench_step(args.problem).items():
            parts = (f"{k} {v:8.1f}" + ("" if k == "steps" else " us") for k, v in res.items())
            print(f"{label:30s} " + "  ".join(parts))
    elif args.cmd == "mbm":
        t0 = time.perf_counter()
        rows = run_mbm(
            args.selector, {"matrix-field-qp": json.loads(args.config)}, args.planners.split(","), verbose=args.v
        )
        print_table(rows, args.report_from)
        print(f"wall time {time.perf_counter() - t0:.0f} s")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(rows, fh, indent=0, default=float)
    else:
        for cfg in json.loads(args.grid):
            t0 = time.perf_counter()
            rows = run_mbm(args.selector, {"matrix-field-qp": cfg}, ["matrix-field-qp"])
            s = summarize(rows)
            per = " ".join(f"{f[:10]}={v['success']:.0%}" for f, v in s.items() if f != "all")
            print(
                json.dumps(cfg),
                f"success {s['all']['success']:.1%} t_med {s['all']['time_ms']:.0f} ms",
                per,
                json.dumps(violations(rows)),
                json.dumps(s["all"]["reasons"]),
                f"({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
