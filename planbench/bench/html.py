"""One self-contained HTML report: summary tables (per planner, per planner and family, with failure
reasons), the suites' settings, a table of every run, the list of runs that raised, timed out or
crashed, and every plot embedded as base64 PNG (no external files, no scripts).

A results file may come from another lab: everything read from it (names, messages, settings) is
escaped before it is written into the page, so nothing in it runs as code.
"""

from __future__ import annotations

import base64
import datetime
import html
import json
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from planbench.bench.plots import write_plots
from planbench.bench.report import (
    FAILURE_STATUSES,
    METRICS,
    Metric,
    certificate_rows,
    metrics_for,
    summarize,
    summary_cells,
    summary_headers,
)
from planbench.files.outputs import check_output

__all__ = ["write_html", "render_html"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em; max-width: 1200px; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; }
th { background: #f3f3f3; } td.key { text-align: left; font-weight: 600; }
img { max-width: 48%; margin: 0.5%; border: 1px solid #eee; }
pre { background: #f8f8f8; padding: 0.5em; overflow-x: auto; font-size: 0.8em; }
"""


def _table(summary: Sequence[dict[str, Any]], by: Sequence[str], metrics: Sequence[Metric] = METRICS) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in summary_headers(by, metrics))
    body = []
    for s in summary:
        keys = "".join(f'<td class="key">{html.escape(str(s[c]))}</td>' for c in by)
        cells = "".join(f"<td>{html.escape(c)}</td>" for c in summary_cells(s, metrics))
        body.append(f"<tr>{keys}{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _settings(suites: dict[str, Any]) -> str:
    """Each suite's stored definition and result-changing settings, as escaped JSON."""
    parts = []
    for name, (definition, settings) in sorted(suites.items()):
        text = json.dumps({"settings": settings, "definition": definition}, indent=1, sort_keys=True, default=str)
        parts.append(f"<details><summary>suite {html.escape(name)}</summary><pre>{html.escape(text)}</pre></details>")
    return "".join(parts)


RUN_COLUMNS = (
    ("planner", "planner", 1.0),
    ("problem", "problem", 1.0),
    ("seed", "seed", 1.0),
    ("success", "success", 1.0),
    ("failure", "failure", 1.0),
    ("planning_time", "time [ms]", 1e3),
    ("min_clearance", "clearance [mm]", 1e3),
    ("joint_path_length", "joint length [rad]", 1.0),
)


def _runs(rows: Sequence[dict[str, Any]], limit: int = 5000, replays: dict[int, str] | None = None) -> str:
    """Every run (at most ``limit``) as one table row, linked to its replay where there is one."""
    head = "".join(f"<th>{html.escape(label)}</th>" for _, label, _ in RUN_COLUMNS)
    if replays:
        head += "<th>replay</th>"
    body = []
    for r in rows[:limit]:
        cells = []
        for name, _, scale in RUN_COLUMNS:
            v = r.get(name)
            if isinstance(v, float):
                text = "-" if v != v else f"{v * scale:.3g}"  # NaN: no value
            else:
                text = "" if v is None else str(v)
            cells.append(
                f'<td class="key">{html.escape(text)}</td>'
                if name in ("planner", "problem", "failure")
                else f"<td>{html.escape(text)}</td>"
            )
        if replays:
            link = replays.get(r.get("id", -1))
            cells.append(f'<td><a href="{html.escape(link)}">3D</a></td>' if link else "<td></td>")
        body.append(f"<tr>{''.join(cells)}</tr>")
    more = f"<p>... and {len(rows) - limit} more runs (planbench export --format csv has them all).</p>"
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>" + (
        more if len(rows) > limit else ""
    )


def render_html(
    rows: Sequence[dict[str, Any]],
    title: str = "planbench report",
    plots_dir: str | Path | None = None,
    suite_settings: dict[str, Any] | None = None,
    replays: dict[int, str] | None = None,
) -> str:
    """The report as an HTML string; plots are made in ``plots_dir`` (a temporary folder if None).
    ``suite_settings``: name to (definition, settings) as stored in the results file, shown as
    they are."""
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
        f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>",
    ]
    suites = sorted({r["suite"] for r in rows})
    planners = sorted({r["planner"] for r in rows})
    first = rows[0] if rows else {}
    parts.append(
        f"<p>{len(rows)} runs; suites: {html.escape(', '.join(suites))}; planners: {html.escape(', '.join(planners))}; "
        f"host: {html.escape(str(first.get('host', '')))}; generated "
        f"{datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')}.</p>"
        "<p>Success is planbench's own validation of every path. Metric cells: median [q1, q3] over "
        "validated successes; success rates with 95% Wilson intervals.</p>"
    )
    metrics = metrics_for(rows)
    tabled = [*rows, *certificate_rows(rows)]  # the scenarios' certificates: a line of the tables
    parts.append("<h2>Per planner</h2>" + _table(summarize(tabled, ("planner",)), ("planner",), metrics))
    parts.append(
        "<h2>Per planner and family</h2>"
        + _table(summarize(tabled, ("planner", "family")), ("planner", "family"), metrics)
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(plots_dir) if plots_dir else Path(tmp)
        files = write_plots(rows, folder)
        parts.append("<h2>Plots</h2>")
        order = sorted(files, key=lambda p: (not p.stem.startswith(("time_to", "success")), p.stem))
        for f in order:
            data = base64.b64encode(f.read_bytes()).decode("ascii")
            parts.append(f'<img alt="{html.escape(f.stem)}" src="data:image/png;base64,{data}">')
    if suite_settings:
        parts.append("<h2>Suites and their settings</h2>" + _settings(suite_settings))
    parts.append(
        f"<h2>Every run ({len(rows)})</h2><details{' open' if replays else ''}><summary>show</summary>"
        f"{_runs(rows, replays=replays)}</details>"
    )
    bad = [r for r in rows if r["status"] in FAILURE_STATUSES]
    if bad:
        parts.append(f"<h2>Runs that raised, timed out or crashed ({len(bad)})</h2>")
        for r in bad[:200]:
            parts.append(
                f"<details><summary>{html.escape(r['planner'])} on {html.escape(r['problem'])} seed {r['seed']}: "
                f"{html.escape(r['status'])}: {html.escape(str(r['message']))}</summary>"
                f"<pre>{html.escape(str(r.get('traceback') or '(no traceback)'))}</pre></details>"
            )
    versions = first.get("versions", "")
    parts.append(f"<h2>Versions</h2><pre>{html.escape(str(versions))}</pre></body></html>")
    return "\n".join(parts)


def write_html(
    rows: Sequence[dict[str, Any]],
    path: str | Path,
    title: str = "planbench report",
    suites: dict[str, Any] | None = None,
    replays: bool = False,
) -> Path:
    """Write :func:`render_html` to ``path``; ``replays``: also a replay page per run with a path,
    in the folder ``<path stem>_replays/`` beside it, linked from the table of runs."""
    out = check_output(path)
    links: dict[int, str] = {}
    if replays:
        from planbench.bench.replay import replay_row

        folder = out.parent / f"{out.stem}_replays"
        folder.mkdir(parents=True, exist_ok=True)
        for r in rows:
            if r.get("path") is not None and r.get("id") is not None:
                replay_row(r, folder / f"run-{int(r['id'])}.html")
                links[int(r["id"])] = f"{folder.name}/run-{int(r['id'])}.html"
    out.write_text(render_html(rows, title, suite_settings=suites, replays=links))
    return out
