"""The replay of a run of a results file: its row, its problem or scenario, the 3D page
(:mod:`planbench.visual.replay`), its panel filled from the row."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from planbench.bench.db import ResultsDB
from planbench.errors import PlanbenchError
from planbench.visual.replay import ReplayInfo, write_replay

__all__ = ["replay_row", "replay_run", "replay_scenario"]


def replay_run(db_path: str | Path, run_id: int, out: str | Path) -> Path:
    """The replay of run ``run_id`` of a results file (:func:`replay_row`)."""
    with ResultsDB(db_path, read_only=True) as db:
        rows = [r for r in db.rows(with_arrays=True) if r["id"] == run_id]
    if not rows:
        raise PlanbenchError(f"{db_path} holds no run with id {run_id} (planbench export --format csv lists them)")
    return replay_row(rows[0], out)


def replay_row(row: dict[str, Any], out: str | Path) -> Path:
    """The replay of a results-file row read with its arrays: a planner's path on its problem, or
    a closed-loop run among its scenario's moving obstacles; a run without a path shows the
    problem's start. The page's panel holds the row's verdict and metrics (:class:`ReplayInfo`)."""
    verdict = "success" if row["success"] else str(row["failure"])
    title = f"{row['planner']} on {row['problem']}, seed {row['seed']}: {verdict}"
    info = ReplayInfo.from_row(row)
    if row.get("deadline_misses") is not None:  # a closed-loop run: its scenario, moving obstacles and all
        from planbench.reactive.sets import load_scenario  # on use: the closed-loop side

        return replay_scenario(out, load_scenario(row["problem"]), row.get("path"), row.get("times"), title, info)
    from planbench.problems.datasets import load_problem

    return write_replay(out, load_problem(row["problem"]), row.get("path"), row.get("times"), title=title, info=info)


def replay_scenario(
    out: str | Path, scenario: Any, path: Any, times: Any, title: str, info: ReplayInfo | None = None
) -> Path:
    """The replay of a timed trajectory in a scenario: the arm among the obstacles, the moving
    ones where they are at each time (a closed-loop run, a solvability certificate)."""
    from planbench.reactive.checker import TickChecker  # on use: the closed-loop side

    moving = TickChecker(scenario)
    geometry = moving.checker.geometry_model
    return write_replay(
        out, scenario.problem, path, times, geometry=geometry, place=moving.place, title=title, info=info
    )
