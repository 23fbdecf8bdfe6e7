"""OMPL planners and the certified checker: how the search and the simplifier check motions, and
whether failing segments are repaired, measured by certified success and planning time.

Usage::

    python benchmarks/ompl_certified.py [--problems mbm:*/0001-0005] [--planner ompl-rrtconnect]
        [--time-limit 5] [--seed 0] [--variant NAME=key:value,key:value ...] [--before REV]

Each variant is a set of planner settings (``motion_check``, ``simplify_check``,
``repair_attempts`` ...), e.g. ``--variant search=motion_check:certified``. ``--before REV`` adds the
OMPL plugin as it was at git revision ``REV`` (its files read with ``git show``, imported under
another name, against today's planbench) as the variant ``before``.

This script keeps its own loop: ``--before REV`` imports the plugin of another git revision under
another name, which a suite's workers cannot load. Every run is one fresh process, as
``planbench bench`` runs OMPL planners: ``setup`` untimed, ``plan``
timed, then ``planbench.evaluate`` (the certified harness) decides success. The variants of one
problem run one after the other, in an order rotated from problem to problem, so a busy machine
slows all of them alike. Printed: per variant, certified successes, median planning time over all
runs and over the runs every variant solved, median time certifying inside ``plan``, and where the
returned paths came from (``path_source``, and how many segments were repaired).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import subprocess
import sys
import tempfile

DEFAULT_VARIANTS = {
    "sampled": {"motion_check": "sampled", "simplify_check": "sampled", "repair_attempts": 0},
    "repair": {"motion_check": "sampled", "simplify_check": "sampled"},
    "simplify": {"motion_check": "sampled", "simplify_check": "certified"},
    "certified": {"motion_check": "certified", "simplify_check": "certified"},
}


def _value(text: str) -> object:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def parse_variant(spec: str) -> tuple[str, dict[str, object]]:
    name, _, rest = spec.partition("=")
    settings = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition(":")
        settings[key] = _value(value)
    return name, settings


def _before_package(rev: str) -> str:
    """The OMPL plugin's files at ``rev`` as a package ``ompl_before`` in a temporary folder."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    folder = tempfile.mkdtemp(prefix="ompl_before_")
    pkg = os.path.join(folder, "ompl_before")
    os.makedirs(pkg)
    names = subprocess.run(
        ["git", "ls-tree", "--name-only", rev, "plugins/ompl_planners/"], cwd=root, check=True, capture_output=True
    ).stdout.split()
    for raw in names:
        name = raw.decode()
        text = subprocess.run(["git", "show", f"{rev}:{name}"], cwd=root, check=True, capture_output=True).stdout
        with open(os.path.join(pkg, os.path.basename(name)), "wb") as f:
            f.write(text)
    return folder


def run_one(problem_id: str, planner: str, settings: dict[str, object], time_limit: float, seed: int) -> dict:
    import numpy as np

    import planbench
    from planbench.problems.datasets import load_problems

    (problem,) = load_problems(problem_id)
    if settings.pop("_before", False):
        import ompl_before

        cls = {"ompl-rrtconnect": ompl_before.RRTConnectPlanner}[planner]
        instance = cls(**settings)
    else:
        from planbench.registry import get_planner

        instance = get_planner(planner)(**settings)
    result = planbench.plan(problem, instance, seed=seed, time_limit=time_limit)
    ev = planbench.evaluate(problem, result)
    info = result.info or {}
    keep = ("path_source", "verify_time", "solve_time", "simplify_time", "repaired_segments", "certified_checks")
    return {
        "success": bool(ev.success),
        "status": result.status.value,
        "planning_time": float(result.planning_time),
        "failure": ev.failure[:200],
        **{k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in info.items() if k in keep},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", default="mbm:*/0001-0005")
    ap.add_argument("--planner", default="ompl-rrtconnect")
    ap.add_argument("--time-limit", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", action="append", default=[], help="NAME=key:value,... (default: four variants)")
    ap.add_argument("--before", metavar="REV", help="add the OMPL plugin as of git revision REV as 'before'")
    ap.add_argument("--json", help="also write every run to this file (JSON lines)")
    ap.add_argument("--_run", help=argparse.SUPPRESS)
    args = ap.parse_args()

    if args._run:  # one run in this (fresh) process
        problem_id, settings = json.loads(args._run)
        print("RESULT " + json.dumps(run_one(problem_id, args.planner, settings, args.time_limit, args.seed)))
        return

    from planbench.problems.datasets import load_problems

    variants = dict(parse_variant(v) for v in args.variant) if args.variant else dict(DEFAULT_VARIANTS)
    env = dict(os.environ)
    if args.before:
        env["PYTHONPATH"] = _before_package(args.before) + os.pathsep + env.get("PYTHONPATH", "")
        variants = {"before": {"_before": True}, **variants}
    problems = [p.id for p in load_problems(args.problems)]
    names = list(variants)
    rows: dict[str, dict[str, dict]] = collections.defaultdict(dict)
    out = open(args.json, "w") if args.json else None  # noqa: SIM115
    for n, pid in enumerate(problems):
        order = names[n % len(names) :] + names[: n % len(names)]
        for name in order:
            cmd = [sys.executable, __file__, "--planner", args.planner, "--time-limit", str(args.time_limit)]
            cmd += ["--seed", str(args.seed), "--_run", json.dumps([pid, variants[name]])]
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
            lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
            row = json.loads(lines[-1][7:]) if lines else {"success": False, "error": proc.stderr[-500:]}
            rows[name][pid] = row
            if out:
                out.write(json.dumps({"problem": pid, "variant": name, **row}) + "\n")
                out.flush()
        line = "  ".join(
            f"{name}: {'ok' if rows[name][pid].get('success') else 'FAIL'} "
            f"{rows[name][pid].get('planning_time', float('nan')) * 1000:.0f} ms"
            for name in names
        )
        print(f"{pid:32s} {line}", flush=True)

    solved_by_all = [p for p in problems if all(rows[v][p].get("success") for v in names)]
    print(f"\n{len(problems)} problems, {args.planner}, seed {args.seed}, {args.time_limit:g} s; medians [ms]")
    print(f"{'variant':12s} {'success':>8s} {'plan':>7s} {'plan*':>7s} {'verify':>7s}  path_source")
    for name in names:
        r = rows[name]
        succ = sum(bool(r[p].get("success")) for p in problems)
        times = [r[p]["planning_time"] for p in problems if "planning_time" in r[p]]
        common = [r[p]["planning_time"] for p in solved_by_all]
        verify = [r[p].get("verify_time", 0.0) for p in problems if "planning_time" in r[p]]
        sources = collections.Counter(r[p].get("path_source", "-") for p in problems)
        repaired = sum(r[p].get("repaired_segments", 0) or 0 for p in problems)

        def med(x: list[float]) -> str:
            return f"{statistics.median(x) * 1000:7.0f}" if x else "      -"

        print(
            f"{name:12s} {succ:5d}/{len(problems):<3d}{med(times)} {med(common)} {med(verify)}  "
            f"{dict(sources)} repaired segments: {repaired}"
        )
    print(f"plan*: over the {len(solved_by_all)} problems every variant solved")


if __name__ == "__main__":
    main()
