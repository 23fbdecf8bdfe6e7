"""The results database: SQLite, embedded, one row per run, written and committed as each run ends.

Schema (``planbench-results/1``)::

    meta(key TEXT PRIMARY KEY, value TEXT)          -- schema version
    suites(name TEXT PRIMARY KEY, definition TEXT,  -- the suite as JSON (planners, seeds, limits)
           settings TEXT, created TEXT)             -- the settings that change results, JSON
    runs(id INTEGER PRIMARY KEY,
         suite, problem, family, planner (the label), seed,        -- UNIQUE(suite, problem, planner, seed)
         planner_name, planner_settings (JSON), planner_version,
         time_limit [s], status, success (0/1), failure, message, traceback,
         <every field of planbench.Evaluation: planning_time [s], setup_time [s],
          joint_path_length [rad], ee_path_length [m], min_clearance [m], duration [s], ...>,
         checks (JSON), info (JSON planner diagnostics),
         path BLOB, times BLOB,       -- float64 .npy bytes (shape and dtype included), NULL without
         wall_time [s] (problem loading + setup + plan + validate, in the worker),
         validation_time [s] (planbench.evaluate), elapsed [s] (dispatch to record, seen by the parent),
         worker_pid, host,
         versions (JSON: python, planbench, numpy, scipy, pin, coal, ompl, ...),
         settings (JSON: limits and validation of the run), finished (ISO time UTC))

``--resume`` works off the unique key: a run whose key has a row is never run again, and a run
is recorded with one INSERT in its own transaction, so a kill leaves either the whole row or none.
"""

from __future__ import annotations

import dataclasses
import datetime
import io
import json
import math
import platform
import socket
import sqlite3
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from planbench.errors import PlanbenchError

__all__ = ["ResultsDB", "RunKey", "package_versions", "array_from_blob"]

SCHEMA = "planbench-results/1"
RunKey = tuple[str, str, str, int]  # (suite, problem, planner label, seed)

_KEY_COLS = ("suite", "problem", "planner", "seed")
_RUN_COLS: tuple[tuple[str, str], ...] = (
    ("suite", "TEXT NOT NULL"),
    ("problem", "TEXT NOT NULL"),
    ("family", "TEXT"),
    ("planner", "TEXT NOT NULL"),
    ("seed", "INTEGER NOT NULL"),
    ("planner_name", "TEXT"),
    ("planner_settings", "TEXT"),
    ("planner_version", "TEXT"),
    ("time_limit", "REAL"),
    ("message", "TEXT"),
    ("traceback", "TEXT"),
    ("info", "TEXT"),
    ("path", "BLOB"),
    ("times", "BLOB"),
    ("wall_time", "REAL"),
    ("validation_time", "REAL"),
    ("elapsed", "REAL"),
    ("worker_pid", "INTEGER"),
    ("host", "TEXT"),
    ("versions", "TEXT"),
    ("settings", "TEXT"),
    ("finished", "TEXT"),
)
KEY_DEPENDENCIES = ("numpy", "scipy", "pin", "coal", "ompl", "qpsolvers", "numba")


def _evaluation_columns() -> list[tuple[str, str]]:
    """Columns for every field of :class:`planbench.Evaluation` (added as the dataclass grows)."""
    from planbench.validate import Evaluation

    cols = []
    for f in dataclasses.fields(Evaluation):
        t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        t = t.removesuffix(" | None")
        sql = {"bool": "INTEGER", "int": "INTEGER", "float": "REAL", "str": "TEXT"}.get(t, "TEXT")
        cols.append((f.name, sql))
    return cols


def package_versions() -> dict[str, str]:
    """Versions of Python, planbench and the key dependencies ("" when not installed)."""
    import importlib.metadata

    out = {"python": platform.python_version(), "platform": platform.platform()}
    for dist in ("planbench", *KEY_DEPENDENCIES):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = ""
    return out


def array_to_blob(a: np.ndarray | None) -> bytes | None:
    if a is None:
        return None
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a, dtype=float), allow_pickle=False)
    return buf.getvalue()


def array_from_blob(blob: bytes | None) -> np.ndarray | None:
    """The array stored in a ``path`` or ``times`` column (None for NULL)."""
    if blob is None:
        return None
    return np.load(io.BytesIO(blob), allow_pickle=False)  # type: ignore[no-any-return]


def _sql_value(v: Any) -> Any:
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (dict, list, tuple)):
        return json.dumps(v, sort_keys=True)
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


class ResultsDB:
    """A results file; ``ResultsDB(path)`` creates it (and the tables) when missing."""

    def __init__(self, path: str | Path, create: bool = True) -> None:
        self.path = Path(path)
        if not create and not self.path.is_file():
            raise PlanbenchError(f"{self.path}: no such results database")
        try:
            self.conn = sqlite3.connect(str(self.path), timeout=30.0)
            self.conn.row_factory = sqlite3.Row
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=NORMAL")
            self._create()
        except sqlite3.DatabaseError as exc:
            raise PlanbenchError(f"{self.path}: not a planbench results database ({exc})") from exc
        self.versions = package_versions()
        self.host = socket.gethostname()

    def _create(self) -> None:
        with self.conn:
            self.conn.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            row = self.conn.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
            if row is None:
                self.conn.execute("INSERT INTO meta VALUES ('schema', ?)", (SCHEMA,))
            elif row[0] != SCHEMA:
                raise PlanbenchError(f"{self.path}: results schema {row[0]!r}, this planbench reads {SCHEMA!r}")
            self.conn.execute(
                "CREATE TABLE IF NOT EXISTS suites "
                "(name TEXT PRIMARY KEY, definition TEXT, settings TEXT, created TEXT)"
            )
            cols = list(_RUN_COLS[:5]) + _evaluation_columns() + list(_RUN_COLS[5:])
            body = ", ".join(f"{name} {sql}" for name, sql in cols)
            self.conn.execute(
                f"CREATE TABLE IF NOT EXISTS runs (id INTEGER PRIMARY KEY, {body}, UNIQUE({', '.join(_KEY_COLS)}))"
            )
            have = {r[1] for r in self.conn.execute("PRAGMA table_info(runs)")}
            for name, sql in cols:  # a newer Evaluation with more metrics: add their columns
                if name not in have:
                    self.conn.execute(f"ALTER TABLE runs ADD COLUMN {name} {sql.replace(' NOT NULL', '')}")
            if "validation_checks" not in have and "collision_checks" in have:
                # written before the planner's own count had its column: collision_checks held the harness's
                self.conn.execute(
                    "UPDATE runs SET validation_checks = collision_checks, collision_checks = "
                    "CASE WHEN json_valid(info) THEN json_extract(info, '$.collision_checks') END"
                )
        self.columns = [r[1] for r in self.conn.execute("PRAGMA table_info(runs)")]

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> ResultsDB:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- suites ----------------------------------------------------------------------------------

    def suite_settings(self, name: str) -> tuple[dict[str, Any], dict[str, Any]] | None:
        """(definition, settings) stored for suite ``name``, or None."""
        row = self.conn.execute("SELECT definition, settings FROM suites WHERE name=?", (name,)).fetchone()
        return None if row is None else (json.loads(row[0]), json.loads(row[1]))

    def put_suite(self, name: str, definition: dict[str, Any], settings_json: str) -> None:
        now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        with self.conn:
            self.conn.execute(
                "INSERT OR REPLACE INTO suites VALUES "
                "(?, ?, ?, COALESCE((SELECT created FROM suites WHERE name=?), ?))",
                (name, json.dumps(definition, sort_keys=True, default=str), settings_json, name, now),
            )

    def delete_suite_runs(self, name: str) -> int:
        with self.conn:
            return self.conn.execute("DELETE FROM runs WHERE suite=?", (name,)).rowcount

    def suites(self) -> list[str]:
        return [r[0] for r in self.conn.execute("SELECT DISTINCT suite FROM runs ORDER BY suite")]

    # -- runs ------------------------------------------------------------------------------------

    def done_keys(self, suite: str) -> set[RunKey]:
        rows = self.conn.execute("SELECT suite, problem, planner, seed FROM runs WHERE suite=?", (suite,))
        return {(r[0], r[1], r[2], int(r[3])) for r in rows}

    def count(self, suite: str | None = None) -> int:
        if suite is None:
            return int(self.conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
        return int(self.conn.execute("SELECT COUNT(*) FROM runs WHERE suite=?", (suite,)).fetchone()[0])

    def add_run(self, fields: dict[str, Any], record: dict[str, Any]) -> None:
        """Insert one run: ``fields`` (key, planner, settings) and the worker's ``record``; commits."""
        row: dict[str, Any] = dict(fields)
        row.update(record["evaluation"])
        row.update(
            message=record.get("message", ""),
            traceback=record.get("traceback", ""),
            info=record.get("info", {}),
            path=array_to_blob(record.get("path")),
            times=array_to_blob(record.get("times")),
            wall_time=record.get("wall_time"),
            validation_time=record.get("validation_time"),
            elapsed=record.get("elapsed"),
            worker_pid=record.get("pid"),
            host=record.get("host") or self.host,
            versions=self.versions,
            finished=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds"),
        )
        names = [n for n in row if n in self.columns]
        missing = set(row) - set(self.columns)
        if missing:
            raise PlanbenchError(f"{self.path}: run fields {sorted(missing)} have no column")
        sql = f"INSERT INTO runs ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})"
        with self.conn:
            self.conn.execute(sql, [_sql_value(row[n]) for n in names])

    def rows(self, suite: str | None = None, with_arrays: bool = False) -> list[dict[str, Any]]:
        """Runs as dicts in key order (``path``/``times`` decoded when ``with_arrays``)."""
        cols = [c for c in self.columns if with_arrays or c not in ("path", "times")]
        sql = f"SELECT {', '.join(cols)} FROM runs"
        args: tuple[Any, ...] = ()
        if suite is not None:
            sql += " WHERE suite=?"
            args = (suite,)
        sql += " ORDER BY suite, planner, problem, seed"
        out = []
        for r in self.conn.execute(sql, args):
            d = dict(r)
            for name in ("success",):
                d[name] = bool(d[name])
            for name, value in d.items():
                if value is None and name in _FLOAT_COLUMNS:
                    d[name] = math.nan
            if with_arrays:
                d["path"] = array_from_blob(d["path"])
                d["times"] = array_from_blob(d["times"])
            out.append(d)
        return out


def _float_columns() -> set[str]:
    return {n for n, sql in _evaluation_columns() if sql == "REAL"} | {
        "time_limit",
        "wall_time",
        "validation_time",
        "elapsed",
    }


_FLOAT_COLUMNS = _float_columns()


def iter_keys(rows: Iterable[dict[str, Any]]) -> list[RunKey]:
    return [(r["suite"], r["problem"], r["planner"], int(r["seed"])) for r in rows]
