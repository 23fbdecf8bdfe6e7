"""Per planner and problem family: success with its 95 % interval, failure reasons, medians; and
for ``matrix-field-guided`` the clearance it gains over its global planner on the same problems.

    python benchmarks/summary.py results.db                      # every planner label in the file
    python benchmarks/summary.py results.db --baseline ompl-rrtconnect --guided matrix-field-guided
    python benchmarks/summary.py issue17.db tr.db --all-only     # several files, one row per planner and set

Reads a results file written by ``planbench bench`` (e.g. with a suite of ``benchmarks/suites/``)
and prints Markdown tables. Failure reasons: the harness's verdict (a collision names the robot
link, ``self`` when both bodies are the robot's), else the planner's status (local minimum, step
or time limit, infeasible step).
"""

from __future__ import annotations

import argparse
import collections
import json
import statistics
from collections.abc import Sequence
from typing import Any

from scipy.stats import binomtest

from planbench.bench.db import ResultsDB


def interval(k: int, n: int) -> str:
    """``k/n (p %, [lo, hi])``: Clopper-Pearson 95 % interval."""
    if n == 0:
        return "-"
    ci = binomtest(k, n).proportion_ci(0.95, method="exact")
    return f"{k}/{n} ({100 * k / n:.0f} %, [{100 * ci.low:.0f}, {100 * ci.high:.0f}])"


def reason(row: dict[str, Any]) -> str:
    if row["collision_pair"]:  # "link / obstacle:name" or "link / link"
        a, _, b = str(row["collision_pair"]).partition(" / ")
        return f"collision {a}" if b.startswith("obstacle:") else f"self {a}/{b}"
    return str(row["status"]).replace("_", " ")


def median(values: Sequence[float | None], scale: float = 1.0) -> str:
    present = [v for v in values if v is not None]
    return f"{statistics.median(present) * scale:.1f}" if present else "-"


def problem_set(problem: str) -> str:
    """``mbm``, or ``gen:<robot>`` for the generated sets."""
    family = problem.split("/")[0]
    return "mbm" if family.startswith("mbm:") else family.rsplit("_", 1)[0].split("_")[0]


def table(rows: list[dict[str, Any]], by_set: bool = False) -> None:
    """One row per planner and family (and ``all``), or per planner and problem set (``by_set``)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = collections.defaultdict(list)
    for r in rows:
        if by_set:
            groups[(r["planner"], problem_set(r["problem"]))].append(r)
            continue
        family = r["problem"].split("/")[0].removeprefix("mbm:")  # gen: sets keep their robot
        groups[(r["planner"], family)].append(r)
        groups[(r["planner"], "all")].append(r)
    print("| planner | family | solved (95 % interval) | planning [ms] | min clearance [mm] | failures |")
    print("| --- | --- | --- | --- | --- | --- |")
    for (planner, family), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1] == "all", kv[0][1])):
        ok = [r for r in rs if r["success"]]
        fails = collections.Counter(reason(r) for r in rs if not r["success"])
        text = ", ".join(f"{k} {v}" for k, v in fails.most_common(4))
        t_ms = median([r["planning_time"] for r in ok], 1000)
        clearance_mm = median([r["min_clearance"] for r in ok], 1000)
        print(f"| {planner} | {family} | {interval(len(ok), len(rs))} | {t_ms} | {clearance_mm} | {text} |")


def guided(rows: list[dict[str, Any]], baseline: str, label: str) -> None:
    base = {(r["problem"], r["seed"]): r for r in rows if r["planner"] == baseline}
    matched = [(r, base.get((r["problem"], r["seed"]))) for r in rows if r["planner"] == label]
    pairs = [(g, b) for g, b in matched if b is not None and g["success"] and b["success"]]
    if not pairs:
        return
    info = [json.loads(g["info"]) if isinstance(g["info"], str) else (g["info"] or {}) for g, _ in pairs]
    fallback = collections.Counter(str(i.get("fallback")) for i in info)
    gained = [g["min_clearance"] - b["min_clearance"] for g, b in pairs]
    ratio = [g["planning_time"] / b["planning_time"] for g, b in pairs]
    print(f"\n{label} against {baseline}, {len(pairs)} problems both solved:")
    print(
        f"- median min clearance: {median([g['min_clearance'] for g, _ in pairs], 1000)} mm against "
        f"{median([b['min_clearance'] for _, b in pairs], 1000)} mm; gained per problem: median "
        f"{median(gained, 1000)} mm, {sum(x > 0 for x in gained)} larger, {sum(x < 0 for x in gained)} smaller"
    )
    print(
        f"- median planning time: {median([g['planning_time'] for g, _ in pairs], 1000)} ms against "
        f"{median([b['planning_time'] for _, b in pairs], 1000)} ms (median ratio per problem {median(ratio)})"
    )
    print(f"- returned: {dict(fallback)} (None: the tracked path)")
    dep = [i.get("departure_max") for i in info if i.get("fallback") is None]
    print(f"- departure from the global path (tracked paths): median of the largest {median(dep)} rad")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("db", nargs="+", help="results files (their rows are read together)")
    parser.add_argument("--all-only", action="store_true", help="one row per planner and problem set")
    parser.add_argument("--baseline", default="ompl-rrtconnect")
    parser.add_argument("--guided", default="matrix-field-guided")
    args = parser.parse_args(argv)
    rows = []
    for path in args.db:
        with ResultsDB(path, create=False, read_only=True) as db:
            rows += db.rows()
    table(rows, by_set=args.all_only)
    guided(rows, args.baseline, args.guided)


if __name__ == "__main__":
    main()
