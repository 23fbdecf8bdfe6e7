"""The benchmark: suites of planners x problems x seeds, run in isolated worker processes into a
SQLite results database, summarized as tables, plots and reports, exported for OMPL's tools.

Library use::

    from planbench.bench import benchmark
    table = benchmark("smoke", out="results.db", jobs=2)   # a list of summary dicts, one per planner
    for row in table:
        print(row["planner"], row["success_rate"], row["planning_time_median"])

Command line: ``planbench bench --suite smoke``, ``planbench report results.db``,
``planbench export results.db --format planner-arena``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from planbench.bench.benchmark import BenchmarkOutcome, run_benchmark, select
from planbench.bench.db import ResultsDB
from planbench.bench.executors import make_executor
from planbench.bench.report import summarize
from planbench.bench.suite import PlannerEntry, Suite, SuiteFileError, load_suite, parse_suite

__all__ = [
    "BenchmarkOutcome",
    "PlannerEntry",
    "ResultsDB",
    "Suite",
    "SuiteFileError",
    "benchmark",
    "load_suite",
    "parse_suite",
    "run_benchmark",
    "summarize",
]


def benchmark(
    suite: Suite | str | Path = "smoke",
    *,
    out: str | Path = "results.db",
    jobs: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    planners: Sequence[str] | None = None,
    problems: Sequence[str] | None = None,
    seeds: Any = None,
    time_limit: float | None = None,
    settings: Mapping[str, Any] | None = None,
    by: Sequence[str] = ("planner",),
    executor: str = "local",
    address: str | None = None,
) -> list[dict[str, Any]]:
    """Run ``suite`` (a :class:`Suite`, a built-in name or a TOML file) and return its summary table.

    Same options as ``planbench bench``: results go to the SQLite file ``out``; ``jobs`` worker
    processes (default: all cores); ``resume`` runs only what ``out`` lacks; ``planners``,
    ``problems``, ``seeds`` and ``time_limit`` [s] narrow or change the suite; ``settings`` are planner
    settings given to every planner of it (parsed to their types before any run). The table has one
    dict per group of ``by`` (see :func:`planbench.bench.report.summarize`). ``executor="ray"`` runs
    on a Ray cluster (``address``; default a local Ray instance), see docs/benchmarking.md.
    """
    s = select(suite, planners, problems, seeds, time_limit, settings=settings)
    runner = make_executor(executor, jobs, address)
    try:
        run_benchmark(s, out, jobs=jobs, resume=resume, overwrite=overwrite, executor=runner)
    finally:
        runner.close()
    with ResultsDB(out, create=False) as db:
        return summarize(db.rows(s.name), by)
