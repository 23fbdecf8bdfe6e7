"""Benchmarks of the matrix-field planner. Prints medians; run on a quiet machine for timings.

    python benchmarks/matrix_field.py step                  # per-step cost and its split
    python benchmarks/matrix_field.py step --rounds 15      # more rounds (a busy machine)
    python benchmarks/matrix_field.py step --config '{"hierarchy": "priority"}'   # with settings
    python benchmarks/matrix_field.py mbm "mbm:*/0021-0100"  # planning on MotionBenchMaker
    python benchmarks/matrix_field.py sweep                 # parameter sweep on 0001-0020

``step``: the time of one planner step with the Panda's automatic control points (20), from the
planner's own loop (``max_steps`` steps, no stopping, no collision checks: kinematics, repulsion,
solve, integration and the loop's bookkeeping), next to the bare pinocchio calls the step makes
(``computeJointJacobians`` and ``updateFramePlacement``) and their ratio, each the median of 5
rounds. The breakdown times each part alone, on the query's own objects: the rest of the
kinematics (control points and the goal frame's Jacobian, one compiled call), field sampling
(``FieldRepulsion.forces``), the self-collision push (``SelfCollisionPush``: field sampling and
push timed over the round's own path, in order, so that the push's ask schedule and its coal
queries near the arm's own links count as in the loop), the compiled step (all task terms, manipulability gradient,
repulsion mapping, DLS with null space, limits), the integration; glue is the rest (the Python
loop and its bookkeeping). The numpy reference step (the task functions composed in Python) is
timed alone too.

``mbm``: run by ``planbench.bench`` (isolated workers, certified validation): success, median
planning and setup time, median joint and end-effector path length and minimum clearance of the
solved problems, and the failure reasons, per family, next to the straight-line reference planner.
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from _bench import run_suite

import planbench
from planbench_plugins.ik_loop import fast
from planbench_plugins.ik_loop.self_collision import SelfCollisionPush
from planbench_plugins.matrix_field import MatrixFieldConfig, MatrixFieldPlanner


def _per_call_us(fn: Any, reps: int = 2000) -> float:
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps * 1e6


def _along_path(path: np.ndarray, kin: Any, push: SelfCollisionPush) -> tuple[float, float]:
    """Per-step time [us] of the field's repulsion (``push.inner``) and of the self-collision
    push on top of it, over the configurations of ``path`` in order (the push's ask schedule as
    in the loop): the kinematics alone, with the field, with field and push, each timed over the
    whole path and subtracted."""
    inner = push.inner

    def over(fn: Any) -> float:
        push.restart()
        t0 = time.perf_counter()
        for q in path:
            kin.update(q)
            fn(kin)
        return (time.perf_counter() - t0) / len(path) * 1e6

    base = over(lambda k: None)
    field = over(inner.forces)
    both = over(push.forces)
    return field - base, both - field


def bench_step(
    problem_id: str = "mbm:box/0001", steps: int = 1000, repeats: int = 5, settings: dict[str, Any] | None = None
) -> dict[str, float]:
    """Per-step time of the planner's loop and of its parts, each the median of ``repeats``
    rounds; in each round every part is timed once, right after the loop, so that the ratio to
    the bare pinocchio calls (``ratio``, the median of the rounds' ratios) is taken under the
    same load."""
    import pinocchio as pin

    problem = planbench.load_problems(problem_id)[0]
    cfg = MatrixFieldConfig(
        stall_ratio=0.0,
        max_steps=steps,
        collision_check_every=0,
        verify_path=False,
        goal_tolerance_scale=1e-9,
        **(settings or {}),
    )
    planner = MatrixFieldPlanner(cfg)
    planner.setup(problem)
    rng = np.random.default_rng(0)
    planner.plan(problem, time_limit=60.0, rng=rng)

    # the query's own objects, as the loop uses them (prepared by setup), at a configuration near the start
    stepper = planner.stepper
    kin, inputs, repulsion = stepper.kin, stepper.inputs, stepper.repulsion
    push = repulsion if isinstance(repulsion, SelfCollisionPush) else None
    q = np.asarray(problem.start, dtype=float) + 0.05
    kin.update(q)
    points, F, support, joint = repulsion.forces(kin)
    model, data, fid = kin.model, kin.data, kin.frame_id
    qd, dg, tool = stepper.qd, stepper.diag, stepper.tool
    step = stepper.solve
    lower, upper = inputs.lower, inputs.upper
    args = (stepper.q, qd, cfg.dt, lower, upper, np.empty((2, len(q))))  # the loop's integration, as plan binds it
    advance = functools.partial(
        fast.bind(fast.compiled().advance, *args, 0) if planner.use_numba else fast.advance_numpy, *args
    )

    def pin_calls() -> None:  # what ArmKinematics.update asks of pinocchio
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacement(model, data, fid)

    def pin_calls_frame_jacobian() -> None:  # what the step asked of pinocchio before it computed J itself
        pin_calls()
        pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)

    def numpy_step() -> None:
        fast.step_numpy(
            kin.S,
            kin.J,
            kin.p,
            kin.R,
            inputs.p_goal,
            inputs.R_goal,
            q,
            lower,
            upper,
            inputs.qd_max,
            points,
            F,
            support,
            kin.descendants,
            tool,
            inputs.params,
            qd,
            dg,
        )

    rounds: dict[str, list[float]] = {}
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = planner.plan(problem, time_limit=60.0, rng=rng)
        row = {"step": (time.perf_counter() - t0) / max(1, r.info["steps"] + 1) * 1e6}
        row["pinocchio"] = _per_call_us(pin_calls)
        row["ratio"] = row["step"] / row["pinocchio"]
        pin3 = _per_call_us(pin_calls_frame_jacobian)
        row["kinematics (rest)"] = _per_call_us(lambda: kin.update(q)) - row["pinocchio"]
        if push is None:
            row["field sampling"] = _per_call_us(lambda: repulsion.forces(kin))
        else:  # along the round's own path: the push asks coal only where the arm comes near itself
            row["field sampling"], row["self-collision push"] = _along_path(np.asarray(r.path), kin, push)
        row["solve (compiled step)"] = _per_call_us(lambda: step(points, F, support, tool))
        row["integrate"] = _per_call_us(lambda: advance(1))
        row["glue (rest)"] = row["step"] - sum(v for k, v in row.items() if k not in ("step", "ratio"))
        row["(numpy step, reference)"] = _per_call_us(numpy_step, reps=200)
        row["pinocchio + getFrameJacobian"] = pin3
        row["ratio to it"] = row["step"] / pin3
        for k, v in row.items():
            rounds.setdefault(k, []).append(v)
    out = {k: statistics.median(v) for k, v in rounds.items()}
    out["control_points"] = float(len(stepper.control_points))
    return out


def run_mbm(
    selector: str, config: dict[str, Any], time_limit: float = 5.0, straight: bool = True, verbose: bool = False
) -> dict[str, Any]:
    """matrix-field (with ``config``) and the straight line on every problem, run and validated by
    ``planbench.bench`` (benchmarks/_bench.py); rows per problem with both planners' numbers."""
    planners = {"matrix-field": ("matrix-field", config)}
    if straight:
        planners["straight-line"] = ("straight-line", {})
    bench_rows = run_suite("matrix-field-mbm", [selector], planners, time_limit=time_limit)
    by_label: dict[str, dict[str, dict[str, Any]]] = {label: {} for label in planners}
    for r in bench_rows:
        by_label[r["planner"]][r["problem"]] = r
    rows = []
    for pid, r in by_label["matrix-field"].items():
        nan = float("nan")
        reason = "success" if r["success"] else (r["failure"] or r["status"] or "?").split(":")[0][:30]
        row = dict(
            family=r["family"],
            id=pid,
            ok=bool(r["success"]),
            reason=reason,
            time=r["planning_time"] if r["planning_time"] is not None else nan,
            setup=r["setup_time"] if r["setup_time"] is not None else nan,
            qlen=r["joint_path_length"] if r["joint_path_length"] is not None else nan,
            eelen=r["ee_path_length"] if r["ee_path_length"] is not None else nan,
            clearance=r["min_clearance"] if r["min_clearance"] is not None else nan,
            steps=json.loads(r["info"] or "{}").get("steps", 0),
        )
        if straight:
            sl = by_label["straight-line"][pid]
            row.update(
                sl_ok=bool(sl["success"]),
                sl_qlen=sl["joint_path_length"] if sl["joint_path_length"] is not None else nan,
                sl_eelen=sl["ee_path_length"] if sl["ee_path_length"] is not None else nan,
                sl_clearance=sl["min_clearance"] if sl["min_clearance"] is not None else nan,
                sl_time=sl["planning_time"],
            )
        rows.append(row)
        if verbose:
            print(pid, reason, f"{row['time'] * 1e3:.1f} ms", flush=True)
    return {"rows": rows, "summary": summarize(rows, straight)}


def _med(values: list[float]) -> float:
    vals = [v for v in values if np.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def summarize(rows: list[dict[str, Any]], straight: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for fam in sorted({r["family"] for r in rows}) + ["all"]:
        rr = [r for r in rows if fam in ("all", r["family"])]
        ok = [r for r in rr if r["ok"]]
        s: dict[str, Any] = dict(
            n=len(rr),
            success=len(ok) / len(rr),
            time_ms=1e3 * _med([r["time"] for r in rr]),
            setup_ms=1e3 * _med([r["setup"] for r in rr]),
            qlen=_med([r["qlen"] for r in ok]),
            eelen=_med([r["eelen"] for r in ok]),
            clearance=_med([r["clearance"] for r in ok]),
            reasons=dict(Counter(r["reason"] for r in rr if not r["ok"])),
        )
        if straight:
            sok = [r for r in rr if r["sl_ok"]]
            s.update(
                sl_success=len(sok) / len(rr),
                sl_qlen=_med([r["sl_qlen"] for r in sok]),
                sl_eelen=_med([r["sl_eelen"] for r in sok]),
                sl_clearance=_med([r["sl_clearance"] for r in sok]),
            )
        out[fam] = s
    return out


def print_summary(summary: dict[str, Any]) -> None:
    print(
        f"{'family':18s} {'n':>4s} {'succ':>6s} {'t_med ms':>9s} {'setup ms':>9s} {'q len':>6s} {'ee len':>7s} "
        f"{'clear':>6s} | {'SL succ':>7s} {'SL q':>6s} {'SL ee':>6s} {'SL clr':>6s}  failures"
    )
    for fam, s in summary.items():
        print(
            f"{fam:18s} {s['n']:4d} {s['success']:6.0%} {s['time_ms']:9.1f} {s['setup_ms']:9.1f} {s['qlen']:6.2f} "
            f"{s['eelen']:7.2f} {s['clearance']:6.3f} | {s.get('sl_success', float('nan')):7.0%} "
            f"{s.get('sl_qlen', float('nan')):6.2f} {s.get('sl_eelen', float('nan')):6.2f} "
            f"{s.get('sl_clearance', float('nan')):6.3f}  {s['reasons']}"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    st = sub.add_parser("step")
    st.add_argument("--problem", default="mbm:box/0001")
    st.add_argument("--config", default="{}", help='JSON object of settings, e.g. {"hierarchy": "priority"}')
    st.add_argument(
        "--rounds", type=int, default=5, help="rounds of which the medians are taken (more on a busy machine)"
    )
    m = sub.add_parser("mbm")
    m.add_argument("selector", nargs="?", default="mbm:*/0021-0100")
    m.add_argument("--config", default="{}", help="JSON object of MatrixFieldConfig settings")
    m.add_argument("--json", help="write the rows and summary to this file")
    m.add_argument("-v", action="store_true")
    sw = sub.add_parser("sweep")
    sw.add_argument("--selector", default="mbm:*/0001-0020")
    sw.add_argument("--grid", default='{"standoff": [0.08, 0.1, 0.12], "tool_repulsion_gain": [0.0, 1.0]}')
    args = ap.parse_args(argv)
    if args.cmd == "step":
        res = bench_step(args.problem, repeats=args.rounds, settings=json.loads(args.config))
        points = int(res.pop("control_points"))
        print(f"{args.problem}, {points} control points, median of {args.rounds} rounds [us per step]:")
        print(f"  full loop step     {res.pop('step'):7.2f}  (kinematics + repulsion + solve + integrate + loop)")
        print(f"  bare pinocchio     {res.pop('pinocchio'):7.2f}  (computeJointJacobians + updateFramePlacement)")
        print(f"  ratio              {res.pop('ratio'):7.2f}")
        pin3, ratio3 = res.pop("pinocchio + getFrameJacobian"), res.pop("ratio to it")
        print(f"  (with getFrameJacobian, which the step no longer calls: {pin3:.2f} us, ratio {ratio3:.2f})")
        print("  breakdown (pinocchio above):")
        for k, v in res.items():
            print(f"    {k:24s} {v:7.2f}")
    elif args.cmd == "mbm":
        out = run_mbm(args.selector, json.loads(args.config), verbose=args.v)
        print_summary(out["summary"])
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(out, fh, indent=1, default=float)
    else:
        import itertools

        grid = json.loads(args.grid)
        keys = list(grid)
        for values in itertools.product(*(grid[k] for k in keys)):
            cfg = dict(zip(keys, values, strict=True))
            out = run_mbm(args.selector, cfg, straight=False)
            s = out["summary"]["all"]
            per = " ".join(f"{f[:10]}={v['success']:.0%}" for f, v in out["summary"].items() if f != "all")
            print(json.dumps(cfg), f"success {s['success']:.1%} t_med {s['time_ms']:.1f} ms  {per}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
