"""The matrix field's push against ``edt-field``'s where ``matrix-field`` collides (issue 32).

For every problem ``matrix-field`` failed in a results file, the planner is run again in this
process (seed 0, ``--time-limit``); from the configuration each collision escape rewound to (the
last one checked free), the loop is stepped again without escapes for up to ``--steps`` steps,
once with the matrix field and once with ``edt-field``'s push from the same configuration.
Printed per problem: how many of those re-runs collided with each field; at the end, at the step
the matrix field's re-run collides, the push of both fields at the control point where
``edt-field`` pushes hardest (magnitudes [m/s] and the cosine between the two directions), and
the links of those points.

    python benchmarks/push_at_collisions.py --db tune.db --problems /tmp/tune-s1 /tmp/tune-s2
"""

from __future__ import annotations

import argparse
import collections
import functools
import sqlite3
from typing import Any

import numpy as np

import planbench
from planbench.checking.collision import CollisionChecker
from planbench_plugins.matrix_field import MatrixFieldPlanner
from planbench_plugins.potential_fields import EDTFieldPlanner


def run_on(planner: Any, q0: np.ndarray, checker: Any, steps: int, record: Any = None) -> int | None:
    """Step ``planner``'s loop from ``q0``; the step of the first collision, or None."""
    stepper, q = planner.stepper, q0.copy()
    for k in range(steps):
        q = q + stepper(q) * planner.config.dt
        if record is not None:
            record(q)
        if checker.in_collision(q):
            return k
    return None


def compare(mf: Any, edt: Any, names: np.ndarray, last: dict[str, Any], q: np.ndarray) -> None:
    """Both pushes at ``q`` at the control point where ``edt-field`` pushes hardest, into ``last``."""
    _, fm = mf.repulsion_at(q)
    _, fe = edt.repulsion_at(q)
    n = len(names)  # the control points (the self-collision push's points follow)
    fm, fe = fm[:n], fe[:n]
    j = int(np.argmax(np.linalg.norm(fe, axis=1)))
    a, b = float(np.linalg.norm(fm[j])), float(np.linalg.norm(fe[j]))
    last["v"] = (str(names[j]), a, b, float(fm[j] @ fe[j]) / max(a * b, 1e-12))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", required=True, help="a results file with matrix-field runs")
    ap.add_argument("--problems", nargs="+", required=True, help="problem selectors holding its problems")
    ap.add_argument("--time-limit", type=float, default=30.0)
    ap.add_argument("--steps", type=int, default=40)
    args = ap.parse_args()
    failed = [
        p
        for (p,) in sqlite3.connect(args.db).execute(
            "select problem from runs where planner = 'matrix-field' and success = 0 order by problem"
        )
    ]
    problems = {p.id: p for selector in args.problems for p in planbench.load_problems(selector)}
    counts: collections.Counter[str] = collections.Counter()
    links: collections.Counter[str] = collections.Counter()
    mf_push, edt_push, cosine = [], [], []
    for pid in failed:
        problem = problems.get(pid)
        if problem is None:
            continue
        mf = MatrixFieldPlanner()
        result = planbench.plan(problem, mf, time_limit=args.time_limit, seed=0)
        edt = EDTFieldPlanner()
        edt.setup(problem)
        checker = CollisionChecker(problem.robot, problem.scene)
        cp, path = mf.control_points, result.path
        if cp is None or path is None:
            continue
        names = np.array(cp.link)
        here: collections.Counter[str] = collections.Counter()
        for what, frm in zip(result.info["escape_after"], result.info["escape_steps"], strict=True):
            if what != "collision" or frm >= len(path):
                continue
            last: dict[str, Any] = {}
            k_mf = run_on(mf, path[frm], checker, args.steps, functools.partial(compare, mf, edt, names, last))
            k_edt = run_on(edt, path[frm], checker, args.steps)
            if k_mf is None:
                here["matrix field free"] += 1
                continue
            if k_edt is None:
                here["edt free"] += 1
            elif k_edt > k_mf:
                here["edt later"] += 1
            else:
                here["edt as soon"] += 1
            name, a, b, c = last["v"]
            links[name] += 1
            mf_push.append(a)
            edt_push.append(b)
            cosine.append(c)
        print(pid, result.status.name, dict(here), flush=True)
        counts.update(here)
    print("re-runs (matrix field collides within the steps; what edt-field does from there):", dict(counts))
    if mf_push:
        q = [10, 50, 90]
        print("push at the collision step [m/s], p10/median/p90:")
        print(
            "  matrix field",
            np.round(np.percentile(mf_push, q), 2),
            " edt-field",
            np.round(np.percentile(edt_push, q), 1),
        )
        print("  cosine between them", np.round(np.percentile(cosine, q), 2), " links", dict(links))


if __name__ == "__main__":
    main()
