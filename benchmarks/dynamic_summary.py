"""Tables of a closed-loop results file: success per controller by robot, speed, sensing and
behaviour (95 % Wilson intervals), failure reasons, compute times and the hand-off; or, with
``--loaded``, how many verdicts of a run beside other load differ from a quiet run's.

    planbench bench --suite dynamic --out dynamic.db --jobs 2
    python benchmarks/dynamic_summary.py dynamic.db            # Markdown, as in docs/reactive.md
    python benchmarks/dynamic_summary.py dynamic.db --loaded loaded.db
    python benchmarks/dynamic_summary.py dynamic-test.db --sensing depth --common
    python benchmarks/dynamic_summary.py seed0.db seed1.db --truth-gap   # depth against truth, paired

``--truth-gap`` pairs each depth run with the truth run of the same scenario and seed (runs of
several seeds pool: ``planbench bench ... --seeds 0-2``) and gives the gap in points with a 95 %
interval that resamples scenarios, each with all of its seeds.

Keys come from the shipped scenario names (``dynamic:<robot>_<behaviour>_<speed>_<sensing>/N``).
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from planbench.bench.closed_loop_plots import scenario_keys
from planbench.bench.db import ResultsDB
from planbench.errors import PlanbenchError
from planbench.metrics import wilson_interval
from planbench.reactive.sets import load_scenario

ORDER = {"slow": 0, "medium": 1, "fast": 2, "truth": 0, "depth": 1}


def rate(rows: Sequence[dict[str, Any]]) -> str:
    return _rate(sum(1 for r in rows if r["success"]), len(rows))


def _rate(k: int, n: int) -> str:
    """``k`` successes of ``n`` as a percentage with its 95 % Wilson interval."""
    if not n:
        return "-"
    lo, hi = wilson_interval(k, n)
    return f"{100 * k / n:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] ({k}/{n})"


def by(rows: Sequence[dict[str, Any]], key: str) -> str:
    controllers = sorted({r["planner"] for r in rows})
    values = sorted({scenario_keys(r["problem"]).get(key, "?") for r in rows}, key=lambda v: (ORDER.get(v, 9), v))
    lines = [f"| controller | {' | '.join(values)} | all |", "|---" * (len(values) + 2) + "|"]
    for c in controllers:
        mine = [r for r in rows if r["planner"] == c]
        cells = [rate([r for r in mine if scenario_keys(r["problem"]).get(key) == v]) for v in values]
        lines.append(f"| `{c}` | {' | '.join(cells)} | {rate(mine)} |")
    return "\n".join(lines)


def reasons(rows: Sequence[dict[str, Any]]) -> str:
    lines = ["| controller | failures |", "|---|---|"]
    for c in sorted({r["planner"] for r in rows}):
        counts: collections.Counter[str] = collections.Counter()
        for r in rows:
            if r["planner"] == c and not r["success"]:
                f = r["failure"] or r["status"]
                if f.startswith("collision with "):
                    what = f.removeprefix("collision with ").split(" at t")[0]
                    obstacle, _, link = what.partition(" (")
                    moving = obstacle.removeprefix("obstacle:") in moving_names(r["problem"])
                    if not obstacle.startswith("obstacle:"):  # a link of the robot: "<link> (<link>)"
                        f = "collision of the arm with itself"
                    else:
                        f = "collision with the moving obstacle" if moving else "collision with the static scene"
                    if r.get("collision_observed") is not None and not r["collision_observed"]:
                        f += ", never observed"
                    elif (r["failure"] or "").endswith(", in unobserved space"):  # hit where no frame showed it
                        f += ", in unobserved space"
                elif f.startswith("goal not reached"):
                    f = "goal not reached in the horizon"
                elif f.startswith("error"):
                    f = "error"
                counts[f] += 1
        lines.append(f"| `{c}` | {', '.join(f'{n} {k}' for k, n in counts.most_common()) or '-'} |")
    return "\n".join(lines)


@functools.cache
def moving_names(scenario: str) -> frozenset[str]:
    """The moving obstacles of a shipped scenario (by its name), or of a scenario file."""
    try:
        return frozenset(m.name for m in load_scenario(scenario).moving)
    except PlanbenchError:
        return frozenset()


def compute(rows: Sequence[dict[str, Any]]) -> str:
    lines = [
        "| controller | tick median [ms] | tick p99 [ms] | field update per frame [ms] | deadline misses per run | "
        "unobserved motion [s] | time to goal [s] | certificate's time to goal [s] | min clearance [mm] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def med(values: list[float | None], scale: float = 1.0) -> str:
        a = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
        return f"{np.median(a) * scale:.3g}" if a.size else "-"

    for c in sorted({r["planner"] for r in rows}):
        mine = [r for r in rows if r["planner"] == c]
        ok = [r for r in mine if r["success"]]
        ticks = f"{med([r['tick_time_median'] for r in mine], 1e3)} | {med([r['tick_time_p99'] for r in mine], 1e3)}"
        lines.append(
            f"| `{c}` | {ticks} "
            f"| {med([r['field_update_time'] for r in mine], 1e3)} | {med([r['deadline_misses'] for r in mine])} "
            f"| {med([r.get('unobserved_motion') for r in mine])} | {med([r['time_to_goal'] for r in ok])} "
            f"| {med([certificate_time(r['problem']) for r in ok])} | {med([r['min_clearance'] for r in ok], 1e3)} |"
        )
    return "\n".join(lines)


@functools.cache
def certificate_time(scenario: str) -> float | None:
    """[s] the time to goal of the scenario's solvability certificate (the omniscient planner's), or
    None: the column beside a controller's time to goal, over the scenarios it solved."""
    try:
        cert = load_scenario(scenario).certificate
    except PlanbenchError:
        return None
    return None if cert is None else cert.time_to_goal


def handoff(rows: Sequence[dict[str, Any]]) -> str:
    """Per controller, medians over runs of each run's hand-off median and p99 (the wall-clock round
    trip of a call less the CPU time charged for it, measured by the simulation)."""
    lines = ["| controller | hand-off median [µs] | hand-off p99 [µs] | calls per run |", "|---|---|---|---|"]
    for c in sorted({r["planner"] for r in rows}):
        infos = [json.loads(r["info"]) if isinstance(r["info"], str) else r["info"] for r in rows if r["planner"] == c]
        got = [i for i in infos if isinstance(i, dict) and i.get("handoff_median") is not None]
        if not got:
            continue
        m = np.median([i["handoff_median"] for i in got]) * 1e6
        p = np.median([i["handoff_p99"] for i in got]) * 1e6
        n = np.median([i["handoff_calls"] for i in got])
        lines.append(f"| `{c}` | {m:.0f} | {p:.0f} | {n:.0f} |")
    return "\n".join(lines)


def compare(quiet: Sequence[dict[str, Any]], loaded: Sequence[dict[str, Any]]) -> str:
    """Per controller, the runs of ``loaded`` whose verdict differs from the same scenario's in
    ``quiet`` (matched by scenario and controller)."""
    before = {(r["problem"], r["planner"]): bool(r["success"]) for r in quiet}
    lines = [
        "| controller | runs compared | success quiet | success loaded | verdicts that differ |",
        "|---|---|---|---|---|",
    ]
    for c in sorted({r["planner"] for r in loaded}):
        pairs = [
            (before[(r["problem"], c)], bool(r["success"]))
            for r in loaded
            if r["planner"] == c and (r["problem"], c) in before
        ]
        differ = sum(a != b for a, b in pairs)
        lines.append(f"| `{c}` | {len(pairs)} | {sum(a for a, _ in pairs)} | {sum(b for _, b in pairs)} | {differ} |")
    return "\n".join(lines)


def truth_gap(rows: Sequence[dict[str, Any]], resamples: int = 10_000) -> str:
    """Per controller and robot, success with depth sensing against truth sensing on the same
    scenarios (base problem, behaviour and speed) and seeds, for the controllers that ran both.
    The gap [points] is truth's success less depth's over the pairs; its 95 % interval resamples
    the scenarios with replacement, each with all of its seeds (a percentile bootstrap, seeded)."""
    verdicts: dict[tuple[str, str, str, int], bool] = {}
    robot_of: dict[str, str] = {}
    for r in rows:
        keys = scenario_keys(r["problem"])
        sensing = keys.get("sensing")
        if sensing in ("truth", "depth"):
            same = str(r["problem"]).replace(f"_{sensing}/", "/")
            verdicts[(r["planner"], sensing, same, int(r["seed"]))] = bool(r["success"])
            robot_of[same] = keys["robot"]
    lines = [
        "| controller | robot | seeds | truth | depth | gap [points] (95 % interval) |",
        "|---|---|---|---|---|---|",
    ]
    for c in sorted({k[0] for k in verdicts}):
        both = sorted(
            (p, seed)
            for (cc, sensing, p, seed) in verdicts
            if (cc, sensing) == (c, "depth") and (c, "truth", p, seed) in verdicts
        )
        robots = sorted({robot_of[p] for p, _ in both})
        for robot in [*robots, "all"] if len(robots) > 1 else robots:
            mine = [(p, seed) for p, seed in both if robot in ("all", robot_of[p])]
            t = sum(verdicts[(c, "truth", p, seed)] for p, seed in mine)
            d = sum(verdicts[(c, "depth", p, seed)] for p, seed in mine)
            lo, hi = _gap_interval(
                [(p, verdicts[(c, "truth", p, seed)], verdicts[(c, "depth", p, seed)]) for p, seed in mine], resamples
            )
            seeds = ",".join(str(x) for x in sorted({seed for _, seed in mine}))
            lines.append(
                f"| `{c}` | {robot} | {seeds} | {_rate(t, len(mine))} | {_rate(d, len(mine))} "
                f"| {100 * (t - d) / len(mine):.1f} [{lo:.1f}, {hi:.1f}] |"
            )
    return "\n".join(lines)


def _gap_interval(pairs: Sequence[tuple[str, bool, bool]], resamples: int) -> tuple[float, float]:
    """95 % percentile-bootstrap interval [points] of truth's success less depth's over ``pairs``
    (scenario, truth verdict, depth verdict), resampling scenarios with all of their pairs."""
    by: dict[str, list[int]] = collections.defaultdict(list)
    for p, t, d in pairs:
        by[p].append(int(t) - int(d))
    diff = np.array([sum(v) for v in by.values()], dtype=float)  # per scenario: summed over its seeds
    count = np.array([len(v) for v in by.values()], dtype=float)
    rng = np.random.default_rng(0)
    pick = rng.integers(0, len(diff), size=(resamples, len(diff)))
    gaps = 100 * diff[pick].sum(axis=1) / count[pick].sum(axis=1)
    lo, hi = np.percentile(gaps, [2.5, 97.5])
    return float(lo), float(hi)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("db", nargs="+", help="results files (their closed-loop runs are pooled)")
    parser.add_argument(
        "--loaded", help="a results file of the same scenarios run beside other load: verdicts compared"
    )
    parser.add_argument("--sensing", choices=("truth", "depth"), help="only the scenarios of this sensing model")
    parser.add_argument(
        "--truth-gap",
        action="store_true",
        help="only: each controller's success with depth sensing against truth sensing on the same scenarios",
    )
    parser.add_argument(
        "--common",
        action="store_true",
        help="only the scenarios every controller has a run of (a partial run compares like with like)",
    )
    args = parser.parse_args()
    rows = _rows(args.db)
    if args.truth_gap:
        print(f"### Depth sensing against truth sensing\n\n{truth_gap(rows)}")
        return
    if args.sensing:
        rows = [r for r in rows if scenario_keys(r["problem"]).get("sensing") == args.sensing]
    if args.common:
        rows = common(rows)
    if args.loaded:
        print(f"### Verdicts beside load against quiet\n\n{compare(rows, _rows([args.loaded]))}")
        return
    print(f"{len(rows)} closed-loop runs\n")
    for key in ("robot", "speed", "sensing", "behaviour"):
        print(f"### Success by {key}\n\n{by(rows, key)}\n")
    print(f"### Failure reasons\n\n{reasons(rows)}\n")
    print(f"### Compute and motion (medians; compute over every run, the rest over successes)\n\n{compute(rows)}\n")
    print(f"### Hand-off (medians over runs)\n\n{handoff(rows)}")


def common(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows of the scenarios that every controller in ``rows`` has a run of."""
    controllers = {r["planner"] for r in rows}
    have: dict[str, set[str]] = collections.defaultdict(set)
    for r in rows:
        have[r["problem"]].add(r["planner"])
    return [r for r in rows if have[r["problem"]] == controllers]


def _rows(paths: Sequence[str]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for path in paths:
        with ResultsDB(path, read_only=True) as db:
            rows += [r for r in db.rows() if r.get("deadline_misses") is not None]
    return rows


if __name__ == "__main__":
    main()
