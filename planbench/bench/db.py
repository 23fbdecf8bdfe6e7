"""The results database: SQLite, embedded, one row per run, written and committed as each run ends.

Schema (``planbench-results/1``)::

    meta(key TEXT PRIMARY KEY, value TEXT)          -- schema version
    suites(name TEXT PRIMARY KEY, definition TEXT,  -- the suite as JSON (planners, seeds, limits)
           settings TEXT, created TEXT)             -- the settings that change results, JSON
    runs(id INTEGER PRIMARY KEY,
         suite, problem, family, planner (the label), seed,        -- UNIQUE(suite, problem, planner, seed)
         planner_name, planner_settings (JSON: the settings given), planner_config (JSON: every
         setting of the planner as built, defaults included), planner_version,
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

Who may open a file how:

- ``planbench bench`` opens it writable and holds :meth:`ResultsDB.lock_for_writing` (an
  ``flock`` on the file itself, so on its inode, whatever name reaches it) for the whole benchmark,
  so a second ``bench`` on the same file refuses at start and names the first, instead of redoing
  its runs and colliding on the key. A writable open refuses a symbolic link and a file with more
  than one hard link: SQLite names its ``-wal`` journal after the path, so two names of one file
  would be two journals, and runs written through one of them would be lost.
- ``report`` and ``export`` open it read-only (``ResultsDB(path, read_only=True)``): nothing is
  created or migrated, the file stays byte-identical; migrations of older files are applied to
  the rows as they are read. A file without planbench's ``meta`` table is refused.
  (SQLite may still create its ``-wal``/``-shm`` companion files next to a WAL file, as any
  reader does; the results file itself is not written.)
- Every SQLite failure (damaged pages, a file that is not SQLite) becomes a
  :class:`~planbench.errors.ResultsFileError` naming the file, at whichever query meets it;
  read-only opens and the writer's lock also run ``PRAGMA quick_check`` first.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import functools
import importlib.metadata
import io
import json
import logging
import math
import os
import platform
import socket
import sqlite3
import stat
import sys
import urllib.parse
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from planbench.errors import PlanbenchError, ResultsFileError, ResultsLockedError, UnstorableValueError
from planbench.validate import Evaluation

log = logging.getLogger(__name__)

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
    ("planner_config", "TEXT"),
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
    cols = []
    for f in dataclasses.fields(Evaluation):
        t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        t = t.removesuffix(" | None")
        sql = {"bool": "INTEGER", "int": "INTEGER", "float": "REAL", "str": "TEXT"}.get(t, "TEXT")
        cols.append((f.name, sql))
    return cols


def package_versions() -> dict[str, str]:
    """Versions of Python, planbench and the key dependencies ("" when not installed)."""
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
    buf = io.BytesIO(blob)  # the header's claim checked before numpy allocates for it
    version = np.lib.format.read_magic(buf)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(buf)
    if dtype.hasobject or len(blob) - buf.tell() < math.prod(shape) * dtype.itemsize:
        raise ValueError(f"its header claims a {dtype} array of shape {shape}, in {len(blob)} bytes")
    buf.seek(0)
    return np.load(buf, allow_pickle=False)  # type: ignore[no-any-return]


INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def _sql_value(v: Any, column: str = "?", path: object = "<results>") -> Any:
    """``v`` as SQLite stores it, or :class:`UnstorableValueError` naming ``column``.

    Refusing (rather than storing an oversized int as text) keeps every column's type what its
    readers expect; the producer of the bad value is the one to turn it into an error row.
    """
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (dict, list, tuple)):
        try:
            v = json.dumps(v, sort_keys=True)
        except (TypeError, ValueError, RecursionError) as exc:
            raise UnstorableValueError(path, column, v, f"not JSON-serialisable ({exc})") from exc
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and math.isnan(v):
        return None
    if isinstance(v, int) and not INT64_MIN <= v <= INT64_MAX:
        raise UnstorableValueError(path, column, v, "SQLite integers are 64-bit (|value| < 2**63)")
    if isinstance(v, str):
        try:
            v.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise UnstorableValueError(path, column, v, f"not valid UTF-8 text ({exc.reason})") from exc
    if v is not None and not isinstance(v, (int, float, str, bytes)):
        raise UnstorableValueError(path, column, v, f"a {type(v).__name__} is not a number, text or bytes")
    return v


_F = TypeVar("_F", bound=Callable[..., Any])


def _sqlite_errors(method: _F) -> _F:
    """Turn SQLite failures inside ``method`` into a ResultsFileError naming the file.

    Damaged pages surface at whichever query first reads them, not at connect, so every query
    site is covered, not only the opening.
    """

    @functools.wraps(method)
    def wrapper(self: ResultsDB, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(self, *args, **kwargs)
        except sqlite3.DatabaseError as exc:
            raise _file_error(self.path, exc) from exc

    return wrapper  # type: ignore[return-value]


def _file_error(path: Path, exc: sqlite3.DatabaseError) -> ResultsFileError:
    text = str(exc)
    if "malformed" in text or "not a database" in text or "encrypted" in text:
        return ResultsFileError(
            path,
            f"damaged or not a SQLite file ({text}). Keep a copy, then recover the readable runs with "
            f"`sqlite3 {path} .recover | sqlite3 recovered.db`, or run the benchmark into a new --out",
        )
    if "readonly" in text or "read-only" in text:
        return ResultsFileError(path, f"cannot write ({text}): check the file's and folder's permissions")
    return ResultsFileError(path, f"SQLite error: {text}")


class ResultsDB:
    """A results file. ``ResultsDB(path)`` opens it for writing and creates it (and the tables)
    when missing; ``create=False`` requires an existing file; ``read_only=True`` opens an
    existing planbench results file without writing anything (see the module docstring)."""

    def __init__(self, path: str | Path, create: bool = True, read_only: bool = False) -> None:
        self.path = Path(path)
        self.read_only = read_only
        self._fd = -1  # writable: an fd of the file, for the writer's lock (see _open_writable)
        self._holder: Path | None = None  # while locked: the file describing this process
        self.versions = package_versions()
        self.host = socket.gethostname()
        if self.path.exists() and not self.path.is_file():
            raise ResultsFileError(self.path, "is a folder or a device, not a results file; give a file name")
        if (read_only or not create) and not self.path.is_file():
            raise ResultsFileError(self.path, "no such results database (write one with `planbench bench --out`)")
        try:
            if read_only:
                self._open_read_only()
            else:
                self._open_writable()
        except sqlite3.DatabaseError as exc:
            self._close_quietly()
            raise _file_error(self.path, exc) from exc
        except PlanbenchError:
            self._close_quietly()
            raise

    def _open_writable(self) -> None:
        """Open an fd of the file first (refusing links), then SQLite's connection.

        The fd carries the writer's ``flock``. It is closed only after the connection (in
        :meth:`close`): closing any fd of a file drops every POSIX lock this process holds on it,
        SQLite's own included (an idle WAL connection holds one).
        """
        self._fd = _open_for_lock(self.path)
        self.conn = sqlite3.connect(str(self.path), timeout=30.0)
        self.conn.row_factory = sqlite3.Row
        self._require_planbench(allow_empty=True)
        self.conn.execute("PRAGMA journal_mode=WAL")
        self.conn.execute("PRAGMA synchronous=NORMAL")
        self._create()

    def _open_read_only(self) -> None:
        uri = f"file:{urllib.parse.quote(str(self.path.resolve()))}?mode=ro"
        self.conn = sqlite3.connect(uri, uri=True, timeout=30.0)
        self.conn.row_factory = sqlite3.Row
        self._require_planbench(allow_empty=False)
        if not self._tables() >= {"runs", "suites"}:
            raise ResultsFileError(self.path, "a planbench results file without its runs/suites tables")
        self.columns = [r[1] for r in self.conn.execute("PRAGMA table_info(runs)")]
        self.check_integrity()  # damage anywhere, not only in the pages a report happens to read

    def _tables(self) -> set[str]:
        return {r[0] for r in self.conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}

    def _require_planbench(self, allow_empty: bool) -> None:
        """Refuse a SQLite file that planbench did not write (no ``meta`` table with the schema),
        so that no command adds tables to somebody else's database."""
        tables = self._tables()
        if not tables and allow_empty:
            return
        row = None
        if "meta" in tables:
            row = self.conn.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        if row is None:
            raise ResultsFileError(
                self.path,
                "not a planbench results file (no 'meta' table with a 'schema' entry); "
                "give the file `planbench bench --out` wrote, or another --out for a new benchmark",
            )
        if row[0] != SCHEMA:
            raise ResultsFileError(self.path, f"results schema {row[0]!r}, this planbench reads {SCHEMA!r}")

    def _close_quietly(self) -> None:
        conn = getattr(self, "conn", None)
        if conn is not None:
            with contextlib.suppress(sqlite3.Error):
                conn.close()
        self._close_fd()

    def _close_fd(self) -> None:
        self._unlock()
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def _create(self) -> None:
        with self.conn:
            self.conn.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            self.conn.execute("INSERT OR IGNORE INTO meta VALUES ('schema', ?)", (SCHEMA,))
            self.conn.execute(
                "CREATE TABLE IF NOT EXISTS suites "
                "(name TEXT PRIMARY KEY, definition TEXT, settings TEXT, created TEXT)"
            )
            cols = _all_columns()
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

    # -- the writer's lock ------------------------------------------------------------------------

    @property
    def holder_path(self) -> Path:
        """The file describing the lock's holder: keyed by the inode, so that a second writer that
        reached the file by another name (a renamed file, a bind mount) still finds it."""
        return self.path.parent / f".planbench-writer-{os.fstat(self._fd).st_ino}"

    @contextlib.contextmanager
    def lock_for_writing(self) -> Iterator[None]:
        """Hold the exclusive writer's lock of this file and check its pages.

        A second ``planbench bench`` on the same file raises :class:`ResultsLockedError` naming the
        holder (pid, host, start time, command) before it does any work. The lock is an ``flock`` on
        the results file itself (its inode, not its name), independent of SQLite's POSIX locks; the
        kernel drops it when the holder exits, kill -9 included, so it never blocks anyone after.
        ``PRAGMA quick_check`` runs under the lock, so a damaged file is refused before any run is
        planned rather than when a record meets a bad page.
        """
        self._require_writable()
        if self._fd < 0:  # pragma: no cover (not POSIX): no lock, as before
            yield
            return
        _refuse_links(self.path, os.fstat(self._fd))  # a link made since the file was opened
        self._require_same_file()
        holder = self.holder_path
        _acquire_lock(self.path, self._fd, holder)
        self._holder = holder
        try:
            self.check_integrity()
            yield
        finally:
            self._unlock()

    def _unlock(self) -> None:
        """Remove the holder's description while still holding the lock, then drop the lock (the
        fd stays open until the connection is closed, see :meth:`_open_writable`)."""
        if self._holder is None:
            return
        with contextlib.suppress(OSError):
            self._holder.unlink()
        self._holder = None
        if self._fd >= 0:
            import fcntl

            fcntl.flock(self._fd, fcntl.LOCK_UN)

    def _require_same_file(self) -> None:
        """Refuse when the path no longer names the file this object opened (replaced meanwhile)."""
        try:
            now = os.stat(self.path, follow_symlinks=False)
        except FileNotFoundError:
            now = None
        mine = os.fstat(self._fd)
        if now is None or (now.st_dev, now.st_ino) != (mine.st_dev, mine.st_ino):
            raise ResultsFileError(self.path, "was replaced or removed while opening it; run the command again")

    @_sqlite_errors
    def check_integrity(self) -> None:
        """Raise :class:`ResultsFileError` when SQLite's quick check finds damaged pages."""
        problems = [r[0] for r in self.conn.execute("PRAGMA quick_check(5)")]
        if problems != ["ok"]:
            lines = [x.strip() for p in problems for x in p.splitlines() if x.strip() and not x.startswith("***")]
            raise ResultsFileError(
                self.path,
                "damaged (" + "; ".join(lines) + "). Keep a copy, then recover the readable runs with "
                f"`sqlite3 {self.path} .recover | sqlite3 recovered.db`, or run the benchmark into a new --out",
            )

    def close(self) -> None:
        self.conn.close()
        self._close_fd()  # after the connection: see _open_writable

    def __enter__(self) -> ResultsDB:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- suites ----------------------------------------------------------------------------------

    @_sqlite_errors
    def suite_settings(self, name: str) -> tuple[dict[str, Any], dict[str, Any]] | None:
        """(definition, settings) stored for suite ``name``, or None."""
        row = self.conn.execute("SELECT definition, settings FROM suites WHERE name=?", (name,)).fetchone()
        try:
            return None if row is None else (json.loads(row[0]), json.loads(row[1]))
        except (TypeError, ValueError) as exc:
            raise ResultsFileError(self.path, f"suite {name!r}: its stored settings are not JSON ({exc})") from None

    @_sqlite_errors
    def put_suite(self, name: str, definition: dict[str, Any], settings_json: str) -> None:
        self._require_writable()
        now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        with self.conn:
            self.conn.execute(
                "INSERT OR REPLACE INTO suites VALUES "
                "(?, ?, ?, COALESCE((SELECT created FROM suites WHERE name=?), ?))",
                (name, json.dumps(definition, sort_keys=True, default=str), settings_json, name, now),
            )

    @_sqlite_errors
    def delete_suite_runs(self, name: str) -> int:
        self._require_writable()
        with self.conn:
            return self.conn.execute("DELETE FROM runs WHERE suite=?", (name,)).rowcount

    @_sqlite_errors
    def suites(self) -> list[str]:
        return [r[0] for r in self.conn.execute("SELECT DISTINCT suite FROM runs ORDER BY suite")]

    # -- runs ------------------------------------------------------------------------------------

    @_sqlite_errors
    def done_keys(self, suite: str) -> set[RunKey]:
        rows = self.conn.execute("SELECT suite, problem, planner, seed FROM runs WHERE suite=?", (suite,))
        return {(r[0], r[1], r[2], int(r[3])) for r in rows}

    @_sqlite_errors
    def count(self, suite: str | None = None) -> int:
        if suite is None:
            return int(self.conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
        return int(self.conn.execute("SELECT COUNT(*) FROM runs WHERE suite=?", (suite,)).fetchone()[0])

    @_sqlite_errors
    def add_run(self, fields: dict[str, Any], record: dict[str, Any]) -> bool:
        """Insert one run: ``fields`` (key, planner, settings) and the worker's ``record``; commits.

        Returns False, with a warning, when the run's key already has a row: the stored run is
        complete (rows are written whole), so keeping it is what ``--resume`` would do, and
        crashing here would throw away every run still in flight. A value SQLite cannot store
        raises :class:`UnstorableValueError` naming the column, before anything is written.
        """
        self._require_writable()
        row = self._run_row(fields, record)
        names = [n for n in row if n in self.columns]
        missing = set(row) - set(self.columns)
        if missing:
            raise ResultsFileError(self.path, f"run fields {sorted(missing)} have no column")
        values = [_sql_value(row[n], n, self.path) for n in names]
        sql = f"INSERT INTO runs ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})"
        try:
            with self.conn:
                self.conn.execute(sql, values)
        except sqlite3.IntegrityError as exc:
            key = tuple(row.get(k) for k in _KEY_COLS)
            if not self._has_key(key):
                raise ResultsFileError(self.path, f"run {key} not stored: {exc}") from exc
            log.warning("%s: run %s is already stored; keeping the stored row, not this one", self.path, key)
            return False
        return True

    def _require_writable(self) -> None:
        if self.read_only:
            raise ResultsFileError(self.path, "opened read-only (as report and export do); runs are written by bench")

    def _has_key(self, key: tuple[Any, ...]) -> bool:
        where = " AND ".join(f"{k}=?" for k in _KEY_COLS)
        return self.conn.execute(f"SELECT 1 FROM runs WHERE {where}", key).fetchone() is not None

    def _run_row(self, fields: dict[str, Any], record: dict[str, Any]) -> dict[str, Any]:
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
        return row

    @_sqlite_errors
    def rows(self, suite: str | None = None, with_arrays: bool = False) -> list[dict[str, Any]]:
        """Runs as dicts in key order (``path``/``times`` decoded when ``with_arrays``).

        Every column of the current schema is present; in an older file opened read-only the
        columns it lacks read as missing values, and its check counts are moved as
        :meth:`_create` would move them.
        """
        cols = [c for c in self.columns if with_arrays or c not in ("path", "times")]
        sql = f"SELECT {', '.join(cols)} FROM runs"
        args: tuple[Any, ...] = ()
        if suite is not None:
            sql += " WHERE suite=?"
            args = (suite,)
        sql += " ORDER BY suite, planner, problem, seed"
        absent = [n for n, _ in _all_columns() if n not in self.columns and (with_arrays or n not in ("path", "times"))]
        old_counts = "validation_checks" in absent and "collision_checks" in self.columns
        out = []
        for r in self.conn.execute(sql, args):
            d = dict(r)
            d.update(dict.fromkeys(absent))
            if old_counts:
                d["validation_checks"], d["collision_checks"] = d["collision_checks"], _info_count(d.get("info"))
            d["success"] = bool(d["success"])
            for name, value in d.items():
                if value is None and name in _FLOAT_COLUMNS:
                    d[name] = math.nan
                elif name in _FLOAT_COLUMNS and not isinstance(value, (int, float)):
                    raise ResultsFileError(self.path, f"run {d.get('id')}: column {name} holds {value!r}, not a number")
            if with_arrays:
                try:
                    d["path"] = array_from_blob(d["path"])
                    d["times"] = array_from_blob(d["times"])
                except (ValueError, EOFError) as exc:
                    raise ResultsFileError(
                        self.path, f"run {d.get('id')}: its path is not a readable array ({exc})"
                    ) from None
            out.append(d)
        return out


def _info_count(info: Any) -> Any:
    """The planner's own ``collision_checks`` from a run's info JSON (None when absent)."""
    try:
        value = json.loads(info).get("collision_checks")
    except (TypeError, ValueError, AttributeError):
        return None
    return value if isinstance(value, int) else None


def _all_columns() -> list[tuple[str, str]]:
    """The runs table's columns (without ``id``) in table order, for the current Evaluation."""
    return list(_RUN_COLS[:5]) + _evaluation_columns() + list(_RUN_COLS[5:])


def _refuse_links(path: Path, st: os.stat_result) -> None:
    """Refuse a symbolic link and a file with several hard links: SQLite keeps a ``-wal`` journal
    per name, so writing one file through two names loses the runs of one of them."""
    if stat.S_ISLNK(st.st_mode):
        raise ResultsFileError(
            path,
            f"is a symbolic link (to {os.readlink(path)}); planbench writes a results file only by its "
            f"real path: give --out {path.resolve()}",
        )
    if st.st_nlink > 1:
        raise ResultsFileError(
            path,
            f"has {st.st_nlink} hard links (other names for the same file); two names mean two SQLite "
            f"journals and lost runs. Remove the other names, or copy the file (cp {path} copy.db) and "
            "write the copy",
        )


def _open_for_lock(path: Path) -> int:
    """An fd of the results file (created when missing), never through a symbolic link, or -1
    where there is no ``flock`` (not POSIX)."""
    try:
        import fcntl  # noqa: F401  (POSIX only: imported where it is used, so the module loads anywhere)
    except ImportError:  # pragma: no cover
        return -1
    with contextlib.suppress(FileNotFoundError):
        _refuse_links(path, os.lstat(path))
    flags = os.O_RDONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        why = f"cannot open: {exc.strerror}; check the path and its folder's permissions"
        raise ResultsFileError(path, why) from exc
    try:
        _refuse_links(path, os.fstat(fd))
    except ResultsFileError:
        os.close(fd)
        raise
    return fd


def _acquire_lock(db_path: Path, fd: int, holder_path: Path) -> None:
    """Take ``flock(LOCK_EX)`` on the results file's fd and describe this process in
    ``holder_path``; :class:`ResultsLockedError` naming the holder when another one has it."""
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError as exc:
        raise ResultsLockedError(db_path, _read_holder(holder_path)) from exc
    except OSError as exc:
        raise ResultsFileError(db_path, f"cannot lock it ({exc.strerror}); put it on a local file system") from exc
    _write_holder(holder_path)


def _write_holder(holder_path: Path) -> None:
    """Describe this process in ``holder_path`` (written whole, then renamed: never half read)."""
    started = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    info = {"pid": os.getpid(), "host": socket.gethostname(), "started": started, "command": " ".join(sys.argv)[:500]}
    part = holder_path.with_name(f"{holder_path.name}.{os.getpid()}")
    try:
        part.write_text(json.dumps(info))
        os.replace(part, holder_path)
    except OSError as exc:  # the lock holds without its description
        log.warning("%s: cannot describe the writer's lock (%s)", holder_path, exc)


def _read_holder(holder_path: Path) -> str:
    """The lock holder as text: pid, host, start time and command line."""
    try:
        info = json.loads(holder_path.read_text(errors="replace"))
        return f"pid {info['pid']} on host {info['host']}, started {info['started']}: {info['command']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "a process that has not written its details yet"


def _float_columns() -> set[str]:
    return {n for n, sql in _evaluation_columns() if sql == "REAL"} | {
        "time_limit",
        "wall_time",
        "validation_time",
        "elapsed",
    }


_FLOAT_COLUMNS = _float_columns()
