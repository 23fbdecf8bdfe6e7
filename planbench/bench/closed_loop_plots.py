"""Plots of closed-loop runs (matplotlib, Agg; PNG, PDF or SVG), written by ``planbench report --plots`` and the HTML
report for closed-loop suites:

- ``tick_time_ecdf``: per controller, the ECDF of its compute time per tick it ran (every tick
  of every run pooled; ``Axes.ecdf``), on a log axis with the control period and 1 ms marked;
- ``success_by_speed``, ``success_by_sensing``: success rate per obstacle speed and per
  sensing model (shipped scenario names: ``dynamic:<robot>_<behaviour>_<speed>_<sensing>/N``),
  with Wilson 95 % intervals and every bar labelled ``k/n`` (a 0 % bar is visible as such);
- ``clearance_<scenario>``: the distance between the arm and the true obstacles over time in
  one scenario, one line per controller (recomputed from each run's trajectory).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planbench.visual.plots import pyplot, save, success_bar

__all__ = ["clearance_over_time", "scenario_keys", "success_by", "tick_time_ecdf", "write_dynamic_plots"]

_NAME = re.compile(r"^dynamic:(?P<robot>[a-z0-9]+)_(?P<behaviour>[a-z]+)_(?P<speed>[a-z]+)_(?P<sensing>[a-z]+)/\d+$")


def scenario_keys(problem: str) -> dict[str, str]:
    """``robot``, ``behaviour``, ``speed``, ``sensing`` of a shipped scenario's name (empty otherwise)."""
    m = _NAME.match(problem)
    return m.groupdict() if m else {}


def _controllers(rows: Sequence[dict[str, Any]]) -> list[str]:
    return sorted({r["planner"] for r in rows})


def _ticks(row: dict[str, Any]) -> np.ndarray:
    info = row.get("info")
    if isinstance(info, str):
        try:
            info = json.loads(info)
        except ValueError:
            return np.zeros(0)
    values = (info or {}).get("measured") or []
    a = np.array([v for v in values if v is not None], dtype=float)
    return a[np.isfinite(a) & (a > 0)]


def tick_time_ecdf(rows: Sequence[dict[str, Any]], path: Path, period: float = 0.01) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for c in _controllers(rows):
        ticks = np.concatenate([_ticks(r) for r in rows if r["planner"] == c] or [np.zeros(0)])
        if ticks.size:
            ax.ecdf(ticks * 1e3, label=f"{c} ({ticks.size} ticks)")
    for x, text in ((period * 1e3, "control period"), (1.0, "1 ms")):
        ax.axvline(x, color="0.4", lw=0.8, ls="--")
        ax.text(x, 0.02, f" {text}", fontsize="small", color="0.3")
    ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("compute per tick [ms] (update + step)")
    ax.set_ylabel("fraction of ticks")
    ax.set_title("controller compute time per tick (ECDF)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="small")
    save(fig, path)


def success_by(rows: Sequence[dict[str, Any]], key: str, path: Path) -> bool:
    """Bars of the success rate per ``key`` (``speed`` or ``sensing``) and controller; False (and
    no file) when no row is a shipped scenario."""
    pairs = [(scenario_keys(r["problem"]).get(key), r) for r in rows]
    keyed = [(k, r) for k, r in pairs if k]
    if not keyed:
        return False
    order = {"slow": 0, "medium": 1, "fast": 2, "truth": 0, "depth": 1}
    groups = sorted({k for k, _ in keyed}, key=lambda k: (order.get(k, 9), k))
    controllers = _controllers([r for _, r in keyed])
    plt = pyplot()
    width = 0.8 / max(1, len(controllers))
    fig, ax = plt.subplots(figsize=(max(6, 1.6 * len(groups) + 3), 4))
    x = np.arange(len(groups))
    for i, c in enumerate(controllers):
        pos = x + (i - (len(controllers) - 1) / 2) * width
        for xi, g in zip(pos, groups, strict=True):
            members = [r for k, r in keyed if k == g and r["planner"] == c]
            success_bar(ax, xi, members, width, i, c if g == groups[0] else None)
    ax.set_xticks(x, groups)
    ax.set_ylim(0, 1.12)
    ax.set_xlabel({"speed": "obstacle speed", "sensing": "sensing model"}.get(key, key))
    ax.set_ylabel("success rate (95% Wilson interval)")
    ax.set_title(f"closed-loop success by {key}")
    ax.legend(fontsize="small", loc="upper right")
    save(fig, path)
    return True


def clearance_over_time(scenario: Any, runs: dict[str, tuple[np.ndarray, np.ndarray]], path: Path) -> None:
    """The arm's distance to the true obstacles [mm] at every tick of each run (``label: (times,
    path)``) in ``scenario``; a collision shows as the line ending below zero."""
    from planbench.reactive.checker import TickChecker

    checker = TickChecker(scenario)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, (times, path_q) in runs.items():
        d = np.array([checker.clearance(q, t) for t, q in zip(times, path_q, strict=True)])
        ax.plot(times, np.where(np.isfinite(d), d, np.nan) * 1e3, label=label, lw=1.2)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("clearance to the true obstacles [mm]")
    ax.set_title(f"{scenario.name}: clearance over time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    save(fig, path)


def write_dynamic_plots(rows: Sequence[dict[str, Any]], folder: str | Path, fmt: str = "png") -> list[Path]:
    """The plots of the module docstring for closed-loop ``rows`` (with arrays for the clearance
    plot: ``ResultsDB.rows(with_arrays=True)``); returns the files written."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    p = out / f"tick_time_ecdf.{fmt}"
    tick_time_ecdf(rows, p)
    files.append(p)
    for key in ("speed", "sensing"):
        p = out / f"success_by_{key}.{fmt}"
        if success_by(rows, key, p):
            files.append(p)
    with_paths = [r for r in rows if r.get("path") is not None and r.get("times") is not None]
    if with_paths:
        first = sorted({r["problem"] for r in with_paths})[0]
        try:
            from planbench.reactive.sets import load_scenario

            scenario = load_scenario(first)
        except Exception:  # a scenario file not found by its name: no clearance plot, the rest stands
            return files
        runs = {
            r["planner"]: (np.asarray(r["times"]), np.asarray(r["path"])) for r in with_paths if r["problem"] == first
        }
        p = out / f"clearance_{re.sub(r'[^A-Za-z0-9_.-]+', '_', first)}.{fmt}"
        clearance_over_time(scenario, runs, p)
        files.append(p)
    return files
