"""PNG plots of a results database (matplotlib, headless Agg backend).

- ``ecdf_<metric>.png``: per planner, the empirical CDF of a metric over validated successes;
- ``box_<metric>.png``: the same data as box plots;
- ``success_by_family.png``: success rate per family and planner, with Wilson 95 % intervals;
- ``time_to_success.png``: fraction of all runs solved (validated) within a planning-time budget,
  per planner, against the budget [s] on a log axis.

Closed-loop runs get the closed-loop metrics' ECDFs and box plots and the plots of
:mod:`planbench.reactive.plots` (tick-time ECDF, success by speed and by sensing, clearance over
time).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planbench.bench.report import DYNAMIC_METRICS, Metric, metrics_for, wilson_interval

__all__ = ["write_plots", "time_to_success"]


def _pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend, imported on first use: it costs about half a second, which every
    ``planbench`` command (this module is loaded with the CLI) would otherwise pay."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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


def ecdf_plot(rows: Sequence[dict[str, Any]], m: Metric, path: Path) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for planner in _planners(rows):
        v = np.sort(_values(rows, planner, m))
        if v.size:
            ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=f"{planner} (n={v.size})")
    ax.set_xlabel(m.label)
    ax.set_ylabel("fraction of successful runs")
    ax.set_title(f"{m.label}: ECDF over " + ("every run" if m.over_all_runs else "validated successes"))
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def box_plot(rows: Sequence[dict[str, Any]], m: Metric, path: Path) -> None:
    plt = _pyplot()
    planners = _planners(rows)
    data = [_values(rows, p, m) for p in planners]
    fig, ax = plt.subplots(figsize=(max(4, 1.4 * len(planners) + 2), 4))
    keep = [(p, d) for p, d in zip(planners, data, strict=True) if d.size]
    if keep:
        ax.boxplot([d for _, d in keep], tick_labels=[f"{p}\n(n={d.size})" for p, d in keep])
    ax.set_ylabel(m.label)
    ax.set_title(f"{m.label} over " + ("every run" if m.over_all_runs else "validated successes"))
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def success_by_family(rows: Sequence[dict[str, Any]], path: Path) -> None:
    plt = _pyplot()
    planners = _planners(rows)
    families = sorted({r["family"] or "-" for r in rows})
    width = 0.8 / max(1, len(planners))
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(families) + 2), 4))
    x = np.arange(len(families))
    for i, planner in enumerate(planners):
        rates, lo, hi = [], [], []
        for fam in families:
            group = [r for r in rows if r["planner"] == planner and (r["family"] or "-") == fam]
            k = sum(1 for r in group if r["success"])
            n = len(group)
            rate = k / n if n else math.nan
            a, b = wilson_interval(k, n)
            rates.append(rate)
            lo.append(rate - a if n else 0)
            hi.append(b - rate if n else 0)
        ax.bar(x + (i - (len(planners) - 1) / 2) * width, rates, width, yerr=[lo, hi], capsize=2, label=planner)
    ax.set_xticks(x, families, rotation=30, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate (95% Wilson interval)")
    ax.set_title("validated success rate per family")
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def time_to_success_plot(rows: Sequence[dict[str, Any]], path: Path) -> None:
    plt = _pyplot()
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
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_plots(rows: Sequence[dict[str, Any]], folder: str | Path) -> list[Path]:
    """Write every plot of the module docstring into ``folder``; returns the files written."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    metrics = metrics_for(rows)
    if metrics is DYNAMIC_METRICS:  # closed-loop runs: their own plots besides the metrics'
        from planbench.reactive.plots import write_dynamic_plots

        files += write_dynamic_plots(rows, out)
    for m in metrics:
        for kind, fn in (("ecdf", ecdf_plot), ("box", box_plot)):
            p = out / f"{kind}_{m.name}.png"
            fn(rows, m, p)
            files.append(p)
    for name, fn2 in (("success_by_family", success_by_family), ("time_to_success", time_to_success_plot)):
        p = out / f"{name}.png"
        fn2(rows, p)
        files.append(p)
    return files
