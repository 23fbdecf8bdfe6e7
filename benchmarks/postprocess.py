"""The post-processing stage (planbench.bench.postprocess) measured on a results file.

Usage::

    python benchmarks/postprocess.py table RESULTS.db [--suite NAME] [--baseline ompl-rrtconnect]
    python benchmarks/postprocess.py sweep RESULTS.db [--suite NAME] [--attempts 0,50,100,200,400]
    python benchmarks/postprocess.py precheck RESULTS.db [--suite NAME] [--resolutions 0,0.05]

``table``: per planner, validated successes, the median joint path length raw and processed, each
as a ratio to the baseline's median with the same stage, the medians over the problems every
planner solved (paired), and the median planning and post-processing times. A file written with
``postprocess = "shortcut"`` holds both stages of every run (raw: ``none``; processed: ``shortcut``).

``sweep``: the runs' stored raw paths shortcut again, here, once with the largest ``attempts``
count (the seed of each run, the stage's checker with default validation settings); its trace
gives what each smaller count would have (the same draws): the median processed length and
shortcutting time per planner and count, to choose the default on a tuning part.
Only the shortcut is redone (its segments are certified by construction), not the re-validation.

``precheck``: the same paths shortcut with and without the sampled pre-check (``--resolutions``,
[rad], 0: none), interleaved: the time ratio, and whether the processed paths are identical.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Sequence
from typing import Any

from planbench.bench.db import ResultsDB
from planbench.bench.postprocess import PostprocessSettings, segment_checker, shortcut
from planbench.problems.datasets import load_problem
from planbench.validate import ValidationSettings


def _median(values: Sequence[float]) -> float:
    kept = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(kept) if kept else math.nan


def _rows(path: str, suite: str | None, arrays: bool = False) -> list[dict[str, Any]]:
    with ResultsDB(path, read_only=True) as db:
        return db.rows(suite, with_arrays=arrays)


def table(path: str, suite: str | None, baseline: str) -> None:
    rows = _rows(path, suite)
    planners = sorted({r["planner"] for r in rows})
    solved = {p: {r["problem"]: r for r in rows if r["planner"] == p and r["success"]} for p in planners}
    common = set.intersection(*(set(s) for s in solved.values())) if solved else set()
    base = solved.get(baseline, {})
    base_raw = _median([r["joint_path_length"] for r in base.values()])
    base_pp = _median([r["processed_joint_path_length"] for r in base.values()])
    base_raw_c = _median([base[k]["joint_path_length"] for k in common]) if base else math.nan
    base_pp_c = _median([base[k]["processed_joint_path_length"] for k in common]) if base else math.nan
    print(f"{len({r['problem'] for r in rows})} problems, {len(common)} solved by every planner; baseline {baseline}")
    head = (
        "| planner | solved | joint len raw [rad] | ratio | processed [rad] | ratio | paired raw ratio | "
        "paired processed ratio | planning time [ms] | post-processing [ms] | processed timed [s] |"
    )
    print(head)
    print("|" + "---|" * head.count(" | ") + "---|")
    for p in planners:
        mine = solved[p]
        raw = _median([r["joint_path_length"] for r in mine.values()])
        pp = _median([r["processed_joint_path_length"] for r in mine.values()])
        raw_c = _median([mine[k]["joint_path_length"] for k in common])
        pp_c = _median([mine[k]["processed_joint_path_length"] for k in common])
        plan = _median([r["planning_time"] for r in mine.values()])
        post = _median([r["postprocess_time"] for r in mine.values()])
        timed = _median([r["processed_duration_limited"] for r in mine.values()])
        n = sum(1 for r in rows if r["planner"] == p)
        print(
            f"| {p} | {len(mine)}/{n} | {raw:.2f} | {raw / base_raw:.2f} | {pp:.2f} | {pp / base_pp:.2f} | "
            f"{raw_c / base_raw_c:.2f} | {pp_c / base_pp_c:.2f} | {1e3 * plan:.0f} | {1e3 * post:.0f} | {timed:.2f} |"
        )


def sweep(path: str, suite: str | None, attempts: Sequence[int], stage: dict[str, Any]) -> None:
    rows = [r for r in _rows(path, suite, arrays=True) if r["success"] and r["path"] is not None]
    validation = ValidationSettings()
    out: dict[tuple[str, int], list[tuple[float, float]]] = {}
    for r in rows:
        problem = load_problem(r["problem"])
        settings = PostprocessSettings(method="shortcut", attempts=max(attempts), time_budget=1e6, **stage)
        done = shortcut(r["path"], segment_checker(problem, validation, settings), settings, int(r["seed"]))
        raw = (0.0, float(sum(math.dist(a, b) for a, b in zip(r["path"][:-1], r["path"][1:], strict=True))))
        for n in attempts:  # the first n tries are those of a run with n attempts
            spent, length = done.trace[min(n, len(done.trace)) - 1] if n and done.trace else raw
            out.setdefault((r["planner"], n), []).append((length, spent))
    print("| planner | attempts | runs | median processed joint len [rad] | median shortcut time [ms] |")
    print("|---|---|---|---|---|")
    for (planner, n), values in sorted(out.items()):
        lengths, times = zip(*values, strict=True)
        print(f"| {planner} | {n} | {len(values)} | {_median(lengths):.3f} | {1e3 * _median(times):.0f} |")


def precheck(path: str, suite: str | None, resolutions: Sequence[float]) -> None:
    """Each stored path shortcut with every pre-check resolution in turn (the order rotated from
    path to path, so that a busy machine slows all alike): the time ratio against the first, and
    whether the processed paths are the same."""
    rows = [r for r in _rows(path, suite, arrays=True) if r["success"] and r["path"] is not None]
    validation = ValidationSettings()
    times: dict[float, list[float]] = {x: [] for x in resolutions}
    same = 0
    for k, r in enumerate(rows):
        problem = load_problem(r["problem"])
        paths = {}
        order = list(resolutions[k % len(resolutions) :]) + list(resolutions[: k % len(resolutions)])
        for x in order:
            settings = PostprocessSettings(method="shortcut", precheck_resolution=x, time_budget=1e6)
            t0 = time.perf_counter()
            done = shortcut(r["path"], segment_checker(problem, validation, settings), settings, int(r["seed"]))
            times[x].append(time.perf_counter() - t0)
            paths[x] = done.path
        first = paths[resolutions[0]]
        same += all(p.shape == first.shape and bool((p == first).all()) for p in paths.values())
    base = times[resolutions[0]]
    print(f"{len(rows)} paths; the same processed path with every resolution: {same}")
    print("| precheck_resolution [rad] | total shortcut time [s] | median [ms] | median ratio to the first |")
    print("|---|---|---|---|")
    for x in resolutions:
        ratio = _median([a / b for a, b in zip(times[x], base, strict=True) if b > 0])
        print(f"| {x:g} | {sum(times[x]):.1f} | {1e3 * _median(times[x]):.0f} | {ratio:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("table")
    t.add_argument("db")
    t.add_argument("--suite")
    t.add_argument("--baseline", default="ompl-rrtconnect")
    s = sub.add_parser("sweep")
    s.add_argument("db")
    s.add_argument("--suite")
    s.add_argument("--attempts", default="0,50,100,200,400")
    s.add_argument("--precheck-resolution", type=float, default=PostprocessSettings.precheck_resolution)
    c = sub.add_parser("precheck")
    c.add_argument("db")
    c.add_argument("--suite")
    c.add_argument("--resolutions", default="0,0.05")
    args = parser.parse_args()
    if args.command == "table":
        table(args.db, args.suite, args.baseline)
    elif args.command == "precheck":
        precheck(args.db, args.suite, [float(x) for x in args.resolutions.split(",")])
    else:
        stage = {"precheck_resolution": args.precheck_resolution}
        sweep(args.db, args.suite, [int(x) for x in args.attempts.split(",")], stage)


if __name__ == "__main__":
    main()
