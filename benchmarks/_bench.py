"""What the benchmark scripts share: planners run on problems through ``planbench.bench``.

A script that needs planners' results on problems builds a suite here and runs it with the
benchmark itself (isolated worker processes, time limits, the certified validation, a results
file), then reads the rows back; what the script adds is its own measurement on those rows.
Generated problems are written to a folder first, since workers load problems by reference.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.suite import PlannerEntry, Suite
from planbench.problem import Problem

__all__ = ["run_suite", "write_problems", "problem_by_id"]


def run_suite(
    name: str,
    problems: Sequence[str],
    planners: Mapping[str, tuple[str, Mapping[str, Any]]] | Sequence[str],
    *,
    seeds: Sequence[int] = (0,),
    time_limit: float = 5.0,
    jobs: int = 1,
    out: str | Path | None = None,
    resume: bool = False,
) -> list[dict[str, Any]]:
    """Rows (with ``path`` and ``times`` arrays) of ``planners`` x ``problems`` x ``seeds``.

    ``problems``: selectors (``"mbm:*/0001-0020"``, a folder of problem files); ``planners``: names,
    or ``{label: (planner, settings)}`` to run one planner under several settings. ``out``: keep the
    results file there (default: a temporary file, removed afterwards); ``resume``: run only the
    runs missing from ``out`` (else its runs of this suite are replaced).
    """
    entries = (
        tuple(PlannerEntry(label, planner, dict(settings)) for label, (planner, settings) in planners.items())
        if isinstance(planners, Mapping)
        else tuple(PlannerEntry(p, p) for p in planners)
    )
    suite = Suite(name=name, problems=tuple(problems), planners=entries, seeds=tuple(seeds), time_limit=time_limit)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(out) if out is not None else Path(tmp) / "results.db"
        run_benchmark(suite, path, jobs=jobs, resume=resume, overwrite=not resume)
        with ResultsDB(path, read_only=True) as db:
            return db.rows(name, with_arrays=True)


def write_problems(problems: Sequence[Problem], folder: str | Path) -> str:
    """Save ``problems`` as JSON files in ``folder``; returns it as a selector."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for k, p in enumerate(problems):
        p.save(folder / f"{k:04d}.json")
    return str(folder)


def problem_by_id(problems: Sequence[Problem]) -> dict[str, Problem]:
    return {p.id: p for p in problems}
