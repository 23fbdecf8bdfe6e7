"""Exports: OMPL benchmark logs (parsed with OMPL's own reader from the ompl wheel), the Planner
Arena database (loaded with the plannerarena package's reader when installed), CSV of every run.

Records are made in-process with the worker's own ``run_one`` (no worker processes needed here)."""

import csv
import json
import sqlite3

import numpy as np
import pytest

from planbench.bench.db import ResultsDB
from planbench.bench.export import RUN_PROPERTIES, write_ompl_logs, write_planner_arena, write_runs_csv
from planbench.bench.records import failure_record
from planbench.bench.task import RunTask
from planbench.bench.worker import run_one

PROBLEMS = {"mbm:table_pick/0001": "table_pick", "mbm:box/0001": "box"}


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    db_path = tmp_path_factory.mktemp("export") / "r.db"
    with ResultsDB(db_path) as db:
        for problem, family in PROBLEMS.items():
            for label, planner in (("straight-line", "straight-line"), ("noisy", "bench_planners:NoisyPlanner")):
                for seed in (0, 1):
                    task = RunTask(
                        suite="s",
                        problem_id=problem,
                        problem_ref=problem,
                        label=label,
                        planner=planner,
                        seed=seed,
                        time_limit=1.0,
                    )
                    fields = dict(
                        suite="s",
                        problem=problem,
                        family=family,
                        planner=label,
                        seed=seed,
                        planner_name=planner,
                        planner_settings={},
                        time_limit=1.0,
                        settings={"time_limit": 1.0},
                    )
                    db.add_run(fields, run_one(task))
        fields = dict(
            suite="s",
            problem="mbm:box/0001",
            family="box",
            planner="crashy",
            seed=0,
            planner_name="x:Y",
            planner_settings={},
            time_limit=1.0,
            settings={"time_limit": 1.0},
        )
        db.add_run(fields, failure_record("crash", "worker process died with signal SIGSEGV (11) during plan"))
        rows = db.rows()
    rows_db[0] = db_path
    return rows


rows_db: dict[int, object] = {}


def _runs(path):
    conn = sqlite3.connect(path)
    conn.row_factory = sqlite3.Row
    out = conn.execute(
        "SELECT experiments.name AS experiment, plannerConfigs.name AS planner, runs.* FROM runs "
        "JOIN experiments ON experiments.id = runs.experimentid "
        "JOIN plannerConfigs ON plannerConfigs.id = runs.plannerid "
        "ORDER BY experiment, planner, seed"
    ).fetchall()
    conn.close()
    return [{k: r[k] for k in r.keys() if k not in ("id", "experimentid", "plannerid")} for r in out]


def test_ompl_log_parses_with_ompls_own_reader_and_matches_the_planner_arena_export(rows, tmp_path):
    tools = pytest.importorskip("ompl.tools")
    logs = write_ompl_logs(rows, tmp_path / "logs")
    assert sorted(f.name for f in logs) == ["mbm_box_0001.log", "mbm_table_pick_0001.log"]
    tools.readBenchmarkLog(str(tmp_path / "from_logs.db"), [str(f) for f in logs], False)
    write_planner_arena(rows, tmp_path / "arena.db")
    from_logs, direct = _runs(tmp_path / "from_logs.db"), _runs(tmp_path / "arena.db")
    assert len(direct) == len(rows) == 9
    assert from_logs == direct  # OMPL's reader of our logs gives exactly our Planner Arena tables
    crash = [r for r in direct if r["planner"] == "crashy"][0]
    assert crash["time"] is None and crash["solved"] == 0
    ok = [r for r in direct if r["planner"] == "straight-line" and r["experiment"] == "table_pick"]
    assert [r["solved"] for r in ok] == [1, 1] and ok[0]["time"] > 0 and ok[0]["solution_length"] > 0
    names = {r[1] for r in sqlite3.connect(tmp_path / "arena.db").execute("PRAGMA table_info(runs)")}
    assert {"time", "solved", "status", "solution_length", "solution_clearance", "ee_path_length", "seed"} <= names
    assert len(names) == 3 + len(RUN_PROPERTIES)


def test_planner_arena_database_loads_with_plannerarenas_reader(rows, tmp_path):
    database = pytest.importorskip("plannerarena.database", reason="pip install plannerarena")
    write_planner_arena(rows, tmp_path / "arena.db")
    data = database.load_database(tmp_path / "arena.db")
    assert sorted(data["problem_names"]) == ["box", "table_pick"]  # experiments per family
    assert data["runs"].height == 9
    assert {"time", "solved", "status", "solution length", "setup time"} <= set(data["attributes"])
    assert data["parameters"] == ["family", "problem"]
    assert set(data["planner_configs"]["planner"].cast(str).to_list()) == {"straight-line", "noisy", "crashy"}
    assert "crash" in data["enums"]["description"].to_list()


def test_runs_csv_has_every_run_and_no_path_blobs(rows, tmp_path):
    write_runs_csv(rows, tmp_path / "runs.csv")
    with open(tmp_path / "runs.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 9
    assert "path" not in table[0] and {"planning_time", "status", "traceback", "seed"} <= set(table[0])
    assert [r["status"] for r in table if r["planner"] == "crashy"] == ["crash"]


def test_results_load_as_a_dataframe_with_paths_and_decoded_json(rows):
    import planbench.bench.results

    df = planbench.bench.results.load(rows_db[0])
    assert len(df) == len(rows) == 9 and set(df.planner) == {"straight-line", "noisy", "crashy"}
    ok = df[df.success]
    assert len(ok) >= 1 and all(p.ndim == 2 and p.shape[1] == 7 for p in ok.path)
    assert df.loc[df.planner == "crashy", "path"].iloc[0] is None
    assert isinstance(df.settings.iloc[0], dict) and df.settings.iloc[0]["time_limit"] == 1.0
    rate = df.groupby("planner")["success"].mean()
    assert rate["crashy"] == 0.0
    assert "path" not in planbench.bench.results.load(rows_db[0], paths=False).columns


def test_parquet_and_csv_with_paths_round_trip_the_paths(rows, tmp_path):
    import pandas

    import planbench.bench.results
    from planbench.cli.main import main

    assert main(["export", str(rows_db[0]), "--format", "parquet", "--out", str(tmp_path / "r.parquet")]) == 0
    back = pandas.read_parquet(tmp_path / "r.parquet")
    df = planbench.bench.results.load(rows_db[0])
    assert len(back) == len(df)
    for a, b in zip(df.path, back.path, strict=True):
        assert (a is None and b is None) or np.allclose(a, np.array([list(x) for x in b]))
    assert main(["export", str(rows_db[0]), "--format", "csv", "--paths", "--out", str(tmp_path / "r.csv")]) == 0
    with open(tmp_path / "r.csv", newline="") as f:
        runs = list(csv.DictReader(f))
    first = next(r for r in runs if r["path"])
    assert np.array(json.loads(first["path"])).shape[1] == 7


def test_a_results_file_from_elsewhere_cannot_put_code_in_a_report(tmp_path):
    from planbench.cli.main import main

    evil = "<script>alert('x')</script>"
    db_path = tmp_path / "evil.db"
    with ResultsDB(db_path) as db:
        db.put_suite("s" + evil, {"name": evil, "planners": []}, json.dumps({"note": evil}))
        fields = dict(
            suite="s" + evil,
            problem="mbm:box/0001" + evil,
            family=evil,
            planner=evil,
            seed=0,
            planner_name=evil,
            planner_settings={"x": evil},
            time_limit=1.0,
            settings={"time_limit": 1.0},
        )
        db.add_run(fields, failure_record("error", evil, traceback=evil))
    out = tmp_path / "r.html"
    assert main(["report", str(db_path), "--html", str(out)]) == 0
    page = out.read_text()
    assert "<script" not in page.lower()
    assert "&lt;script&gt;" in page  # the text is there, as text: in the tables, the run list, the settings
    assert page.count("&lt;script&gt;") >= 5
