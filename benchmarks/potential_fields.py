"""Benchmarks of the potential-field baselines next to the matrix field (issue 6). Medians; one
process (run it on a quiet machine for timings; ratios come from the same run).

    python benchmarks/potential_fields.py step                      # per-step repulsion cost
    python benchmarks/potential_fields.py sweep                     # stand-off sweep on mbm:*/0001-0020
    python benchmarks/potential_fields.py mbm "mbm:*" --planners edt-field,distance-field --jsonl rows.jsonl --out pf.db
    python benchmarks/potential_fields.py summary rows.jsonl        # the tables of a (partial) run

``step``: the cost of one repulsion query ``forces(kin)`` (after ``kin.update(q)``, untimed) of
``matrix-field``, ``edt-field`` and ``distance-field`` at the configurations of matrix-field
trajectories on a few MotionBenchMaker problems (arms near and far from obstacles), the median
over configurations of per-configuration medians; plus the whole loop step (planning time per
step with no stopping and no collision checks), and the coal pairs left after culling.

``mbm``: every planner on every problem with the same time limit, run by ``planbench.bench``
(isolated workers, certified validation; ``--out`` keeps the results file and resumes); per
family: success (count), median planning and setup time over all runs, median joint and
end-effector path length and minimum clearance over successes, failure reasons.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import Counter
from collections.abc import Mapping
from typing import Any

import numpy as np
from _bench import run_suite

import planbench
from planbench.planner import Planner
from planbench_plugins.ik_loop import ArmKinematics
from planbench_plugins.matrix_field import MatrixFieldPlanner
from planbench_plugins.potential_fields import DistanceFieldPlanner, EDTFieldPlanner

PLANNERS = {"matrix-field": MatrixFieldPlanner, "edt-field": EDTFieldPlanner, "distance-field": DistanceFieldPlanner}
STEP_PROBLEMS = ("mbm:box/0001", "mbm:bookshelf_small/0001", "mbm:cage/0001", "mbm:table_pick/0001")


def _median_us(fn: Any, reps: int = 200, batches: int = 5) -> float:
    out = []
    for _ in range(batches):
        t0 = time.perf_counter()
        for _ in range(reps):
            fn()
        out.append((time.perf_counter() - t0) / reps * 1e6)
    return statistics.median(out)


def bench_step(problem_ids: tuple[str, ...] = STEP_PROBLEMS, n_configs: int = 8) -> dict[str, dict[str, float]]:
    """Per planner: median repulsion query [us], median whole step [us], mean coal pairs (distance)."""
    out: dict[str, dict[str, list[float]]] = {name: {"repulsion": [], "step": [], "pairs": []} for name in PLANNERS}
    for pid in problem_ids:
        problem = planbench.load_problems(pid)[0]
        ref = planbench.plan(problem, MatrixFieldPlanner, time_limit=5.0)
        assert ref.path is not None, ref.message
        idx = np.linspace(0, len(ref.path) - 1, n_configs).astype(int)
        for name, cls in PLANNERS.items():
            planner = cls(
                stall_ratio=0.0, max_steps=500, collision_check_every=0, verify_path=False, goal_tolerance_scale=1e-9
            )
            planner.setup(problem)
            rep = planner.stepper.repulsion
            kin = ArmKinematics(
                problem.robot,
                problem.robot.frame_id(problem.goal.pose.frame),
                planner.stepper.control_points,
                compiled=planner.use_numba,
            )
            for q in ref.path[idx]:
                kin.update(q)
                out[name]["repulsion"].append(_median_us(lambda rep=rep, kin=kin: rep.forces(kin)))
                out[name]["pairs"].append(float(getattr(rep, "n_pairs_checked", 0)))
            t0 = time.perf_counter()
            r = planner.plan(problem, time_limit=60.0, rng=np.random.default_rng(0))
            out[name]["step"].append((time.perf_counter() - t0) / max(1, r.info["steps"]) * 1e6)
    return {
        name: {k: statistics.median(v) if k != "pairs" else float(np.mean(v)) for k, v in d.items()}
        for name, d in out.items()
    }


def _reason(result: Any, ev: Any) -> str:
    if ev.success:
        return "success"
    if result.status is planbench.PlanStatus.SUCCESS:
        return "claimed success, invalid: " + ev.failure.split(":")[0][:30]
    return result.status.value


def run_mbm(
    selector: str,
    planners: Mapping[str, tuple[type[Planner], Mapping[str, Any]]],
    time_limit: float = 5.0,
    verbose: bool = False,
    jsonl: str | None = None,
    out: str | None = None,
) -> list[dict[str, Any]]:
    """One row per (problem, planner label), run and validated by ``planbench.bench``
    (benchmarks/_bench.py). ``out``: the results file (runs already in it are not run again);
    ``jsonl``: the rows are also written to this file."""
    entries = {label: (cls.name, settings) for label, (cls, settings) in planners.items()}
    bench_rows = run_suite("potential-fields", [selector], entries, time_limit=time_limit, out=out, resume=bool(out))
    rows: list[dict[str, Any]] = []
    for r in bench_rows:
        info = json.loads(r["info"] or "{}")
        reason = "success" if r["success"] else (r["failure"] or r["status"] or "?").split(":")[0][:40]
        rows.append(
            dict(
                planner=r["planner"],
                family=r["family"],
                id=r["problem"],
                ok=bool(r["success"]),
                reason=reason,
                time=r["planning_time"],
                setup=r["setup_time"],
                qlen=r["joint_path_length"],
                eelen=r["ee_path_length"],
                clearance=r["min_clearance"],
                steps=info.get("steps", 0),
            )
        )
        if verbose:
            print(r["problem"], r["planner"], reason, flush=True)
    if jsonl:
        with open(jsonl, "w") as fh:
            fh.writelines(json.dumps(row, default=float) + "\n" for row in rows)
    return rows


def _med(values: list[float]) -> float:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def summarize(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """``{planner: {family or "all": statistics}}``."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for label in dict.fromkeys(r["planner"] for r in rows):
        mine = [r for r in rows if r["planner"] == label]
        out[label] = {}
        for fam in sorted({r["family"] for r in mine}) + ["all"]:
            rr = [r for r in mine if fam in ("all", r["family"])]
            ok = [r for r in rr if r["ok"]]
            out[label][fam] = dict(
                n=len(rr),
                solved=len(ok),
                success=len(ok) / len(rr),
                time_ms=1e3 * _med([r["time"] for r in rr]),
                setup_ms=1e3 * _med([r["setup"] for r in rr]),
                qlen=_med([r["qlen"] for r in ok]),
                eelen=_med([r["eelen"] for r in ok]),
                clearance=_med([r["clearance"] for r in ok]),
                reasons=dict(Counter(r["reason"] for r in rr if not r["ok"]).most_common()),
            )
    return out


def print_summary(summary: dict[str, dict[str, dict[str, Any]]]) -> None:
    """Markdown tables, one per planner."""
    for label, fams in summary.items():
        print(f"\n{label}\n")
        print(
            "| family | success | planning ms | setup ms | joint length rad | EE length m | min clearance m "
            "| failures |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- | --- |")
        for fam, s in fams.items():
            reasons = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in s["reasons"].items()) or "-"
            qlen, eelen, clear = (
                f"{v:.{n}f}" if np.isfinite(v) else "-"
                for v, n in ((s["qlen"], 2), (s["eelen"], 2), (s["clearance"], 3))
            )
            print(
                f"| {fam} | {s['success']:.0%} ({s['solved']}/{s['n']}) | {s['time_ms']:.1f} | {s['setup_ms']:.0f} | "
                f"{qlen} | {eelen} | {clear} | {reasons} |"
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("step")
    m = sub.add_parser("mbm")
    m.add_argument("selector", nargs="?", default="mbm:*")
    m.add_argument("--planners", default="matrix-field,edt-field,distance-field")
    m.add_argument(
        "--config", default="{}", help='JSON {planner: {setting: value}}, e.g. {"edt-field": {"standoff": 0.1}}'
    )
    m.add_argument("--time-limit", type=float, default=5.0)
    m.add_argument("--json", help="write the rows and summary to this file")
    m.add_argument("--jsonl", help="write the rows here (for summary)")
    m.add_argument("--out", help="keep the results file here; runs already in it are not run again (resume)")
    m.add_argument("-v", action="store_true")
    su = sub.add_parser("summary", help="the tables of an mbm or sweep --jsonl file")
    su.add_argument("jsonl")
    sw = sub.add_parser("sweep")
    sw.add_argument("--selector", default="mbm:*/0001-0020")
    sw.add_argument("--jsonl", help="write the rows here (for summary)")
    sw.add_argument("--out", help="keep the results file here; runs already in it are not run again (resume)")
    sw.add_argument(
        "--grid",
        default='{"edt-field": [0.07, 0.1, 0.12], "distance-field": [0.03, 0.05, 0.1]}',
        help="JSON {planner: [standoff, ...]}",
    )
    args = ap.parse_args(argv)
    if args.cmd == "step":
        res = bench_step()
        print("| planner | repulsion query us | whole step us | coal pairs after culling |")
        print("| --- | --- | --- | --- |")
        for name, s in res.items():
            print(f"| {name} | {s['repulsion']:.1f} | {s['step']:.1f} | {s['pairs']:.1f} |")
    elif args.cmd == "summary":
        with open(args.jsonl) as fh:
            print_summary(summarize([json.loads(line) for line in fh if line.strip()]))
    elif args.cmd == "mbm":
        config = json.loads(args.config)
        planners = {name: (PLANNERS[name], config.get(name, {})) for name in args.planners.split(",")}
        t0 = time.perf_counter()
        rows = run_mbm(args.selector, planners, args.time_limit, verbose=args.v, jsonl=args.jsonl, out=args.out)
        summary = summarize(rows)
        print_summary(summary)
        print(f"\nwall time {time.perf_counter() - t0:.0f} s")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump({"rows": rows, "summary": summary}, fh, indent=1, default=float)
    else:
        grid = json.loads(args.grid)
        planners = {
            f"{name}-standoff-{s}": (PLANNERS[name], {"standoff": s}) for name, values in grid.items() for s in values
        }
        sweep = summarize(run_mbm(args.selector, planners, jsonl=args.jsonl, out=args.out))
        fams = [f for f in next(iter(sweep.values())) if f != "all"]
        print("| planner | success | " + " | ".join(fams) + " |")
        print("| --- | --- | " + " | ".join("---" for _ in fams) + " |")
        for label, stats in sweep.items():
            per = " | ".join(f"{stats[f]['success']:.0%}" for f in fams)
            print(f"| {label} | {stats['all']['success']:.1%} | {per} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
