"""Summary tables of a results database: per planner (and per family), success rate with a Wilson
confidence interval, and the median and quartiles of each metric over the runs that succeeded.

Success is planbench's validated success (the path was re-checked), never the planner's claim.
Metrics of failed runs are left out of the medians (a failed run's path length means nothing);
the status counts say how runs failed. Two failures with a valid path are named apart: ``late``
(an answer after the time limit, a ``timeout`` row) and ``claimed-failure`` (the planner reported a
failure status with a path that validates), so that neither hides among the other reasons.
"""

from __future__ import annotations

import collections
import csv
import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rich.console import Group
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from planbench.files.outputs import csv_cell
from planbench.metrics import wilson_interval

__all__ = [
    "CERTIFICATE",
    "certificate_rows",
    "summary_cells",
    "summary_headers",
    "DYNAMIC_METRICS",
    "METRICS",
    "PROCESSED_METRICS",
    "Metric",
    "metrics_for",
    "summarize",
    "to_markdown",
    "to_csv",
    "to_rich",
]


@dataclass(frozen=True)
class Metric:
    """A column of the results: its name, a label with display unit, and the SI-to-display factor."""

    name: str
    label: str
    scale: float = 1.0
    short: str = ""
    lower_is_better: bool = True
    over_all_runs: bool = False
    """Summarised over every run (compute times) rather than over validated successes only."""


METRICS: tuple[Metric, ...] = (
    Metric("planning_time", "planning time [ms]", 1e3, "time [ms]"),
    Metric("setup_time", "setup time [ms]", 1e3, "setup [ms]"),
    Metric("joint_path_length", "joint path length [rad]", 1.0, "joint len [rad]"),
    Metric("ee_path_length", "EE path length [m]", 1.0, "EE len [m]"),
    Metric("min_clearance", "min clearance [mm]", 1e3, "clearance [mm]", lower_is_better=False),
    Metric("duration", "duration at velocity limits [s]", 1.0, "duration [s]"),
    Metric("duration_limited", "duration at velocity and acceleration limits [s]", 1.0, "timed [s]"),
)
TERMINAL_METRICS = tuple(m for m in METRICS if m.name != "setup_time")
PROCESSED_METRICS: tuple[Metric, ...] = (
    Metric("processed_joint_path_length", "processed joint path length [rad]", 1.0, "pp joint len [rad]"),
    Metric("processed_ee_path_length", "processed EE path length [m]", 1.0, "pp EE len [m]"),
    Metric("processed_min_clearance", "processed min clearance [mm]", 1e3, "pp clearance [mm]", lower_is_better=False),
    Metric(
        "processed_duration_limited", "processed duration at velocity and acceleration limits [s]", 1.0, "pp timed [s]"
    ),
    Metric("postprocess_time", "post-processing time [ms]", 1e3, "pp time [ms]"),
)
"""The columns of the post-processing stage (planbench.bench.postprocess), beside the raw ones, in a
table of runs of which any has a processed path."""
DYNAMIC_METRICS: tuple[Metric, ...] = (
    Metric("time_to_goal", "time to goal [s]", 1.0, "to goal [s]"),
    Metric("min_clearance", "min clearance [mm]", 1e3, "clearance [mm]", lower_is_better=False),
    Metric("path_length", "path length [rad]", 1.0, "length [rad]"),
    Metric("stalled_time", "stalled time [s]", 1.0, "stalled [s]", over_all_runs=True),
    Metric("unobserved_motion", "motion through unknown space [s]", 1.0, "unobserved [s]", over_all_runs=True),
    Metric("tick_time_median", "tick time, median [ms]", 1e3, "tick [ms]", over_all_runs=True),
    Metric("tick_time_p99", "tick time, p99 [ms]", 1e3, "tick p99 [ms]", over_all_runs=True),
    Metric("deadline_misses", "deadline misses", 1.0, "misses", over_all_runs=True),
    Metric("field_update_time", "field update per frame [ms]", 1e3, "update [ms]", over_all_runs=True),
)
"""The columns of closed-loop runs (planbench.reactive): compute times over every run, the rest
over validated successes."""


CERTIFICATE = "certificate"
"""The label of the rows that stand for the scenarios' solvability certificates in a table."""


def certificate_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row labelled :data:`CERTIFICATE` per scenario of closed-loop ``rows`` (per suite): a
    success with the certificate's time to goal where the scenario holds one, else a failure (no
    certificate). None at all when no scenario holds one, or the rows are not closed-loop runs.
    Summarised with the runs, it puts the time an omniscient planner needs beside each
    controller's (the certificate as the scenario file holds it: ``planbench check-scenario``
    verifies it)."""
    if metrics_for(rows) is not DYNAMIC_METRICS:
        return []
    from planbench.errors import PlanbenchError
    from planbench.reactive.sets import load_scenario  # on use: the closed-loop side

    out: list[dict[str, Any]] = []
    seen: set[tuple[Any, Any]] = set()
    for r in rows:
        key = (r.get("suite"), r["problem"])
        if key in seen:
            continue
        seen.add(key)
        try:
            cert = load_scenario(str(r["problem"])).certificate
        except PlanbenchError:  # a scenario no longer found: no line for it
            continue
        found = cert is not None
        out.append(
            {
                "suite": r.get("suite"),
                "problem": r["problem"],
                "family": r.get("family"),
                "planner": CERTIFICATE,
                "seed": 0,
                "success": found,
                "status": "success" if found else "no_certificate",
                "deadline_misses": 0,
                "time_to_goal": cert.time_to_goal if cert is not None else math.nan,
            }
        )
    return out if any(r["success"] for r in out) else []


def metrics_for(rows: Sequence[dict[str, Any]], terminal: bool = False) -> tuple[Metric, ...]:
    """:data:`DYNAMIC_METRICS` for closed-loop runs, else the static ones (terminal: no setup time),
    followed by :data:`PROCESSED_METRICS` where any run has a processed path."""
    if rows and all(r.get("deadline_misses") is not None for r in rows):
        return DYNAMIC_METRICS
    raw = TERMINAL_METRICS if terminal else METRICS
    if any(_finite(r.get("processed_joint_path_length")) for r in rows):
        return raw + PROCESSED_METRICS
    return raw


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


FAILURE_STATUSES = ("error", "timeout", "crash")
VALID_PATH_FAILURES = ("late", "claimed_failure")
"""Counts of :func:`summarize` for failed runs whose path is valid (see :func:`valid_path_failure`)."""
LOCATED = ("collision", "unseen-collision", "self-collision", "claimed-failure")
"""Failure reasons counted with their detail (a link, the status claimed) by :func:`failure_text`."""


def _quartiles(values: Sequence[float]) -> tuple[float, float, float]:
    a = np.asarray([v for v in values if v is not None and not math.isnan(v)], dtype=float)
    if a.size == 0:
        return (math.nan, math.nan, math.nan)
    q1, med, q3 = np.percentile(a, [25, 50, 75])
    return (float(med), float(q1), float(q3))


def summarize(
    rows: Sequence[dict[str, Any]], by: Sequence[str] = ("planner",), metrics: Sequence[Metric] | None = None
) -> list[dict[str, Any]]:
    """One summary dict per group of ``rows`` (grouped by the columns ``by``), in first-seen order.

    Keys: the ``by`` columns, ``runs``, ``solved``, ``success_rate``, ``success_ci_low``,
    ``success_ci_high``, a count per failure status (``error``, ``timeout``, ``crash``), the counts of
    :data:`VALID_PATH_FAILURES` (``late``, ``claimed_failure``), and for
    each metric ``<name>_median``, ``<name>_q1``, ``<name>_q3`` in SI units over solved runs (over
    every run for a metric ``over_all_runs``). ``metrics``: by default :func:`metrics_for` the rows.
    """
    metrics = metrics_for(rows) if metrics is None else metrics
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(c, "") for c in by), []).append(r)
    out = []
    for key, members in sorted(groups.items(), key=lambda kv: tuple(str(k) for k in kv[0])):
        n = len(members)
        solved = [r for r in members if r["success"]]
        lo, hi = wilson_interval(len(solved), n)
        s: dict[str, Any] = dict(zip(by, key, strict=True))
        s.update(runs=n, solved=len(solved), success_rate=len(solved) / n, success_ci_low=lo, success_ci_high=hi)
        for status in FAILURE_STATUSES:
            s[status] = sum(1 for r in members if r["status"] == status)
        for what in VALID_PATH_FAILURES:
            s[what] = sum(1 for r in members if valid_path_failure(r) == what)
        s["failures"] = failure_text(members)
        for m in metrics:
            med, q1, q3 = _quartiles([r.get(m.name, math.nan) for r in (members if m.over_all_runs else solved)])
            s[f"{m.name}_median"], s[f"{m.name}_q1"], s[f"{m.name}_q3"] = med, q1, q3
        out.append(s)
    return out


def _checks(row: dict[str, Any]) -> dict[str, Any]:
    """A row's ``checks`` (a dict in a record, JSON text in a results file; {} when absent)."""
    checks = row.get("checks")
    if isinstance(checks, str):
        try:
            checks = json.loads(checks)
        except ValueError:
            return {}
    return checks if isinstance(checks, dict) else {}


def valid_path_failure(row: dict[str, Any]) -> str:
    """``"late"`` for a run that answered after its time limit, ``"claimed_failure"`` for a valid
    path whose planner reported a failure status, else "" (rows written before these checks
    existed: "")."""
    if row.get("success"):
        return ""
    checks = _checks(row)
    if checks.get("in_time") is False:
        return "late"
    if checks.get("claimed_success") is False and all(v for k, v in checks.items() if k != "claimed_success"):
        return "claimed_failure"
    return ""


def failure_reason(row: dict[str, Any]) -> str:
    """Why a run failed, in a few words ("" for a success): ``collision <robot link>``,
    ``unseen-collision <robot link>`` (a closed-loop run's collision with an obstacle no observation
    had shown), ``unobserved-collision <robot link>`` (with one shown elsewhere, hit in space the
    latest observation did not know: :mod:`planbench.reactive.exposure`),
    ``self-collision <link>/<link>``, ``stall`` (a local minimum), ``time limit``, ``late`` (an
    answer after the time limit), ``claimed-failure <status>`` (a valid path, a failure status),
    ``horizon`` (a closed-loop run that did not reach its goal in time), ``error``, ``crash``, or
    the planner's own status (``step limit``, ``infeasible``, ...)."""
    if row.get("success"):
        return ""
    status = str(row.get("status") or "")
    if status in ("error", "crash"):
        return status
    valid = valid_path_failure(row)
    if valid == "late":
        return "late"
    if valid == "claimed_failure":
        return "claimed-failure " + status.replace("_", " ")
    pair = str(row.get("collision_pair") or "")
    if pair:
        a, _, b = pair.partition(" / ")
        if b and not b.startswith("obstacle:"):
            return f"self-collision {a}/{b}"
        observed = row.get("collision_observed")  # None, or a bool (an integer from the results file)
        if observed is not None and not observed:
            return f"unseen-collision {a}"
        if str(row.get("failure") or "").endswith(", in unobserved space"):
            return f"unobserved-collision {a}"
        return f"collision {a}"
    if status == "timeout":
        return "horizon" if row.get("deadline_misses") is not None else "time limit"
    return {"local_minimum": "stall"}.get(status, status.replace("_", " ") or "failed")


def failure_text(rows: Sequence[dict[str, Any]], links: int = 2) -> str:
    """The failure reasons of ``rows`` counted, most frequent first; collisions summed with their
    most frequent robot links, claimed failures with their statuses:
    ``collision 37 (panda_hand 20, panda_link5 10), stall 10, claimed-failure 2 (timeout 2)``."""
    reasons = collections.Counter(failure_reason(r) for r in rows if not r.get("success"))
    grouped: collections.Counter[str] = collections.Counter()
    detail: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for reason, n in reasons.items():
        located = reason.startswith(tuple(f"{kind} " for kind in LOCATED))
        kind, _, where = reason.partition(" ") if located else (reason, "", "")
        grouped[kind] += n
        if where:
            detail[kind][where] += n
    parts = []
    for kind, n in grouped.most_common():
        top = ", ".join(f"{w} {k}" for w, k in detail[kind].most_common(links))
        more = " ..." if len(detail[kind]) > links else ""
        parts.append(f"{kind} {n}" + (f" ({top}{more})" if top else ""))
    return ", ".join(parts)


def _num(v: float, scale: float = 1.0) -> str:
    if v is None or math.isnan(v):
        return "-"
    v = v * scale
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def _rate(s: dict[str, Any]) -> str:
    return f"{100 * s['success_rate']:.0f}% [{100 * s['success_ci_low']:.0f}, {100 * s['success_ci_high']:.0f}]"


def summary_cells(s: dict[str, Any], metrics: Sequence[Metric], quartiles: bool = True) -> list[str]:
    cells = [f"{s['solved']}/{s['runs']}", _rate(s), s.get("failures") or "-"]
    for m in metrics:
        med = s[f"{m.name}_median"]
        if math.isnan(med) or not quartiles:
            cells.append(_num(med, m.scale))
        else:
            q1, q3 = _num(s[f"{m.name}_q1"], m.scale), _num(s[f"{m.name}_q3"], m.scale)
            cells.append(f"{_num(med, m.scale)} [{q1}, {q3}]")
    return cells


def summary_headers(by: Sequence[str], metrics: Sequence[Metric], short: bool = False) -> list[str]:
    labels = [(m.short or m.label) if short else m.label for m in metrics]
    return [*by, "solved", "success [95% CI]", "failures", *labels]


def to_markdown(
    summary: Sequence[dict[str, Any]], by: Sequence[str] = ("planner",), metrics: Sequence[Metric] = METRICS
) -> str:
    """A Markdown table; metric cells are ``median [q1, q3]`` over solved runs."""
    head = summary_headers(by, metrics)
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for s in summary:
        lines.append("| " + " | ".join([*(str(s[c]) for c in by), *summary_cells(s, metrics)]) + " |")
    return "\n".join(lines) + "\n"


def to_csv(summary: Sequence[dict[str, Any]]) -> str:
    """The summary as CSV with one column per statistic, SI units (no display scaling); text that a
    spreadsheet would run as a formula (a planner label) is escaped (:func:`~planbench.files.outputs.csv_cell`)."""
    if not summary:
        return ""
    buf = io.StringIO()
    fields = list(summary[0])
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([csv_cell(k) for k in fields])
    for s in summary:
        cells = (s.get(k, "") for k in fields)
        writer.writerow([csv_cell("" if isinstance(v, float) and math.isnan(v) else v) for v in cells])
    return buf.getvalue()


def to_rich(
    summary: Sequence[dict[str, Any]],
    by: Sequence[str] = ("planner",),
    title: str = "",
    metrics: Sequence[Metric] = TERMINAL_METRICS,
    width: int | None = None,
    wide: bool = False,
) -> Any:
    """A rich Table for the terminal (short headers, no setup time). In a terminal narrower than
    140 columns the metric cells show medians only, so that the rows stay short; narrower than
    :data:`WIDE` (an 80-column terminal) the table is stacked: the outcomes (solved, success,
    failure reasons), then the metric medians in as many tables as the width needs, every cell
    whole (``wide=True`` or ``width=None``: one table)."""
    if width is not None and width < WIDE and not wide:
        return _stacked(summary, by, title, metrics, width)
    quartiles = width is None or width >= 140
    table = Table(
        title=escape(title) if title else None,
        title_justify="left",
        caption=escape(
            "metrics: median [q1, q3] over validated successes" + _all_runs_note(metrics)
            if quartiles
            else "metrics: median over validated successes (quartiles: a wider terminal, or --markdown)"
            + _all_runs_note(metrics)
        ),
        caption_justify="left",
    )
    for i, h in enumerate(summary_headers(by, metrics, short=True)):
        table.add_column(escape(h), justify="left" if i < len(by) else "right", no_wrap=i < len(by))
    for s in summary:
        table.add_row(*(escape(str(s[c])) for c in by), *summary_cells(s, metrics, quartiles))
    return table


WIDE = 160
"""Terminal width [columns] from which the whole table is one (below it: :func:`_stacked`)."""


def _stacked(
    summary: Sequence[dict[str, Any]], by: Sequence[str], title: str, metrics: Sequence[Metric], width: int
) -> Any:
    """The outcome table, then the metric medians split into tables that fit ``width``."""
    keys = [" / ".join(str(s[c]) for c in by) for s in summary]
    key_width = max([len(k) for k in keys] + [len(" / ".join(by))])
    outcome = Table(title=escape(title) if title else None, title_justify="left", expand=False)
    outcome.add_column(escape(" / ".join(by)), no_wrap=True)
    outcome.add_column("solved", justify="right", no_wrap=True)
    outcome.add_column("success [95% CI]", justify="right", no_wrap=True)
    outcome.add_column("failures", overflow="fold")
    for k, s in zip(keys, summary, strict=True):
        outcome.add_row(escape(k), f"{s['solved']}/{s['runs']}", _rate(s), escape(s.get("failures") or "-"))
    tables: list[Any] = [outcome]
    cells = {m.name: [_num(s[f"{m.name}_median"], m.scale) for s in summary] for m in metrics}
    room = width - key_width - 4  # the key column and the table's borders
    chunk: list[Metric] = []
    used = 0
    for m in [*metrics, None]:
        need = 0 if m is None else max(len(m.short or m.label), *(len(c) for c in cells[m.name])) + 3
        if m is None or (chunk and used + need > room):
            table = Table(title_justify="left")
            table.add_column(escape(" / ".join(by)), no_wrap=True)
            for c in chunk:
                table.add_column(escape(c.short or c.label), justify="right", no_wrap=True)
            for i, k in enumerate(keys):
                table.add_row(escape(k), *(cells[c.name][i] for c in chunk))
            tables.append(table)
            chunk, used = [], 0
        if m is not None:
            chunk.append(m)
            used += need
    note = "metrics: medians over validated successes" + _all_runs_note(metrics) + " (all columns: --wide)"
    return Group(*tables, Text(note))


def _all_runs_note(metrics: Sequence[Metric]) -> str:
    names = [m.short or m.label for m in metrics if m.over_all_runs]
    return f"; {', '.join(names)}: over every run" if names else ""


def failures(rows: Sequence[dict[str, Any]], limit: int = 20) -> list[str]:
    """One line per error/timeout/crash run (its key and message), at most ``limit``."""
    out = []
    for r in rows:
        if r["status"] in FAILURE_STATUSES:
            out.append(f"{r['planner']} on {r['problem']} seed {r['seed']}: {r['status']}: {r['message']}")
    return out[:limit] + ([f"... and {len(out) - limit} more"] if len(out) > limit else [])
