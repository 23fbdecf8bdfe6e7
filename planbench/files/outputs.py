"""What every file planbench writes is protected against.

- :func:`check_output`: no command writes a report, export, plot or replay over a results file
  (the one it reads, under any name, or any other SQLite database): a mistyped ``--out`` would
  otherwise replace hours of runs with HTML.
- :func:`csv_cell`: CSV cells that a spreadsheet would run as a formula are escaped; planner
  labels, messages and settings are chosen by whoever wrote the suite or the plugin.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from planbench.errors import OutputFileError

__all__ = ["check_output", "csv_cell", "is_sqlite_file"]

SQLITE_HEADER = b"SQLite format 3\x00"
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def is_sqlite_file(path: str | Path) -> bool:
    """Whether ``path`` is a regular file that starts with SQLite's header."""
    try:
        with open(path, "rb") as f:
            return f.read(len(SQLITE_HEADER)) == SQLITE_HEADER
    except OSError:
        return False


def check_output(path: str | Path, inputs: Iterable[str | Path] = ()) -> Path:
    """``path`` as a Path, or :class:`OutputFileError` when writing it would destroy a results
    file: ``path`` is one of ``inputs`` (the same inode: any name, link or spelling of it) or an
    existing SQLite database. A folder passes; the writers check each file they put in it."""
    out = Path(path)
    try:
        st = os.stat(out)
    except OSError:  # nothing there yet (or unreadable: the writer reports that)
        return out
    for source in inputs:
        if _same_file(st, source):
            raise OutputFileError(
                out, f"is the results file {source} itself; give an output path of its own (e.g. --out report.html)"
            )
    if stat.S_ISREG(st.st_mode) and is_sqlite_file(out):
        raise OutputFileError(
            out,
            "is a SQLite database (a results file?); planbench never writes an output over one. Choose another "
            "output path, or delete the file first if it really is to be replaced",
        )
    return out


def _same_file(st: os.stat_result, other: str | Path) -> bool:
    try:
        o = os.stat(other)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == (o.st_dev, o.st_ino)


def csv_cell(value: Any) -> Any:
    """``value`` for a CSV cell: text starting with ``= + - @``, a tab or a carriage return gets a
    leading ``'`` (OWASP's rule against CSV injection), so a spreadsheet shows it as text instead
    of running it; numbers are kept as they are (a float -0.5 stays -0.5)."""
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        return "'" + value
    return value
