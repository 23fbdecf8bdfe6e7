"""VAMP against planbench's verdict: a results file of ``planbench bench`` summarised per planner,
with what VAMP claimed beside what planbench's certified check accepted.

Usage::

    planbench bench --planners vamp-rrtc,ompl-rrtconnect --problems "mbm:*" --jobs 1 --out mbm.db
    python benchmarks/vamp_baseline.py mbm.db [--baseline ompl-rrtconnect] [--by family] [--model-check]

Printed, as a Markdown table, per planner (and family with ``--by family``): runs; validated
successes (planbench's verdict); claimed successes (the planner's own status); *refused*: claimed
successes planbench does not accept, split into a collision with the true geometry (with the
deepest penetration found) and other reasons (joint limits ...); among the refused, how many paths
VAMP's own check of the returned path calls free (``info["vamp_verdict"]``); the median planning
time over validated successes and its ratio to the baseline's median from the same file; the
median of the per-problem ratios where both solved; the median joint path length and minimum
clearance over validated successes. Needs pandas (``planbench[data]``).

``--model-check`` (needs the VAMP extra): for every refused VAMP path with a collision, VAMP's own
configuration check at the configuration where planbench found the contact (the segment and
fraction the results file holds): free there means VAMP's robot model misses the contact, not the
spacing of its motion checks.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

import planbench.bench.results as results


def _median(values: Any) -> float:
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    return float(np.median(a)) if a.size else math.nan


def _cell(v: float, fmt: str) -> str:
    return "-" if not math.isfinite(v) else format(v, fmt)


def summary(df: Any, baseline: str, by: str) -> list[dict[str, Any]]:
    """One dict per planner (and ``by`` group) of the columns described in the module docstring."""
    base = df[(df.planner == baseline) & df.success]
    base_time = base.groupby("problem").planning_time.min()
    rows = []
    keys = ["planner"] if by == "planner" else ["planner", by]
    for key, g in df.groupby(keys, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        ok = g[g.success]
        claimed = g[g.status == "success"]
        refused = claimed[~claimed.success]
        hit = refused[refused.collision_pair.fillna("") != ""]
        verdicts = [i.get("vamp_verdict") if isinstance(i, dict) else None for i in refused["info"]]
        same = base_time.reindex(ok.problem)
        ratio = (ok.planning_time.to_numpy() / same.to_numpy()) if len(ok) else np.array([])
        base_in_group = base[base.problem.isin(g.problem)]
        rows.append(
            {
                **dict(zip(keys, key, strict=True)),
                "runs": len(g),
                "validated": len(ok),
                "claimed": len(claimed),
                "refused": len(refused),
                "refused_collision": len(hit),
                "deepest_mm": float(hit.penetration_depth.max() * 1e3) if len(hit) else math.nan,
                "refused_vamp_free": sum(v == "free" for v in verdicts),
                "has_verdict": any(v is not None for v in verdicts) or "vamp" in str(key[0]),
                "time_ms": _median(ok.planning_time) * 1e3,
                "time_ratio": _median(ok.planning_time) / _median(base_in_group.planning_time),
                "paired_ratio": _median(ratio),
                "length": _median(ok.joint_path_length),
                "clearance_mm": _median(ok.min_clearance) * 1e3,
            }
        )
    return rows


def markdown(rows: list[dict[str, Any]], baseline: str, by: str) -> str:
    head = ["planner"] + ([by] if by != "planner" else [])
    head += [
        "validated",
        "claimed",
        "refused (collision, deepest)",
        "refused that VAMP's check calls free",
        "time [ms]",
        f"time / {baseline}",
        "per-problem ratio",
        "length [rad]",
        "clearance [mm]",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        refused = (
            f"{r['refused']} ({r['refused_collision']}, {_cell(r['deepest_mm'], '.2f')} mm)" if r["refused"] else "0"
        )
        cells = [r["planner"]] + ([str(r[by])] if by != "planner" else [])
        cells += [
            f"{r['validated']}/{r['runs']}",
            str(r["claimed"]),
            refused,
            str(r["refused_vamp_free"]) if r["has_verdict"] else "-",
            _cell(r["time_ms"], ".3g"),
            _cell(r["time_ratio"], ".3g"),
            _cell(r["paired_ratio"], ".3g"),
            _cell(r["length"], ".2f"),
            _cell(r["clearance_mm"], ".2f"),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def model_check(df: Any) -> dict[bool, int]:
    """VAMP's configuration check at each refused VAMP path's contact: {free: count}."""
    import planbench
    from planbench_plugins.vamp_planners import environment, vamp_robot

    hit = df[
        df.planner.str.startswith("vamp")
        & (df.status == "success")
        & ~df.success
        & (df.collision_pair.fillna("") != "")
    ]
    counts = {True: 0, False: 0}
    for _, r in hit.iterrows():
        problem = planbench.load_problems(r.problem)[0]
        robot = vamp_robot(problem.robot)
        env, _ = environment(
            problem.scene, robot, **{k: v for k, v in r.planner_config.items() if k in ("cylinders", "mesh_spacing")}
        )
        k, f = int(r.collision_segment), float(r.collision_fraction)
        q = r.path[k] + f * (r.path[k + 1] - r.path[k])
        counts[bool(robot.module.validate(q.astype(np.float32), env))] += 1
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="a results file of planbench bench")
    parser.add_argument("--baseline", default="ompl-rrtconnect", help="the planner the times are divided by")
    parser.add_argument("--by", default="planner", choices=["planner", "family"])
    parser.add_argument(
        "--model-check", action="store_true", help="VAMP's own check where planbench found each contact"
    )
    args = parser.parse_args()
    df = results.load(args.results, paths=args.model_check)
    print(markdown(summary(df, args.baseline, args.by), args.baseline, args.by))
    if args.model_check:
        counts = model_check(df)
        print(
            f"\nrefused VAMP paths with a collision: VAMP's model is free at the contact in {counts[True]}, "
            f"in collision in {counts[False]}"
        )


if __name__ == "__main__":
    main()
