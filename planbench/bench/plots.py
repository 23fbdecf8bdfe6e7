"""Plots of a results database (matplotlib, headless Agg backend): PNG at 150 dpi, PDF or SVG.

- ``ecdf_<metric>``: per planner, the empirical CDF of a metric over validated successes
  (``Axes.ecdf``: every curve starts at 0, a planner with one success is a visible step); with
  ``by="family"`` one panel per family;
- ``box_<metric>``: the same data as box plots, grouped by family with ``by="family"``;
- ``success_by_family``: success rate per family and planner, with Wilson 95 % intervals; every
  bar labelled ``k/n``, so a 0 % bar reads as such and not as missing data;
- ``time_to_success``: fraction of all runs solved (validated) within a planning-time budget,
  per planner, against the budget [s] on a log axis.

Closed-loop runs get the closed-loop metrics' ECDFs and box plots and the plots of
:mod:`planbench.bench.closed_loop_plots` (tick-time ECDF, success by speed and by sensing, clearance over
time).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planbench.bench.report import DYNAMIC_METRICS, Metric, metrics_for
from planbench.visual.plots import pyplot, save, success_bar

__all__ = ["time_to_success", "write_plots"]


def _planners(rows: Sequence[dict[str, Any]]) -> list[str]:
    return sorted({r["planner"] for r in rows})


def _values(rows: Sequence[dict[str, Any]], planner: str, m: Metric) -> np.ndarray:
    v = [r[m.name] * m.scale for r in rows if r["planner"] == planner and (r["success"] or m.over_all_runs)]
    a = np.asarray(v, dtype=float)
    return a[np.isfinite(a)]


def time_to_success(rows: Sequence[dict[str, Any]], planner: str, budgets: np.ndarray) -> np.ndarray:
    """Fraction of ``planner``'s runs that are validated successes with planning time <= each budget [s]."""
    mine = [r for r in rows if r["planner"] == planner]
    if not mine:
        return np.zeros_like(budgets)
    times = np.sort([r["planning_time"] for r in mine if r["success"] and math.isfinite(r["planning_time"])])
    return np.searchsorted(times, budgets, side="right") / len(mine)


FORMATS = ("png", "pdf", "svg")


def _ecdf_axes(ax: Any, rows: Sequence[dict[str, Any]], m: Metric, planners: Sequence[str]) -> None:
    for i, planner in enumerate(planners):
        v = _values(rows, planner, m)
        if v.size:
            ax.ecdf(v, label=f"{planner} (n={v.size})", color=f"C{i}")
    if not ax.get_lines():
        ax.text(0.5, 0.5, "no run to show", transform=ax.transAxes, ha="center", va="center", color="0.4")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)


def ecdf_plot(rows: Sequence[dict[str, Any]], m: Metric, path: Path, by: str = "planner") -> None:
    plt = pyplot()
    planners = _planners(rows)
    over = "every run" if m.over_all_runs else "validated successes"
    families = _families(rows) if by == "family" else ["all"]
    cols = min(3, len(families))
    nrows = math.ceil(len(families) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5 * cols, 3.6 * nrows), squeeze=False)
    for ax, family in zip(axes.flat, families, strict=False):
        mine = rows if family == "all" else [r for r in rows if (r["family"] or "-") == family]
        _ecdf_axes(ax, mine, m, planners)
        ax.set_title(family if by == "family" else f"{m.label}: ECDF over {over}", fontsize="medium")
        ax.set_xlabel(m.label)
        ax.set_ylabel(f"fraction of {'runs' if m.over_all_runs else 'successes'}")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="x-small")
    for ax in list(axes.flat)[len(families) :]:
        ax.set_visible(False)
    if by == "family":
        fig.suptitle(f"{m.label}: ECDF over {over}, per family")
    save(fig, path)


def box_plot(rows: Sequence[dict[str, Any]], m: Metric, path: Path, by: str = "planner") -> None:
    plt = pyplot()
    planners = _planners(rows)
    families = _families(rows) if by == "family" else ["all"]
    groups = [(f, p) for f in families for p in planners]
    data = [_values(rows if f == "all" else [r for r in rows if (r["family"] or "-") == f], p, m) for f, p in groups]
    fig, ax = plt.subplots(figsize=(max(4, 0.9 * len(groups) + 2), 4.2))
    keep = [(g, d) for g, d in zip(groups, data, strict=True) if d.size]
    if keep:
        labels = [f"{p}\n(n={d.size})" if f == "all" else f"{f}\n{p}\n(n={d.size})" for (f, p), d in keep]
        parts = ax.boxplot([d for _, d in keep], tick_labels=labels, patch_artist=True)
        for patch, ((_, p), _) in zip(parts["boxes"], keep, strict=True):
            patch.set_facecolor(f"C{planners.index(p)}")
            patch.set_alpha(0.5)
        ax.tick_params(axis="x", labelsize="x-small", labelrotation=30 if by == "family" else 0)
    over = "every run" if m.over_all_runs else "validated successes"
    ax.set_ylabel(m.label)
    ax.set_title(f"{m.label} over {over}" + (", per family" if by == "family" else ""))
    ax.grid(alpha=0.3, axis="y")
    save(fig, path)


def _families(rows: Sequence[dict[str, Any]]) -> list[str]:
    return sorted({r["family"] or "-" for r in rows})


def success_by_family(rows: Sequence[dict[str, Any]], path: Path) -> None:
    plt = pyplot()
    planners = _planners(rows)
    families = _families(rows)
    width = 0.8 / max(1, len(planners))
    fig, ax = plt.subplots(figsize=(max(6, 1.4 * len(families) + 2), 4.2))
    x = np.arange(len(families))
    for i, planner in enumerate(planners):
        for xi, fam in zip(x + (i - (len(planners) - 1) / 2) * width, families, strict=True):
            group = [r for r in rows if r["planner"] == planner and (r["family"] or "-") == fam]
            success_bar(ax, xi, group, width, i, planner if fam == families[0] else None)
    ax.set_xticks(x, families, rotation=30, ha="right")
    ax.set_ylim(0, 1.12)
    ax.set_ylabel("success rate (95% Wilson interval)")
    ax.set_title("validated success rate per family (bars labelled solved/runs)")
    ax.legend(fontsize="small")
    save(fig, path)


def time_to_success_plot(rows: Sequence[dict[str, Any]], path: Path) -> None:
    plt = pyplot()
    times = [r["planning_time"] for r in rows if r["success"] and math.isfinite(r["planning_time"])]
    limit = max((r["time_limit"] for r in rows if r.get("time_limit") and math.isfinite(r["time_limit"])), default=1.0)
    lo = max(1e-5, min(times) / 2) if times else 1e-4
    budgets = np.geomspace(lo, max(limit, lo * 10), 200)
    fig, ax = plt.subplots(figsize=(6, 4))
    for planner in _planners(rows):
        ax.step(budgets, time_to_success(rows, planner, budgets), where="post", label=planner)
    ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("planning time budget [s]")
    ax.set_ylabel("fraction of runs solved")
    ax.set_title("time to success")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="small")
    save(fig, path)


def write_plots(
    rows: Sequence[dict[str, Any]], folder: str | Path, fmt: str = "png", by: str = "planner"
) -> list[Path]:
    """Write every plot of the module docstring into ``folder`` as ``fmt`` (png, pdf or svg),
    per family where ``by="family"``; returns the files written."""
    if fmt not in FORMATS:
        raise ValueError(f"plot format must be one of {FORMATS}, got {fmt!r}")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    metrics = metrics_for(rows)
    if metrics is DYNAMIC_METRICS:  # closed-loop runs: their own plots besides the metrics'
        from planbench.bench.closed_loop_plots import write_dynamic_plots

        files += write_dynamic_plots(rows, out, fmt)
    for m in metrics:
        for kind, fn in (("ecdf", ecdf_plot), ("box", box_plot)):
            p = out / f"{kind}_{m.name}.{fmt}"
            fn(rows, m, p, by)
            files.append(p)
    for name, fn2 in (("success_by_family", success_by_family), ("time_to_success", time_to_success_plot)):
        p = out / f"{name}.{fmt}"
        fn2(rows, p)
        files.append(p)
    return files
