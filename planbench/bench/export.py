"""Exports of a results database: OMPL benchmark logs, a Planner Arena database, CSV of every run.

OMPL's benchmark log (the text ``ompl::tools::Benchmark::saveResultsToFile`` writes, read by
``ompl_benchmark_statistics.py``) holds one *experiment*: one problem with every planner's runs.
``write_ompl_logs`` therefore writes one ``.log`` file per problem. ``write_planner_arena`` writes
the SQLite schema that ``ompl_benchmark_statistics.py`` builds from such logs and Planner Arena
reads (``experiments``, ``plannerConfigs``, ``enums``, ``runs``, ``progress``), directly.

Experiments: Planner Arena offers one entry per experiment *name* ("Motion planning problem") and
pools every run of every experiment row with that name; the columns of ``experiments`` after its
twelve fixed ones are *problem parameters*, each a selector (one value, "all (aggregate)" or "all
(separate)"). So each problem stays one experiment row (one log), with the parameters ``family``
and ``problem``, and its *name* is the group chosen with ``by`` (:data:`EXPERIMENT_GROUPS`):
``"family"`` (the default: MotionBenchMaker's ``mbm:box/0001`` is in experiment ``box``; a problem
without a family is its own experiment), ``"suite"`` (one experiment per suite) or ``"problem"``
(one per problem). With runs of several suites, family and problem names are prefixed
``suite:``.

Run properties, in both: OMPL's own names where planbench has the quantity -- ``time`` (planning
time [s]), ``solved`` (planbench's validated success), ``status`` (an enum over
:class:`planbench.PlanStatus`), ``approximate solution``, ``correct solution``, ``solution length``
(joint path length [rad]), ``solution smoothness`` (total turning angle [rad]), ``solution
clearance`` (min clearance [m]) -- and every other planbench metric as an extra column
(``setup time``, ``ee path length``, ``duration``, ``seed``, ...). Runs killed or crashed have no
time; they appear with ``time`` empty and status ``timeout`` or ``crash``.

Planner configurations (``plannerConfigs``; an OMPL log's "common properties"): one per label
and settings, its ``settings`` every setting of the planner as built, defaults included (the run's
``planner_config``; a results file written before it existed: the settings given), one ``name =
value`` per setting, nested ones with dotted names (``params.range``), then an OMPL planner's own
parameters as it reported them on the experiment's first run (``info["ompl_parameters"]``, named
``ompl.<name>``), as :func:`planner_settings` lists them.

Progress (Planner Arena's "Progress" page): a run whose planner recorded ``info["progress"]``
(OMPL's anytime planners do: :mod:`ompl_planners.base`) has its samples in ``progress``: ``time``
[s] since the plan began, ``best cost`` (None before the first solution) and ``iterations``, the
property names of OMPL's own planners (:data:`PROGRESS_PROPERTIES`), plus any other numeric series
it recorded. The samples are the planner's word, shown as information only: a series that is not
numbers with strictly increasing finite times is left out whole. The ``progress`` table always has
the ``best_cost`` column, which Planner Arena's original (R) app requires.
"""

from __future__ import annotations

import csv
import json
import math
import re
import sqlite3
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planbench.files.outputs import check_output, csv_cell
from planbench.planner import PlanStatus

__all__ = [
    "EXPERIMENT_GROUPS",
    "PROGRESS_PROPERTIES",
    "RUN_PROPERTIES",
    "planner_settings",
    "run_progress",
    "write_ompl_logs",
    "write_planner_arena",
    "write_runs_csv",
    "experiments",
]

STATUS_ENUM = [s.value for s in PlanStatus]
EXPERIMENT_GROUPS = ("family", "suite", "problem")
"""What one exported experiment name holds: a problem family, a suite, or one problem."""
EXPERIMENT_PARAMETERS = ("family", "problem")
"""Planner Arena's problem parameters of each experiment row (``experiments`` columns after its twelve)."""

# (OMPL-style property name, SQL type, function of a planbench row)
RUN_PROPERTIES: tuple[tuple[str, str, Any], ...] = (
    ("time", "REAL", lambda r: r["planning_time"]),
    ("solved", "BOOLEAN", lambda r: int(bool(r["success"]))),
    ("status", "ENUM", lambda r: STATUS_ENUM.index(r["status"]) if r["status"] in STATUS_ENUM else None),
    ("approximate solution", "BOOLEAN", lambda r: 0),
    ("correct solution", "BOOLEAN", lambda r: int(bool(r["success"]))),
    ("solution length", "REAL", lambda r: r["joint_path_length"]),
    ("solution smoothness", "REAL", lambda r: r["smoothness"]),
    ("solution clearance", "REAL", lambda r: r["min_clearance"]),
    ("planner claimed success", "BOOLEAN", lambda r: int(r["status"] == "success")),
    ("setup time", "REAL", lambda r: r["setup_time"]),
    ("ee path length", "REAL", lambda r: r["ee_path_length"]),
    ("mean clearance", "REAL", lambda r: r["mean_clearance"]),
    ("duration", "REAL", lambda r: r["duration"]),
    ("trajectory duration", "REAL", lambda r: r["trajectory_duration"]),
    ("final position error", "REAL", lambda r: r["final_position_error"]),
    ("final orientation error", "REAL", lambda r: r["final_orientation_error"]),
    ("final joint error", "REAL", lambda r: r["final_joint_error"]),
    ("waypoints", "INTEGER", lambda r: r["n_waypoints"]),
    ("collision checks", "INTEGER", lambda r: r["collision_checks"]),  # the planner's own count
    ("validation checks", "INTEGER", lambda r: r["validation_checks"]),
    ("wall time", "REAL", lambda r: r["wall_time"]),
    ("seed", "INTEGER", lambda r: r["seed"]),
    # the suite's post-processing stage (planbench.bench.postprocess; empty where it did not run)
    ("processed solution length", "REAL", lambda r: r.get("processed_joint_path_length")),
    ("processed ee path length", "REAL", lambda r: r.get("processed_ee_path_length")),
    ("processed clearance", "REAL", lambda r: r.get("processed_min_clearance")),
    ("processed duration", "REAL", lambda r: r.get("processed_duration_limited")),
    ("postprocess time", "REAL", lambda r: r.get("postprocess_time")),
)


PROGRESS_PROPERTIES: tuple[tuple[str, str], ...] = (("best cost", "REAL"), ("iterations", "INTEGER"))
"""(OMPL's progress property name, SQL type): the columns every exported ``progress`` table has."""
_PROGRESS_NAME = re.compile(r"[A-Za-z][A-Za-z0-9 ]{0,63}")


def run_progress(row: dict[str, Any]) -> dict[str, list[Any]] | None:
    """The progress samples of a run (``info["progress"]``) as ``{"time": [...], property: [...]}``,
    or None when it has none or they are malformed (see the module docstring)."""
    data = _json(row.get("info")).get("progress")
    if not isinstance(data, dict):
        return None
    times = data.get("time")
    if not (isinstance(times, list) and times and all(_is_number(t) and math.isfinite(t) for t in times)):
        return None
    if any(b <= a for a, b in zip(times, times[1:], strict=False)):
        return None
    out: dict[str, list[Any]] = {"time": [float(t) for t in times]}
    for name, values in data.items():
        if name in ("time", "interval") or not _PROGRESS_NAME.fullmatch(str(name)):
            continue
        if not (isinstance(values, list) and len(values) == len(times)):
            return None
        if not all(v is None or _is_number(v) for v in values):
            return None
        out[name] = [_value(float(v)) if isinstance(v, float) else v for v in values]
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _progress_properties(runs: Sequence[dict[str, Any]]) -> list[tuple[str, str]]:
    """(name, SQL type) of the progress properties of ``runs``: OMPL's first, then any others."""
    names: dict[str, str] = {}
    for r in runs:
        for name, values in (run_progress(r) or {}).items():
            if name != "time":
                integer = all(v is None or isinstance(v, int) for v in values)
                names[name] = "INTEGER" if integer and names.get(name, "INTEGER") == "INTEGER" else "REAL"
    known = [(n, t) for n, t in PROGRESS_PROPERTIES if n in names]
    return known + sorted((n, t) for n, t in names.items() if n not in dict(PROGRESS_PROPERTIES))


def planner_settings(row: dict[str, Any]) -> list[tuple[str, str]]:
    """(name, value) of every setting of a run's planner, as the export writes them (see the module
    docstring): ``planner`` first, then its full configuration, then OMPL's own parameters."""
    config = _json(row.get("planner_config")) or _json(row.get("planner_settings"))
    out = [("planner", _setting_text(row.get("planner_name") or row.get("planner") or ""))]
    out += _flatten(config, "")
    ompl = _json(row.get("info")).get("ompl_parameters")
    if isinstance(ompl, dict):
        out += [(f"ompl.{_token(str(k))}", _setting_text(v)) for k, v in sorted(ompl.items())]
    return out


def _flatten(d: dict[str, Any], prefix: str) -> list[tuple[str, str]]:
    out = []
    for k, v in sorted(d.items()):
        name = prefix + _token(str(k))
        if isinstance(v, dict) and v:
            out += _flatten(v, name + ".")
        else:
            out.append((name, _setting_text(v)))
    return out


def _setting_text(v: Any) -> str:
    """A setting's value on one line: text as it is, anything else as JSON."""
    text = v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str)
    return re.sub(r"[\r\n]+", " ", text)


def _settings_text(settings: list[tuple[str, str]]) -> str:
    """The ``settings`` text of ``plannerConfigs``: what OMPL's reader makes of the common properties."""
    return "".join(f"{name} = {value};" for name, value in settings)


def _value(v: Any) -> Any:
    """None for missing numbers (OMPL writes them as empty or ``nan``)."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return None
    return v


def experiments(rows: Sequence[dict[str, Any]], by: str = "family") -> list[dict[str, Any]]:
    """Rows grouped into OMPL experiments: one per (suite, problem), planners in label order, each
    named by its group ``by`` (:data:`EXPERIMENT_GROUPS`, see the module docstring), sorted by name
    then problem."""
    if by not in EXPERIMENT_GROUPS:
        raise ValueError(f"by must be one of {EXPERIMENT_GROUPS}, got {by!r}")
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["suite"], r["problem"]), []).append(r)
    several_suites = len({s for s, _ in groups}) > 1
    out = []
    for (suite, problem), members in groups.items():
        planners: dict[str, list[dict[str, Any]]] = {}
        for r in sorted(members, key=lambda r: (r["planner"], r["seed"])):
            planners.setdefault(r["planner"], []).append(r)
        settings = _json(members[0].get("settings"))
        versions = _json(members[0].get("versions"))
        family = members[0].get("family") or ""
        if by == "suite":
            name = suite
        else:
            name = family if by == "family" and family else problem
            name = f"{suite}:{name}" if several_suites else name
        out.append(
            {
                "name": name,
                "suite": suite,
                "problem": problem,
                "family": family,
                "parameters": {"family": _token(family) if family else "none", "problem": _token(problem)},
                "planners": planners,
                "time_limit": float(members[0].get("time_limit") or 0.0),
                "memory_limit": float(settings.get("memory_limit", 0.0) or 0.0),
                "total_time": float(sum(r["wall_time"] for r in members if _value(r.get("wall_time")) is not None)),
                "host": members[0].get("host") or "unknown",
                "date": members[0].get("finished") or "",
                "seed": min(r["seed"] for r in members),
                "runs_per_planner": max(len(v) for v in planners.values()),
                "version": versions.get("planbench", "0.0.0") or "0.0.0",
                "setup": json.dumps({"suite": suite, "problem": problem, "settings": settings}, sort_keys=True),
                "cpuinfo": versions.get("platform", ""),
            }
        )
    return sorted(out, key=lambda e: (e["name"], e["suite"], e["problem"]))


def _json(v: Any) -> dict[str, Any]:
    if isinstance(v, dict):
        return v
    try:
        d = json.loads(v) if v else {}
    except (TypeError, json.JSONDecodeError):
        return {}
    return d if isinstance(d, dict) else {}


def _token(text: str) -> str:
    """One whitespace-free token (OMPL's parser reads names as the last token of a line)."""
    return re.sub(r"\s+", "_", text.strip()) or "unnamed"


def _log_number(v: Any) -> str:
    v = _value(v)
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def ompl_log(exp: dict[str, Any]) -> str:
    """The text of one OMPL benchmark log for an experiment of :func:`experiments`."""
    lines = [
        f"planbench version {exp['version']}",
        f"Experiment {_token(exp['name'])}",
        f"{len(EXPERIMENT_PARAMETERS)} experiment properties",
        *(f"{name} TEXT = {exp['parameters'][name]}" for name in EXPERIMENT_PARAMETERS),
        f"Running on {_token(exp['host'])}",
        f"Starting at {exp['date']}",
        "<<<|",
        exp["setup"],
        "|>>>",
        "<<<|",
        exp["cpuinfo"],
        "|>>>",
        f"{exp['seed']} is the random seed",
        f"{exp['time_limit']!r} seconds per run",
        f"{exp['memory_limit']!r} MB per run",
        f"{exp['runs_per_planner']} runs per planner",
        f"{exp['total_time']!r} seconds spent to collect the data",
        "1 enum type",
        "status|" + "|".join(STATUS_ENUM),
        f"{len(exp['planners'])} planners",
    ]
    for label, runs in exp["planners"].items():
        settings = planner_settings(runs[0])
        lines += [
            _token(label),
            f"{len(settings)} common properties",
            *(f"{name} = {value}" for name, value in settings),
            f"{len(RUN_PROPERTIES)} properties for each run",
            *(f"{name} {sql}" for name, sql, _ in RUN_PROPERTIES),
            f"{len(runs)} runs",
            *("".join(f"{_log_number(fn(r))}; " for _, _, fn in RUN_PROPERTIES) for r in runs),
        ]
        progress = _progress_properties(runs)
        if progress:  # OMPL's layout: "time REAL" first, then one "t,v,...,;" group per sample
            lines += [f"{len(progress) + 1} progress properties for each run", "time REAL"]
            lines += [f"{name} {sql}" for name, sql in progress]
            lines.append(f"{len(runs)} runs")
            for r in runs:
                series = run_progress(r) or {"time": []}
                samples = []
                for k, t in enumerate(series["time"]):
                    values = [t, *(series.get(name, [None] * len(series["time"]))[k] for name, _ in progress)]
                    samples.append("".join(f"{_log_number(v)}," for v in values) + ";")
                lines.append("".join(samples))
        lines.append(".")
    return "\n".join(lines) + "\n"


def write_ompl_logs(rows: Sequence[dict[str, Any]], folder: str | Path, by: str = "family") -> list[Path]:
    """One OMPL benchmark log per problem in ``folder``, its experiment named by ``by`` (see
    :func:`experiments`); returns the files written."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    exps = experiments(rows, by)
    several_suites = len({e["suite"] for e in exps}) > 1
    for exp in exps:
        stem = f"{exp['suite']}_{exp['problem']}" if several_suites else exp["problem"]
        f = check_output(out / (re.sub(r"[^A-Za-z0-9_.-]+", "_", stem) + ".log"))
        f.write_text(ompl_log(exp))
        files.append(f)
    return files


_ARENA_SCHEMA = """
CREATE TABLE experiments (id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512), totaltime REAL,
    timelimit REAL, memorylimit REAL, runcount INTEGER, version VARCHAR(128), hostname VARCHAR(1024),
    cpuinfo TEXT, date DATETIME, seed VARCHAR(24), setup TEXT, family TEXT, problem TEXT);
CREATE TABLE plannerConfigs (id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512) NOT NULL, settings TEXT);
CREATE TABLE enums (name VARCHAR(512), value INTEGER, description TEXT, PRIMARY KEY (name, value));
CREATE TABLE runs (id INTEGER PRIMARY KEY AUTOINCREMENT, experimentid INTEGER, plannerid INTEGER,
    FOREIGN KEY (experimentid) REFERENCES experiments(id) ON DELETE CASCADE,
    FOREIGN KEY (plannerid) REFERENCES plannerConfigs(id) ON DELETE CASCADE);
CREATE TABLE progress (runid INTEGER, time REAL, PRIMARY KEY (runid, time),
    FOREIGN KEY (runid) REFERENCES runs(id) ON DELETE CASCADE);
"""
# (the progress columns are added per property: PROGRESS_PROPERTIES always, others as runs have them)


def _column(name: str) -> str:
    return name.replace(" ", "_")


def write_planner_arena(rows: Sequence[dict[str, Any]], path: str | Path, by: str = "family") -> Path:
    """A Planner Arena database at ``path`` (a file there is replaced, never a SQLite database:
    :func:`~planbench.files.outputs.check_output`), experiments named by ``by``; see the module
    docstring."""
    out = check_output(path)
    if out.exists():
        out.unlink()
    conn = sqlite3.connect(str(out))
    try:
        with conn:
            conn.executescript(_ARENA_SCHEMA)
            for name, sql, _ in RUN_PROPERTIES:
                conn.execute(f"ALTER TABLE runs ADD {_column(name)} {sql}")
            progress_columns = list(PROGRESS_PROPERTIES)
            progress_columns += [p for p in _progress_properties(rows) if p[0] not in dict(PROGRESS_PROPERTIES)]
            for name, sql in progress_columns:
                conn.execute(f"ALTER TABLE progress ADD {_column(name)} {sql}")
            progress_insert = (
                f"INSERT INTO progress (runid, time, {', '.join(_column(n) for n, _ in progress_columns)}) "
                f"VALUES ({', '.join('?' * (len(progress_columns) + 2))})"
            )
            conn.executemany("INSERT INTO enums VALUES ('status', ?, ?)", list(enumerate(STATUS_ENUM)))
            planner_ids: dict[tuple[str, str], int] = {}
            cols = ["experimentid", "plannerid", *(_column(n) for n, _, _ in RUN_PROPERTIES)]
            insert = f"INSERT INTO runs ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})"
            for exp in experiments(rows, by):
                cur = conn.execute(
                    "INSERT INTO experiments (name, totaltime, timelimit, memorylimit, runcount, version, hostname,"
                    " cpuinfo, date, seed, setup, family, problem) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (
                        _token(exp["name"]),
                        exp["total_time"],
                        exp["time_limit"],
                        exp["memory_limit"],
                        exp["runs_per_planner"],
                        f"planbench {exp['version']}",
                        _token(exp["host"]),
                        exp["cpuinfo"],
                        exp["date"],
                        str(exp["seed"]),
                        exp["setup"],
                        *(exp["parameters"][name] for name in EXPERIMENT_PARAMETERS),
                    ),
                )
                exp_id = cur.lastrowid
                for label, runs in exp["planners"].items():
                    # the text OMPL's reader makes of the log's common properties (without their newlines)
                    pkey = (_token(label), _settings_text(planner_settings(runs[0])))
                    if pkey not in planner_ids:
                        planner_ids[pkey] = (
                            conn.execute("INSERT INTO plannerConfigs (name, settings) VALUES (?, ?)", pkey).lastrowid
                            or 0
                        )
                    for r in runs:
                        run_id = conn.execute(
                            insert, [exp_id, planner_ids[pkey], *(_value(fn(r)) for _, _, fn in RUN_PROPERTIES)]
                        ).lastrowid
                        series = run_progress(r)
                        if series is None:
                            continue
                        n = len(series["time"])
                        conn.executemany(
                            progress_insert,
                            [
                                [
                                    run_id,
                                    series["time"][k],
                                    *(series.get(name, [None] * n)[k] for name, _ in progress_columns),
                                ]
                                for k in range(n)
                            ],
                        )
    finally:
        conn.close()
    return out


def write_runs_csv(rows: Sequence[dict[str, Any]], path: str | Path, paths: bool = False) -> Path:
    """Every run as a CSV row: all database columns (SI units, empty for NaN); ``paths``: with the
    ``path`` and ``times`` arrays as JSON lists (rows read ``with_arrays``), else without them.
    Text that a spreadsheet would run as a formula is escaped (:func:`~planbench.files.outputs.csv_cell`)."""
    out = check_output(path)
    fields = [k for k in (rows[0] if rows else {}) if paths or k not in ("path", "times")]
    with out.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([csv_cell(k) for k in fields])
        for r in rows:
            d = {k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()}
            if paths:
                for name in ("path", "times"):
                    a = r.get(name)
                    d[name] = "" if a is None else json.dumps(np.asarray(a, dtype=float).tolist())
            writer.writerow([csv_cell(d.get(k, "")) for k in fields])
    return out
