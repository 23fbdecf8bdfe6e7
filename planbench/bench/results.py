"""Results as data: a results file as a pandas DataFrame, and as Parquet.

::

    import planbench.bench.results
    df = planbench.bench.results.load("results.db")                  # one row per run
    df.groupby("planner")["success"].mean()                    # success rate per planner
    df.loc[df.success, "planning_time"].median()               # [s], validated successes
    path = df.loc[0, "path"]                                    # (N, nq) float64 array [rad], or None

Columns are the results file's (:mod:`planbench.bench.db`): the run's key (suite, problem, family,
planner label, seed), ``success`` and ``failure`` (planbench's own verdict), every metric in SI
units (NaN where a run has none), ``path`` and ``times`` as numpy arrays (None without a path),
and the JSON columns (``info``, ``checks``, ``planner_settings``, ``planner_config``, ``settings``,
``versions``) decoded to dicts. pandas and pyarrow are the optional extra ``planbench[data]``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planbench.bench.db import ResultsDB
from planbench.errors import PlanbenchError
from planbench.files.outputs import check_output

__all__ = ["JSON_COLUMNS", "load", "write_parquet"]

JSON_COLUMNS = ("info", "checks", "planner_settings", "planner_config", "settings", "versions")
"""Columns the results file stores as JSON text."""


def _pandas() -> Any:
    try:
        import pandas
    except ModuleNotFoundError:
        raise PlanbenchError("results as a DataFrame need pandas: pip install 'planbench[data]'") from None
    return pandas


def load(path: str | Path, suite: str | None = None, paths: bool = True) -> Any:
    """The runs of results file ``path`` (only ``suite``'s when given) as a pandas DataFrame, one
    row per run (module docstring); ``paths=False`` leaves the arrays out (smaller, faster)."""
    pandas = _pandas()
    with ResultsDB(path, read_only=True) as db:
        rows = db.rows(suite, with_arrays=paths)
    for r in rows:
        for name in JSON_COLUMNS:
            r[name] = _decoded(r.get(name))
    frame = pandas.DataFrame(rows)
    return frame


def _decoded(text: Any) -> Any:
    if not isinstance(text, str) or not text:
        return text
    try:
        return json.loads(text)
    except ValueError:
        return text


def write_parquet(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """``rows`` (:meth:`ResultsDB.rows`, with arrays) as one Parquet file: ``path`` and ``times``
    as nested lists of float64, the JSON columns as JSON text (one schema for every run)."""
    pandas = _pandas()
    try:
        import pyarrow  # noqa: F401  (pandas' Parquet engine)
    except ModuleNotFoundError:
        raise PlanbenchError("Parquet needs pyarrow: pip install 'planbench[data]'") from None
    table = []
    for r in rows:
        d = dict(r)
        for name in ("path", "times"):
            a = d.get(name)
            d[name] = None if a is None else np.asarray(a, dtype=float).tolist()
        for name in JSON_COLUMNS:
            v = d.get(name)
            d[name] = v if v is None or isinstance(v, str) else json.dumps(v)
        table.append(d)
    out = check_output(path)
    pandas.DataFrame(table).to_parquet(out, index=False)
    return out
