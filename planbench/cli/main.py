"""The ``planbench`` command line: ``list``, ``plan``, and the commands of other core modules."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import logging
import math
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

import planbench
from planbench.errors import PlanbenchError
from planbench.files.inputs import check_writable, release_outputs
from planbench.files.outputs import check_output
from planbench.harness import DEFAULT_TIME_LIMIT
from planbench.planner import PlanResult, PlanStatus
from planbench.problems.datasets import problem_sets
from planbench.registry import CONTROLLERS, REGISTRY
from planbench.robot import load_robot, robot_names
from planbench.settings import parse_setting, settings_text

log = logging.getLogger("planbench")

# Core modules that contribute subcommands through an ``add_commands(subparsers)`` function.
COMMAND_MODULES = ("planbench.cli.bench", "planbench.cli.field", "planbench.cli.scenario", "planbench.cli.robot")


def cmd_list(args: argparse.Namespace) -> int:
    console = Console()
    for title, registry in (("Planners", REGISTRY), ("Controllers (closed loop)", CONTROLLERS)):
        table = Table(title=title, title_justify="left")
        for col in ("name", "origin", "distribution", "available"):
            table.add_column(col)
        for name in registry.names():
            spec = registry.spec(name)
            ok = spec.available
            status = "yes" if ok else f"no: {spec.error}" + (f" ({spec.hint})" if spec.hint else "")
            dist = f"{spec.distribution} {spec.version}".strip() or "-"
            table.add_row(name, f"{spec.origin}: {spec.entry_point}", dist, status)
        console.print(table)
    robots = Table(title="Robots", title_justify="left")
    for col in ("name", "planned joints", "end effector", "description"):
        robots.add_column(col)
    for name in robot_names():
        try:
            r = load_robot(name)
            robots.add_row(name, str(r.nq), r.settings.ee_frame, r.settings.description)
        except PlanbenchError as exc:
            robots.add_row(name, "-", "-", f"cannot load: {exc}")
    console.print(robots)
    sets = Table(title="Problem sets", title_justify="left")
    sets.add_column("name")
    sets.add_column("content")
    for name, what in problem_sets().items():
        sets.add_row(name, what)
    sets.add_row("dynamic", "432 closed-loop scenarios (Panda, UR5, xArm7; moving obstacles; truth and depth sensing)")
    sets.add_row("dynamic-tune", "144 of them (3 base problems, one per robot): tune controllers' defaults here")
    sets.add_row("dynamic-test", "the other 288 (6 base problems): measure here")
    sets.add_row("dynamic-smoke", "4 of them, for the dynamic-smoke suite")
    console.print(sets)
    console.print(_suites_table())
    return 0


def _suites_table() -> Table:
    """The built-in suites (``planbench bench --suite NAME``): what each runs, from its file."""
    from planbench.bench.suite import builtin_suites, load_suite

    table = Table(title="Suites (planbench bench --suite NAME)", title_justify="left")
    for col in ("name", "kind", "what it runs"):
        table.add_column(col)
    for name in sorted(builtin_suites()):
        try:
            suite = load_suite(name)
        except PlanbenchError as exc:
            table.add_row(name, "-", f"cannot load: {exc}")
            continue
        table.add_row(name, suite.kind, suite.description)
    return table


METRICS = (  # (Evaluation field, label, display unit)
    ("success", "success (validated)", ""),
    ("status", "planner's status", ""),
    ("planning_time", "planning time [ms]", "ms"),
    ("setup_time", "setup time [ms]", "ms"),
    ("joint_path_length", "joint path length [rad]", ""),
    ("ee_path_length", "EE path length [m]", ""),
    ("min_clearance", "min clearance [mm]", "mm"),
    ("mean_clearance", "mean clearance [mm]", "mm"),
    ("duration", "duration at velocity limits [s]", ""),
    ("duration_limited", "duration at velocity and acceleration limits [s]", ""),
    ("smoothness", "turning angle [rad]", ""),
    ("n_waypoints", "waypoints", ""),
    ("final_position_error", "final position error [mm]", "mm"),
    ("final_orientation_error", "final orientation error [rad]", ""),
    ("collision_checks", "collision checks (planner's count)", ""),
    ("validation_checks", "collision checks (validation)", ""),
)
COMPACT = {  # the several-problem table: short headers, so that it stays whole in 80 columns
    "success": "solved",
    "planning_time": "time [ms]",
    "joint_path_length": "joint len [rad]",
    "ee_path_length": "EE len [m]",
    "min_clearance": "clearance [mm]",
}


def _fmt(value: Any, unit: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "-"
        value = value * 1000 if unit in ("ms", "mm") else value
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def _numpy_while_cold(planner: Any) -> None:
    """A planner that would compile numba code on a cold cache computes with numpy instead (the same
    numbers to rounding), while the kernels compile in the background for the next command
    (:mod:`planbench.runtime.compile_cache`); ``PLANBENCH_BACKGROUND_COMPILE=0`` turns this off."""
    from planbench.runtime import backend, compile_cache

    if not compile_cache.enabled() or not getattr(planner, "use_numba", False) or compile_cache.is_warm():
        return
    backend.prefer("numpy")
    if getattr(planner, "use_numba", False):  # numba asked for by name: it compiles now
        backend.prefer(None)
        return
    compile_cache.warm_in_background()
    Console(stderr=True).print(
        "numba's cache is cold: this command computes with numpy (the same numbers to rounding, "
        "slower per step) while planbench's kernels compile in the background for the next ones",
        style="dim",
        highlight=False,
    )


PLAN_GRACE = 1.0
"""[s] past its time limit before ``planbench plan`` kills a planner's worker. Any answer later than
the limit (+ :data:`planbench.harness.HANDOFF_TOLERANCE`) is a ``timeout`` whatever the grace; the
grace only lets a slightly late answer's path be shown, so it is short (a suite's is 5 s)."""


def _worker_settings(setup: Any) -> dict[str, Any]:
    """The planner's settings as its worker gets them: those given, plus ``backend="numpy"`` where
    this command chose numpy for a cold numba cache (:func:`_numpy_while_cold`; the choice is made
    in this process, the worker is a fresh interpreter)."""
    from planbench.runtime import backend

    settings = dict(setup.settings)
    config = setup.config
    if (
        backend.resolve("auto") == "numpy"
        and dataclasses.is_dataclass(config)
        and getattr(config, "backend", None) == "auto"
        and "backend" not in settings
    ):
        settings["backend"] = "numpy"
    return settings


def _plan_in_workers(args: argparse.Namespace, refs: Sequence[Any], settings: dict[str, Any]) -> list[dict[str, Any]]:
    """Each problem planned as a benchmark run is (:class:`planbench.bench.runner.Runner`, one worker):
    killed at the time limit + :data:`PLAN_GRACE`, a late answer a ``timeout``, the path validated
    where no planner code ran. The records, in the order of ``refs``."""
    from planbench.bench.runner import Runner
    from planbench.bench.task import RunTask

    tasks = [
        RunTask(
            suite="plan",
            problem_id=ref.id,
            problem_ref=ref.ref,
            label=args.planner,
            planner=args.planner,
            seed=args.seed,
            settings=settings,
            time_limit=float(args.time_limit),
            grace=PLAN_GRACE,
            memory_limit=0.0,  # as in-process before: no address-space limit
        )
        for ref in refs
    ]
    records: dict[str, dict[str, Any]] = {}
    runner = Runner(1)
    runner.warm_numba = False  # a cold cache: this command plans with numpy and warms it in the background
    runner.run(tasks, lambda task, record: records.__setitem__(task.problem_id, record))
    return [records[ref.id] for ref in refs]


def _result_of(record: dict[str, Any]) -> PlanResult:
    """The plan result a record holds (for ``--plot``)."""
    ev = record["evaluation"]
    return PlanResult(
        PlanStatus(ev["status"]),
        path=record["path"],
        times=record["times"],
        message=str(record.get("message") or ""),
        info=record.get("info") or {},
        planning_time=ev["planning_time"],
        setup_time=ev["setup_time"],
    )


def _check_robots(name: str, planner: Any, refs: Sequence[Any]) -> None:
    """A named error before any run when ``planner`` declares the robots it plans for (its
    ``robots``) and a problem is for another (the first problem of each set is read: a set holds
    one robot)."""
    robots = getattr(planner, "robots", None)
    if not robots:
        return
    seen: set[str] = set()
    for ref in refs:
        group = ref.ref.rsplit("/", 1)[0] if ":" in ref.ref else ref.ref
        if group in seen:
            continue
        seen.add(group)
        robot = planbench.load_problems(ref.ref)[0].robot.name
        if robot not in robots:
            raise PlanbenchError(
                f"planner {name!r} plans for robots {', '.join(robots)}; problem {ref.id} is for robot {robot!r}"
            )


def cmd_plan(args: argparse.Namespace) -> int:
    from planbench.bench.suite import check_seconds, check_seed, expand_problems

    check_seconds(args.time_limit, "--time-limit")
    check_seed(args.seed)
    setup = REGISTRY.configure(args.planner, text=settings_text(args.set))  # settings checked before anything runs
    refs = expand_problems([args.problem])
    for out in (args.json, args.plot, args.replay):
        if out:
            check_output(out)
    planner = setup.build()
    _check_robots(args.planner, planner, refs)
    _numpy_while_cold(planner)
    if args.replay and len(refs) != 1:
        raise PlanbenchError("--replay needs one problem")
    if args.plot and (len(refs) != 1 or not hasattr(planner, "plot_result")):
        why = "one problem" if len(refs) != 1 else f"a planner with a figure; {args.planner!r} has none"
        raise PlanbenchError(f"--plot needs {why}")
    for option, out in (("--json", args.json), ("--plot", args.plot), ("--replay", args.replay)):
        if out is not None:  # before planning: a folder or a FIFO nobody reads would fail or block at the end
            check_writable(out, option, folder_made=option == "--plot")
    console = Console()
    rows = []
    paths = []  # (path, times, the planner's message) per problem, for --json
    records = _plan_in_workers(args, refs, _worker_settings(setup))
    for ref, record in zip(refs, records, strict=True):
        ev = record["evaluation"]
        if ev["status"] in ("error", "crash", "timeout") and record.get("traceback"):
            log.debug("%s", record["traceback"])
        rows.append({"problem": ref.id, "planner": args.planner, "seed": args.seed, **ev})
        paths.append((record["path"], record["times"], record["message"]))
    title = f"{args.planner} on {args.problem}, seed {args.seed} (every path checked by planbench)"
    units = {key: (label, unit) for key, label, unit in METRICS}
    if len(rows) == 1:
        table = Table(title=title, title_justify="left", show_header=False)
        table.add_column("metric")
        table.add_column("value", justify="right")
        for key, label, unit in METRICS:
            table.add_row(escape(label), _fmt(rows[0][key], unit))
        console.print(table)
    else:
        cells = [[row["problem"], *(_fmt(row[key], units[key][1]) for key in COMPACT)] for row in rows]
        heads = ["problem", *COMPACT.values()]
        need = sum(max([len(h), *(len(c[i]) for c in cells)]) + 3 for i, h in enumerate(heads))
        if need <= console.width:  # one row per problem
            table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
            for i, h in enumerate(heads):
                table.add_column(escape(h), justify="left" if i == 0 else "right", no_wrap=True)
            for c in cells:
                table.add_row(*(escape(x) for x in c))
            console.print(table)
        else:  # too narrow for the table: one line per problem, every value whole
            console.print(escape(title), highlight=False)
            for c in cells:
                values = ", ".join(f"{h} {x}" for h, x in zip(heads[1:], c[1:], strict=True))
                console.print(f"[bold]{escape(c[0])}[/bold]: {escape(values)}", highlight=False)
    for row in rows:
        if row["failure"]:
            console.print(f"[bold]{escape(row['problem'])}[/bold] failed: {escape(row['failure'])}", highlight=False)
    console.print(f"{sum(r['success'] for r in rows)}/{len(rows)} solved (validated)")
    if args.plot or args.replay:
        problem = planbench.load_problems(refs[0].ref)[0]
        path, times, _ = paths[0]
    if args.plot:
        planner.plot_result(problem, _result_of(records[0]), args.plot)
        console.print(f"figure written to {args.plot}")
    if args.replay:  # without a path, the page shows the problem's start and why there is none
        from planbench.geometry.occupancy import scene_grid
        from planbench.visual.replay import ReplayInfo, write_replay

        name = f"{args.planner} on {problem.id}: " + ("success" if rows[0]["success"] else rows[0]["failure"])
        grid = scene_grid(problem.scene, 0.02, robot=problem.robot)
        info = ReplayInfo.from_row(rows[0], settings=dict(setup.settings))
        write_replay(args.replay, problem, path, times, grid=grid, title=name, info=info)
        console.print(f"replay written to {escape(args.replay)} (open it in a browser)")
    if args.json:
        out = [
            {**row, "message": message, "path": _array(path), "times": _array(times)}
            for row, (path, times, message) in zip(rows, paths, strict=True)
        ]
        try:
            with open(args.json, "w") as f:
                json.dump(json_safe(out), f, indent=1, allow_nan=False)
        except OSError as exc:
            raise PlanbenchError(f"cannot write {args.json}: {exc.strerror}") from exc
        console.print(f"metrics and paths written to {escape(args.json)}")
    return 0 if any(r["success"] for r in rows) else 1


def cmd_replay(args: argparse.Namespace) -> int:
    from planbench.bench.replay import replay_run

    check_writable(args.out, "--out")
    out = replay_run(args.db, args.run, check_output(args.out, [args.db]))
    print(f"replay written to {out} (open it in a browser)")
    return 0


def cmd_bundle(args: argparse.Namespace) -> int:
    from planbench.bench.suite import expand_problems, load_suite
    from planbench.problems.bundle import save_bundle

    selectors = list(args.problem or [])
    if args.suite:
        suite = load_suite(args.suite)
        if suite.kind != "static":
            raise PlanbenchError(f"suite {suite.name!r} is a closed-loop suite; only problems can be bundled")
        selectors += list(suite.problems)
    if not selectors:
        raise PlanbenchError("name the problems to bundle: --problem SELECTOR (repeatable) and/or --suite SUITE")
    problems = [p for ref in expand_problems(selectors) for p in planbench.load_problems(ref.ref)]
    paths = save_bundle(problems, args.out)
    robots = sorted({p.robot.name for p in problems})
    print(f"{len(paths)} problems bundled in {args.out} (robots: {', '.join(robots)})")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from planbench.bench.suite import check_seconds
    from planbench.cli.check import check_in_subprocess

    check_seconds(args.timeout, "--timeout")
    kind = "controller" if args.controller else "planner"
    outcome = check_in_subprocess(args.name, kind, args.timeout)
    if outcome.unknown:
        raise PlanbenchError(outcome.failure)
    print("\n".join(outcome.lines()))
    return 0 if outcome.conformant else 1


def _array(a: Any) -> Any:
    return None if a is None else np.asarray(a, dtype=float).tolist()


def json_safe(x: Any) -> Any:
    """``x`` as strict JSON data: NaN and infinities become null (JSON has no NaN), numpy scalars
    and arrays plain numbers and lists, anything else its text."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if hasattr(x, "tolist"):
        return json_safe(x.tolist())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if x is None or isinstance(x, (bool, int, str)):
        return x
    return str(x)


class _DefaultsShown(argparse.HelpFormatter):
    """Help that ends each option with its default, where it has one (not for None or flags)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        unset = default is None or default is False or default is argparse.SUPPRESS
        if "%(default)" in text or "default" in text or unset or not action.option_strings:
            return text
        return f"{text} (default: %(default)s)"


class _CommandParser(argparse.ArgumentParser):
    """The parser of each command: its help shows the defaults."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _DefaultsShown)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="planbench",
        description="Plan robot-arm paths and compare planners fairly.",
        epilog="exit codes: 0 done (plan: at least one problem solved), 1 plan: no problem solved, "
        "2 bad input (a named error, no traceback), 130 interrupted",
    )
    parser.add_argument("--version", action="version", version=f"planbench {planbench.__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging (tracebacks of planner errors)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_CommandParser)

    p = sub.add_parser("list", help="planners and controllers (origin, availability), robots, problem sets, suites")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser(
        "plan",
        help="plan problems with one planner and print the validated metrics",
        description="Plan problems with one planner and print the metrics planbench validated. Exit code 0 when "
        "at least one problem is solved, 1 when none is, 2 on bad input.",
    )
    p.add_argument("--problem", required=True, help="mbm:box/0001, mbm:box/0001-0010, mbm:*, or a problem .json")
    p.add_argument("--planner", default="straight-line", help="a registered planner name (see `planbench list`)")
    p.add_argument("--seed", type=int, default=0, help="0 <= seed < 2**63")
    p.add_argument(
        "--time-limit",
        type=float,
        default=DEFAULT_TIME_LIMIT,
        help="[s] per problem, a finite number > 0",
    )
    p.add_argument(
        "--set",
        action="append",
        type=parse_setting,
        metavar="KEY=VALUE",
        help="a planner setting (repeatable), e.g. --set timed=false; read as the type of the planner's setting",
    )
    p.add_argument("--json", metavar="FILE", help="also write each problem's metrics, path, times (JSON, NaN: null)")
    p.add_argument("--plot", metavar="PNG", help="write the planner's figure of the result (one problem only)")
    p.add_argument("--replay", metavar="HTML", help="write a 3D replay of the path, one HTML file (one problem only)")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser(
        "replay",
        help="write a 3D replay of one run of a results file: one HTML file, offline, no server",
    )
    p.add_argument("db", help="results database written by `planbench bench`")
    p.add_argument("--run", type=int, required=True, help="the run's id (the id column of export --format csv)")
    p.add_argument("--out", default="replay.html", help="the HTML file to write")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser(
        "bundle",
        help="write problems (or a suite's) with their robot and mesh files into a folder that loads anywhere",
        description="Write problems into one folder together with every file they need: the robot's settings, "
        "URDF, SRDF and meshes, and the scenes' mesh and point-cloud files, all named relative to the folder. "
        "The folder can be moved or copied to another machine (example-robot-data not needed there); a suite "
        'names it as a problem selector (problems = ["FOLDER/"]).',
    )
    p.add_argument("--problem", action="append", help="mbm:box/0001, mbm:box/0001-0010, a problem .json (repeatable)")
    p.add_argument("--suite", help="a suite name or .toml: bundle its problems")
    p.add_argument("--out", required=True, help="the bundle folder (made if missing)")
    p.set_defaults(func=cmd_bundle)

    p = sub.add_parser(
        "check",
        help="run the conformance checker on a planner or controller, in a process of its own",
        description="Check a planner (or, with --controller, a controller) against planbench's interface and "
        "behaviour rules, in a separate process: a plugin that crashes or hangs fails its check, nothing else. "
        "Every named check is listed as passed, failed (with what was found) or not run. Exit code 0: "
        "conformant; 1: not; 2: unknown name.",
    )
    p.add_argument("name", help="a registered name, a family:variant preset, or module:Attr")
    p.add_argument("--controller", action="store_true", help="NAME is a closed-loop controller")
    p.add_argument("--timeout", type=float, default=300.0, help="[s] for the whole check")
    p.set_defaults(func=cmd_check)

    for module in COMMAND_MODULES:
        try:  # imported here: a command module whose optional dependency is missing is left out
            importlib.import_module(module).add_commands(sub)
        except ModuleNotFoundError as exc:
            if exc.name is None or not module.startswith(exc.name):
                raise
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
    try:
        return int(args.func(args) or 0)
    except PlanbenchError as exc:
        print(f"planbench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("planbench: interrupted", file=sys.stderr)
        return 130
    finally:
        release_outputs()


if __name__ == "__main__":
    sys.exit(main())
