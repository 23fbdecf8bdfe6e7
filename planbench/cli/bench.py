"""CLI subcommands of the benchmark: ``bench``, ``report`` and ``export``.

``planbench.cli.main`` calls :func:`add_commands` with its argparse subparsers; each command's ``func``
takes the parsed arguments and returns an exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from planbench.errors import InvalidConfigError, PlanbenchError
from planbench.files.inputs import check_writable
from planbench.files.outputs import check_output
from planbench.settings import parse_setting, settings_text

if TYPE_CHECKING:
    from planbench.bench.executors import Executor
    from planbench.bench.task import RunTask

EXECUTORS = ("local", "ray")
EXPERIMENT_GROUPS = ("family", "suite", "problem")
DEFAULT_MEMORY_LIMIT = 4096.0
"""The ``--executor`` and ``--experiments`` choices and the default memory limit [MiB]
(:data:`planbench.bench.executors.EXECUTORS`, :data:`planbench.bench.export.EXPERIMENT_GROUPS`,
:data:`planbench.bench.suite.DEFAULT_MEMORY_LIMIT`; a test holds them equal): written here, as
importing any part of :mod:`planbench.bench` imports its runner. The benchmark, report and
export modules are imported by the commands that use them: ``planbench --help`` stays fast."""

log = logging.getLogger(__name__)

__all__ = ["add_commands"]


def _csv_list(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


def _json_object(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"not JSON: {exc}") from exc
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("must be a JSON object")
    return value


def add_commands(subparsers: Any) -> None:
    """Add ``bench``, ``report`` and ``export`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "bench",
        help="run a benchmark suite (planners x problems x seeds) into a results database",
        description="Run every planner of a suite on every problem and seed, each run in an isolated "
        "worker process with hard time limits; every run is validated and written to a SQLite "
        "database as soon as it ends. Interrupted? Run the same command with --resume.",
    )
    p.add_argument("--suite", default="smoke", help="a built-in suite (smoke, mbm) or a suite .toml file")
    p.add_argument("--planners", type=_csv_list, help="comma-separated labels of the suite, or planner names to add")
    p.add_argument("--problems", nargs="+", metavar="SELECTOR", help="problem selectors replacing the suite's")
    p.add_argument("--seeds", help="a count (3), a list (0,1,5) or a range (0-9); 0 <= seed < 2**63")
    p.add_argument(
        "--jobs", "-j", type=int, default=0, help="worker processes (default, or 0: all cores, of the Ray cluster too)"
    )
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="where runs execute: local worker processes (default) or a Ray cluster (pip install 'planbench[ray]')",
    )
    p.add_argument(
        "--address",
        help="with --executor ray: the cluster ('auto', HOST:PORT, ray://HOST:10001); default: a Ray instance "
        "started here on 127.0.0.1",
    )
    p.add_argument(
        "--ray-runtime-env",
        type=_json_object,
        metavar="JSON",
        help="with --executor ray: Ray's runtime environment for the workers, e.g. "
        '\'{"py_modules": ["my_plugins"]}\' (plugins not installed on every node)',
    )
    p.add_argument("--time-limit", type=float, help="[s] planning time per run, a finite number > 0")
    p.add_argument(
        "--set",
        action="append",
        type=parse_setting,
        metavar="KEY=VALUE",
        help="a planner setting for every planner of the suite (repeatable), over the suite's own; read as "
        "the type of the planner's setting and checked before any run",
    )
    p.add_argument(
        "--memory-limit",
        metavar="MIB",
        help="address space per worker process [MiB], or 'none' (default: the suite's memory_limit, "
        f"{DEFAULT_MEMORY_LIMIT:g} MiB unless it sets one)",
    )
    p.add_argument(
        "--postprocess",
        metavar="STAGE",
        help="post-process every planner's valid path alike, on the harness's side: 'none' or 'shortcut' "
        "(certified shortcutting; default: the suite's postprocess, 'none' unless it sets one)",
    )
    p.add_argument("--out", default="results.db", help="results database (SQLite), default results.db")
    p.add_argument("--resume", action="store_true", help="run only the runs missing from --out")
    p.add_argument("--overwrite", action="store_true", help="delete this suite's runs in --out first")
    p.add_argument("--by", choices=("planner", "family"), default="planner", help="summary grouping")
    p.add_argument("--wide", action="store_true", help="one table with every column, whatever the terminal's width")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench)

    p = subparsers.add_parser(
        "report",
        help="summary tables (terminal, Markdown, CSV), plots and an HTML report of a results database",
    )
    p.add_argument("db", help="results database written by `planbench bench`")
    p.add_argument("--suite", help="only this suite (default: all suites in the database)")
    p.add_argument(
        "--problems",
        nargs="+",
        metavar="SELECTOR",
        help="only these problems (selectors as in bench, e.g. 'mbm:*/0021-0100': a held-out set)",
    )
    p.add_argument(
        "--by", choices=("planner", "family"), default="planner", help="group by planner, or planner and family"
    )
    p.add_argument("--wide", action="store_true", help="one table with every column, whatever the terminal's width")
    p.add_argument("--markdown", metavar="FILE", help="write the table as Markdown")
    p.add_argument("--csv", metavar="FILE", help="write the table as CSV (SI units)")
    p.add_argument("--plots", metavar="DIR", help="write the plots into DIR (per family with --by family)")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png", help="file format of --plots")
    p.add_argument("--html", metavar="FILE", help="write one self-contained HTML report")
    p.add_argument(
        "--replays", action="store_true", help="with --html: a 3D replay of every run, linked from the report"
    )
    p.set_defaults(func=cmd_report)

    p = subparsers.add_parser(
        "export",
        help="export a results database: OMPL benchmark logs, a Planner Arena database, CSV or Parquet of every run",
    )
    p.add_argument("db", help="results database written by `planbench bench`")
    p.add_argument("--format", required=True, choices=("ompl-log", "planner-arena", "csv", "parquet"))
    p.add_argument(
        "--out",
        help="output: a folder of .log files (ompl-log), a .db file (planner-arena), a .csv or .parquet file "
        "(default: next to the database)",
    )
    p.add_argument(
        "--paths", action="store_true", help="csv: add each run's path and time stamps (JSON lists) as columns"
    )
    p.add_argument("--suite", help="only this suite")
    p.add_argument(
        "--experiments",
        choices=EXPERIMENT_GROUPS,
        default="family",
        help="planner-arena, ompl-log: what one experiment (a 'problem' in Planner Arena) holds: every run of a "
        "problem family (default; a problem without one is its own), of a suite, or of one problem; each "
        "problem stays selectable as a problem parameter",
    )
    p.set_defaults(func=cmd_export)


def _by(choice: str) -> tuple[str, ...]:
    return ("planner", "family") if choice == "family" else ("planner",)


def _bench_suite(args: argparse.Namespace) -> Any:
    """The suite the ``bench`` options ask for; every option is checked before any file is touched."""
    from planbench.bench.benchmark import select
    from planbench.bench.postprocess import PostprocessSettingError, PostprocessSettings
    from planbench.bench.suite import check_seconds, parse_memory_limit

    if args.jobs < 0:
        raise InvalidConfigError(f"--jobs must be >= 1 (or 0: all cores), got {args.jobs}")
    if args.time_limit is not None:
        check_seconds(args.time_limit, "--time-limit")
    if args.planners is not None and not args.planners:
        raise InvalidConfigError("--planners names no planner: give comma-separated labels or planner names")
    if args.resume and args.overwrite:
        raise InvalidConfigError("--resume keeps the stored runs and --overwrite deletes them: give one of them")
    text = settings_text(args.set)
    suite = select(args.suite, args.planners, args.problems, args.seeds, args.time_limit, text_settings=text)
    if args.memory_limit is not None:
        suite = suite.with_changes(memory_limit=parse_memory_limit(args.memory_limit))
    if args.postprocess is not None:
        stage = {**suite.postprocess, "method": args.postprocess}
        try:
            PostprocessSettings(**stage)
        except PostprocessSettingError as exc:
            raise PostprocessSettingError(f"--postprocess: {exc}") from None
        suite = suite.with_changes(postprocess=stage)
    return suite


def _stored_count(path: str, suite: str) -> int:
    """Runs of ``suite`` in the results file (0 when there is none yet), read without writing."""
    from planbench.bench.db import ResultsDB

    if not Path(path).is_file():
        return 0
    with ResultsDB(path, read_only=True) as db:
        return db.count(suite)


def cmd_bench(args: argparse.Namespace) -> int:
    from planbench.bench.executors import make_executor

    console = Console(stderr=False)
    suite = _bench_suite(args)
    executor = make_executor(args.executor, args.jobs, args.address, args.ray_runtime_env)
    try:
        return _bench(args, suite, executor, console)
    finally:
        executor.close()


def _where(executor: Executor) -> tuple[str, str]:
    """Where the runs execute, as a phrase and as the progress bar's label. A Ray executor connects
    here: a missing Ray or an unreachable cluster is reported before any file is touched."""
    from planbench.bench.runner import Runner

    if isinstance(executor, Runner):
        return f"on {executor.jobs} worker process{'es' if executor.jobs > 1 else ''}", "benchmark"
    info = executor.connect()  # type: ignore[attr-defined]
    return f"on the {info.describe()}", f"ray: {info.size()}"


def _bench(args: argparse.Namespace, suite: Any, executor: Executor, console: Any) -> int:
    from planbench.bench.benchmark import run_benchmark
    from planbench.bench.db import ResultsDB
    from planbench.bench.report import failures, metrics_for, summarize, to_rich

    where, label = _where(executor)
    progress = _Progress(console, enabled=not args.no_progress)

    def on_start(n: int, done: int, skipped: list[str]) -> None:
        for why in skipped:
            console.print(f"[yellow]skipping optional planner[/yellow] {escape(why)}", highlight=False)
        memory = f"{suite.memory_limit:g} MiB" if suite.memory_limit else "none"
        console.print(
            f"suite [bold]{escape(suite.name)}[/bold]: {n + done} runs ({done} already in {escape(args.out)}, "
            f"{n} to run) {where}, time limit {suite.time_limit:g} s, "
            f"memory limit {memory} per worker",
            highlight=False,
        )
        progress.start(n, label)

    try:
        outcome = run_benchmark(
            suite,
            args.out,
            resume=args.resume,
            overwrite=args.overwrite,
            on_record=progress.update,
            on_start=on_start,
            executor=executor,
        )
    except KeyboardInterrupt:
        progress.stop()
        n = _stored_count(args.out, suite.name)
        console.print(
            f"interrupted: {n} runs of suite {escape(suite.name)!r} are in {escape(args.out)}; "
            "run the same command with --resume to do only the missing ones"
        )
        return 130
    progress.stop()
    console.print(f"{outcome.ran} runs in {outcome.wall_time:.1f} s (wall), results in {escape(args.out)}")
    with ResultsDB(args.out, read_only=True) as db:
        rows = db.rows(suite.name)
    metrics = metrics_for(rows, terminal=True)
    summary = summarize(rows, _by(args.by), metrics)
    console.print(
        to_rich(
            summary, _by(args.by), title=f"suite {suite.name}", metrics=metrics, width=console.width, wide=args.wide
        )
    )
    for line in failures(rows, limit=10):
        console.print(escape(line), highlight=False)
    console.print(f"more: planbench report {escape(args.out)} --by family --html report.html")
    return 0


class _Progress:
    """A rich progress bar with counts of validated successes and failures."""

    def __init__(self, console: Any, enabled: bool = True) -> None:
        self.console = console
        self.enabled = enabled
        self.bar: Any = None
        self.counts = {"solved": 0, "failed": 0, "error": 0, "timeout": 0, "crash": 0}

    def start(self, total: int, label: str = "benchmark") -> None:
        if not self.enabled or total == 0:
            return
        self.bar = Progress(
            TextColumn("[progress.description]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn(
                "[green]{task.fields[solved]} solved[/green] [red]{task.fields[failed]} failed[/red]{task.fields[bad]}"
            ),
            TimeElapsedColumn(),
            console=self.console,
        )
        self.bar.start()
        self.task = self.bar.add_task(label, total=total, solved=0, failed=0, bad="")

    def update(self, task: RunTask, record: dict[str, Any]) -> None:
        ev = record["evaluation"]
        self.counts["solved" if ev["success"] else "failed"] += 1
        if ev["status"] in ("error", "timeout", "crash"):
            self.counts[ev["status"]] += 1
        if self.bar is None:
            return
        bad = ", ".join(f"{self.counts[k]} {k}" for k in ("error", "timeout", "crash") if self.counts[k])
        self.bar.update(
            self.task,
            advance=1,
            solved=self.counts["solved"],
            failed=self.counts["failed"],
            bad=f" ({bad})" if bad else "",
        )

    def stop(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None


@contextlib.contextmanager
def _writing(path: str | Path) -> Iterator[None]:
    """Turn a failure to write ``path`` (a missing folder, no permission, a full disk) into a
    named error instead of a traceback after all the work was done."""
    try:
        yield
    except OSError as exc:
        raise PlanbenchError(f"cannot write {path}: {exc.strerror or exc}") from exc


def cmd_report(args: argparse.Namespace) -> int:
    from planbench.bench.db import ResultsDB
    from planbench.bench.html import write_html
    from planbench.bench.plots import write_plots
    from planbench.bench.report import (
        DYNAMIC_METRICS,
        certificate_rows,
        failures,
        metrics_for,
        summarize,
        to_csv,
        to_markdown,
        to_rich,
    )

    console = Console()
    for out in (args.markdown, args.csv, args.html):
        if out:
            check_writable(out)  # before the work: a folder or a FIFO nobody reads would fail or block at the end
    for out in (args.markdown, args.csv, args.plots, args.html):
        if out:
            check_output(out, [args.db])
    with ResultsDB(args.db, read_only=True) as db:
        rows = db.rows(args.suite)
        if rows and ((args.plots or args.html) and metrics_for(rows) is DYNAMIC_METRICS or args.replays):
            rows = db.rows(args.suite, with_arrays=True)  # trajectories: the clearance plot, the replays
    if args.problems:
        from planbench.bench.suite import expand_problems

        wanted = {ref.id for ref in expand_problems(args.problems)}
        rows = [row for row in rows if row["problem"] in wanted]
    if not rows:
        console.print(
            f"{escape(args.db)} holds no runs"
            + (f" of suite {escape(args.suite)!r}" if args.suite else "")
            + (f" of problems {' '.join(args.problems)}" if args.problems else "")
        )
        return 1
    by = _by(args.by)
    tabled = [*rows, *certificate_rows(rows)]  # the certificates' line in the tables, not in the plots
    summary = summarize(tabled, by)
    terminal = metrics_for(rows, terminal=True)
    console.print(
        to_rich(
            summarize(tabled, by, terminal),
            by,
            title=f"{args.db}: {len(rows)} runs",
            metrics=terminal,
            width=console.width,
            wide=args.wide,
        )
    )
    for line in failures(rows, limit=10):
        console.print(escape(line), highlight=False)
    if args.markdown:
        with _writing(args.markdown):
            Path(args.markdown).write_text(to_markdown(summary, by, metrics_for(rows)))
        console.print(f"Markdown table written to {escape(args.markdown)}")
    if args.csv:
        with _writing(args.csv):
            Path(args.csv).write_text(to_csv(summary))
        console.print(f"CSV table written to {escape(args.csv)}")
    if args.plots:
        with _writing(args.plots):
            files = write_plots(rows, args.plots, args.format, "family" if "family" in by else "planner")
        console.print(f"{len(files)} plots written to {escape(args.plots)}")
    if args.html:
        with _writing(args.html):
            with ResultsDB(args.db, read_only=True) as db:
                stored = {name: db.suite_settings(name) for name in {r["suite"] for r in rows}}
            suites = {k: v for k, v in stored.items() if v is not None}
            title = f"planbench report: {Path(args.db).name}"
            write_html(rows, args.html, title=title, suites=suites, replays=args.replays)
        console.print(f"HTML report written to {escape(args.html)}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from planbench.bench import export
    from planbench.bench.db import ResultsDB
    from planbench.bench.results import write_parquet

    db_path = Path(args.db)
    default = {
        "ompl-log": db_path.with_suffix("").as_posix() + "-ompl-logs",
        "planner-arena": db_path.with_suffix("").as_posix() + "-plannerarena.db",
        "csv": db_path.with_suffix(".csv").as_posix(),
        "parquet": db_path.with_suffix(".parquet").as_posix(),
    }[args.format]
    if args.format != "ompl-log":  # (a folder of logs)
        check_writable(args.out or default)
    out = check_output(args.out or default, [db_path])
    arrays = args.format == "parquet" or (args.format == "csv" and args.paths)
    with ResultsDB(db_path, read_only=True) as db:
        rows = db.rows(args.suite, with_arrays=arrays)
    if not rows:
        print(f"{db_path} holds no runs" + (f" of suite {args.suite!r}" if args.suite else "") + "; nothing exported")
        return 1
    with _writing(out):
        if args.format == "ompl-log":
            files = export.write_ompl_logs(rows, out, by=args.experiments)
            print(
                f"{len(files)} OMPL benchmark logs written to {out} "
                f"(one per problem, experiments per {args.experiments})"
            )
        elif args.format == "planner-arena":
            export.write_planner_arena(rows, out, by=args.experiments)
            n = len({e["name"] for e in export.experiments(rows, args.experiments)})
            print(
                f"Planner Arena database written to {out}: {n} experiment(s), one per {args.experiments} "
                f"(open it with `DATABASE={out} plannerarena`)"
            )
        elif args.format == "parquet":
            write_parquet(rows, out)
            print(f"{len(rows)} runs written to {out} (paths as nested lists; pandas.read_parquet reads it)")
        else:
            export.write_runs_csv(rows, out, paths=args.paths)
            print(f"{len(rows)} runs written to {out}" + (" with their paths" if args.paths else ""))
    return 0
