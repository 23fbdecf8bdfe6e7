"""The Planner Arena export as Planner Arena uses it: experiments per family (or suite, or problem),
read back with the plannerarena package's own loader and filters, and with the SQL the original R
app runs (OMPL's ``scripts/plannerarena/server.R``: its joins, its renames, its problem parameters).

Records are made in-process with the worker's own ``run_one`` (fast planners, no worker processes).
"""

import dataclasses
import io
import json
import math
import sqlite3

import numpy as np
import pytest

from conftest import midpoint_wall
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.export import (
    EXPERIMENT_PARAMETERS,
    experiments,
    planner_settings,
    run_progress,
    write_ompl_logs,
    write_planner_arena,
)
from planbench.bench.suite import parse_suite
from planbench.bench.task import RunTask
from planbench.bench.worker import run_one
from planbench.cli.main import main
from planbench.errors import InvalidSettingError
from planbench.problem import Problem
from planbench.registry import REGISTRY
from planbench.scene import Scene
from planbench_plugins.ompl_planners.base import OMPLConfig

PROBLEMS = {"mbm:box/0001": "box", "mbm:box/0002": "box", "mbm:table_pick/0001": "table_pick"}
PLANNERS = {"straight-line": "straight-line", "noisy": "bench_planners:NoisyPlanner"}
SEEDS = (0, 1)

# What server.R reads: the experiments' twelve fixed columns (then the problem parameters), the
# planner configurations, and runs joined to both by id (`runs_ext`), filtered by name and version.
FIXED_EXPERIMENT_COLUMNS = [
    "id",
    "name",
    "totaltime",
    "timelimit",
    "memorylimit",
    "runcount",
    "version",
    "hostname",
    "cpuinfo",
    "date",
    "seed",
    "setup",
]
RUNS_EXT = (
    "SELECT plannerConfigs.name AS planner, plannerConfigs.settings, runs.*, experiments.* FROM plannerConfigs "
    "JOIN runs ON plannerConfigs.id = runs.plannerid JOIN experiments ON runs.experimentid = experiments.id "
    "WHERE experiments.name = ? AND experiments.version = ?"
)


def _record(db, suite, problem, family, label, seed):
    task = RunTask(
        suite=suite, problem_id=problem, problem_ref=problem, label=label, planner=PLANNERS[label], seed=seed
    )
    fields = dict(
        suite=suite,
        problem=problem,
        family=family,
        planner=label,
        seed=seed,
        planner_name=PLANNERS[label],
        planner_settings={},
        time_limit=1.0,
        settings={"time_limit": 1.0},
    )
    db.add_run(fields, run_one(task))


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    path = tmp_path_factory.mktemp("arena") / "results.db"
    with ResultsDB(path) as db:
        for problem, family in PROBLEMS.items():
            for label in PLANNERS:
                for seed in SEEDS:
                    _record(db, "s", problem, family, label, seed)
    return path


@pytest.fixture(scope="module")
def rows(results):
    with ResultsDB(results, read_only=True) as db:
        return db.rows()


def _connect(path):
    conn = sqlite3.connect(path)
    conn.row_factory = sqlite3.Row
    return conn


def test_one_experiment_per_family_holds_every_run_of_that_family(rows, tmp_path):
    path = write_planner_arena(rows, tmp_path / "arena.db")
    conn = _connect(path)
    columns = [r[1] for r in conn.execute("PRAGMA table_info(experiments)")]
    assert columns == FIXED_EXPERIMENT_COLUMNS + list(EXPERIMENT_PARAMETERS)
    names = [r[0] for r in conn.execute("SELECT DISTINCT name FROM experiments ORDER BY name")]
    assert names == ["box", "table_pick"]
    version = conn.execute("SELECT version FROM experiments").fetchone()[0]
    for family in names:
        runs = conn.execute(RUNS_EXT, (family, version)).fetchall()
        expected = [r for r in rows if r["family"] == family]
        assert len(runs) == len(expected) == sum(p == family for p in PROBLEMS.values()) * len(PLANNERS) * len(SEEDS)
        assert {r["problem"] for r in runs} == {r["problem"] for r in expected}
        # every planner has all of its runs of the family under one planner configuration
        for label in PLANNERS:
            mine = [r for r in runs if r["planner"] == label]
            assert len(mine) == len(expected) // len(PLANNERS) and len({r["plannerid"] for r in mine}) == 1
    conn.close()


@pytest.mark.parametrize(
    ("by", "names"),
    [("suite", ["s"]), ("problem", sorted(PROBLEMS)), ("family", ["box", "table_pick"])],
)
def test_experiments_by_suite_family_or_problem(rows, by, names):
    exps = experiments(rows, by)
    assert sorted({e["name"] for e in exps}) == names
    assert sum(len(runs) for e in exps for runs in e["planners"].values()) == len(rows)
    assert [e["parameters"]["problem"] for e in exps if e["problem"] == "mbm:box/0002"] == ["mbm:box/0002"]


def test_several_suites_keep_their_experiments_apart(rows):
    other = [{**r, "suite": "t"} for r in rows]
    names = sorted({e["name"] for e in experiments(rows + other, "family")})
    assert names == ["s:box", "s:table_pick", "t:box", "t:table_pick"]
    with pytest.raises(ValueError, match="family"):
        experiments(rows, "planner")


def test_plannerarenas_loader_shows_families_and_filters_each_problem(rows, tmp_path):
    database = pytest.importorskip("plannerarena.database", reason="pip install plannerarena")
    widgets = pytest.importorskip("plannerarena.widgets")
    path = write_planner_arena(rows, tmp_path / "arena.db")
    data = database.load_database(path)
    assert data["problem_names"] == ["box", "table_pick"]
    assert data["parameters"] == ["family", "problem"]
    # what the performance page plots for experiment "box": all its runs, every planner
    box = data["runs"].filter(data["runs"]["experiment"] == "box")
    assert box.height == 2 * len(PLANNERS) * len(SEEDS)
    assert set(box["planner"].cast(str).to_list()) == set(PLANNERS)
    # one problem of the family, as its problem-parameter selector filters it
    one = widgets.problem_parameter_filter(box, {"problem": "mbm:box/0002", "family": "box"})
    assert one.height == len(PLANNERS) * len(SEEDS) and set(one["problem"].to_list()) == {"mbm:box/0002"}
    every = widgets.problem_parameter_filter(box, {"problem": widgets.PROBLEM_PARAMETERS_AGGREGATE_TEXT})
    assert every.height == box.height


def test_ompl_logs_read_by_ompls_reader_give_the_same_experiments(rows, tmp_path):
    tools = pytest.importorskip("ompl.tools")
    logs = write_ompl_logs(rows, tmp_path / "logs", by="family")
    assert sorted(f.name for f in logs) == ["mbm_box_0001.log", "mbm_box_0002.log", "mbm_table_pick_0001.log"]
    tools.readBenchmarkLog(str(tmp_path / "from_logs.db"), [str(f) for f in logs], False)
    write_planner_arena(rows, tmp_path / "arena.db", by="family")
    query = "SELECT name, family, problem, runcount FROM experiments ORDER BY name, problem"
    from_logs = [tuple(r) for r in _connect(tmp_path / "from_logs.db").execute(query)]
    direct = [tuple(r) for r in _connect(tmp_path / "arena.db").execute(query)]
    assert from_logs == direct
    assert [r[0] for r in direct] == ["box", "box", "table_pick"]


def test_cli_export_experiments_per_suite(results, tmp_path, capsys):
    out = tmp_path / "suite.db"
    assert main(["export", str(results), "--format", "planner-arena", "--experiments", "suite", "--out", str(out)]) == 0
    assert "1 experiment(s), one per suite" in capsys.readouterr().out
    conn = _connect(out)
    assert [r[0] for r in conn.execute("SELECT DISTINCT name FROM experiments")] == ["s"]
    assert conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0] == len(PROBLEMS) * len(PLANNERS) * len(SEEDS)
    conn.close()


RRTSTAR = {"optimize": True, "params": {"range": 0.5}}  # (with OMPL's default range, no path around the plate in 1 s)


@pytest.fixture(scope="module")
def anytime_results(tmp_path_factory, panda):
    """RRT* (optimize: the whole 1 s) in free space and around a plate, RRT-Connect (no progress) there."""
    folder = tmp_path_factory.mktemp("progress")
    start, goal = panda.home, panda.home + 0.3
    scenes = {"free": Scene(name="free"), "plate": Scene([midpoint_wall(panda, start, goal)], name="plate")}
    for name, scene in scenes.items():
        Problem.create(panda, scene, start, goal, id=name).save(folder / f"{name}.json")
    path = folder / "results.db"
    with ResultsDB(path) as db:
        for problem, label, planner, settings in (
            ("free", "rrtstar", "ompl-rrtstar", RRTSTAR),
            ("plate", "rrtstar", "ompl-rrtstar", RRTSTAR),
            ("plate", "rrtconnect", "ompl-rrtconnect", {}),
        ):
            ref = str(folder / f"{problem}.json")
            task = RunTask(
                suite="p",
                problem_id=problem,
                problem_ref=ref,
                label=label,
                planner=planner,
                seed=0,
                settings=settings,
                time_limit=1.0,
            )
            fields = dict(
                suite="p",
                problem=problem,
                family="",
                planner=label,
                seed=0,
                planner_name=planner,
                planner_settings=settings,
                time_limit=1.0,
                settings={"time_limit": 1.0},
            )
            db.add_run(fields, run_one(task))
    with ResultsDB(path, read_only=True) as db:
        return db.rows()


@pytest.mark.slow
def test_an_anytime_planners_best_cost_over_time_reaches_the_progress_table(anytime_results, tmp_path):
    free = [r for r in anytime_results if r["planner"] == "rrtstar" and r["problem"] == "free"]
    assert free[0]["status"] == "success", free[0]["message"]
    recorded = json.loads(free[0]["info"])["progress"]
    assert recorded["interval"] == 0.05 and set(recorded) == {"interval", "time", "best cost", "iterations"}
    path = write_planner_arena(anytime_results, tmp_path / "arena.db")
    conn = _connect(path)
    assert [r[1] for r in conn.execute("PRAGMA table_info(progress)")] == ["runid", "time", "best_cost", "iterations"]
    query = (  # server.R's progPerf: runs_ext joined to progress by run id
        "SELECT plannerConfigs.name AS planner, experiments.name AS experiment, runs.id AS run, "
        "runs.time AS planning_time, progress.time, progress.best_cost, progress.iterations FROM plannerConfigs "
        "JOIN runs ON plannerConfigs.id = runs.plannerid JOIN experiments ON runs.experimentid = experiments.id "
        "JOIN progress ON runs.id = progress.runid ORDER BY runs.id, progress.time"
    )
    samples = conn.execute(query).fetchall()
    assert {s["planner"] for s in samples} == {"rrtstar"}  # RRT-Connect records no progress
    assert {s["experiment"] for s in samples} == {"free", "plate"}
    for experiment in ("free", "plate"):
        mine = [s for s in samples if s["experiment"] == experiment]
        times = [s["time"] for s in mine]
        costs = [s["best_cost"] for s in mine if s["best_cost"] is not None]
        iterations = [s["iterations"] for s in mine]
        assert 10 <= len(mine) <= 40  # every 0.05 s of a 1 s search, and one at its end
        assert all(0 <= a < b for a, b in zip(times, times[1:], strict=False))
        assert all(b <= a for a, b in zip(costs, costs[1:], strict=False))  # non-increasing
        assert all(math.isfinite(c) and c > 0 for c in costs)
        assert iterations == sorted(iterations) and iterations[-1] > 0
        if experiment == "free":
            assert costs and times[-1] <= mine[0]["planning_time"] + 0.05
            # once found, a solution stays: no empty best cost after the first
            first = next(k for k, s in enumerate(mine) if s["best_cost"] is not None)
            assert all(s["best_cost"] is not None for s in mine[first:])
    conn.close()


@pytest.mark.slow
def test_plannerarenas_progress_page_gets_the_samples(anytime_results, tmp_path):
    database = pytest.importorskip("plannerarena.database", reason="pip install plannerarena")
    data = database.load_database(write_planner_arena(anytime_results, tmp_path / "arena.db"))
    assert data["progress"].columns[2:] == ["best cost", "iterations"]  # its "Progress attribute" choices
    # what the progress page plots: progress joined to the experiment's runs of the chosen planners
    runs = data["runs"].filter(data["runs"]["experiment"] == "free")
    joined = data["progress"].join(runs.select(["id", "planner"]), left_on="runid", right_on="id")
    assert set(joined["planner"].cast(str).to_list()) == {"rrtstar"}
    assert joined["best cost"].drop_nulls().len() > 0


@pytest.mark.slow
def test_ompl_logs_carry_the_progress_to_ompls_reader(anytime_results, tmp_path):
    tools = pytest.importorskip("ompl.tools")
    logs = write_ompl_logs(anytime_results, tmp_path / "logs")
    tools.readBenchmarkLog(str(tmp_path / "from_logs.db"), [str(f) for f in logs], False)
    write_planner_arena(anytime_results, tmp_path / "arena.db")
    query = "SELECT runid, time, best_cost, iterations FROM progress ORDER BY runid, time"
    from_logs = _connect(tmp_path / "from_logs.db").execute(query).fetchall()
    direct = _connect(tmp_path / "arena.db").execute(query).fetchall()
    assert len(direct) > 20
    assert [tuple(r) for r in from_logs] == [tuple(r) for r in direct]


def test_malformed_progress_is_left_out_whole():
    def row(progress):
        return {"info": json.dumps({"progress": progress})}

    good = {"interval": 0.05, "time": [0.0, 0.05], "best cost": [None, 2.0], "iterations": [1, 9]}
    assert run_progress(row(good)) == {"time": [0.0, 0.05], "best cost": [None, 2.0], "iterations": [1, 9]}
    for bad in (
        {**good, "time": [0.05, 0.05]},  # not increasing
        {**good, "time": [0.0, float("nan")]},
        {**good, "best cost": [1.0]},  # length
        {**good, "best cost": ["x", 1.0]},
        {"time": "soon"},
        [1, 2],
    ):
        assert run_progress(row(bad)) is None
    assert run_progress({"info": "{not json"}) is None
    assert run_progress(row({**good, "drop table": [1, 2], "bad;name": [1, 2]}))["drop table"] == [1, 2]
    assert "bad;name" not in run_progress(row({**good, "bad;name": [1, 2]}))


def test_progress_is_recorded_by_anytime_planners_only_and_can_be_turned_off(free_problem):
    def plan(name, **settings):
        planner = REGISTRY.make(name, **settings)
        planner.setup(free_problem)
        return planner.plan(free_problem, time_limit=1.0, rng=np.random.default_rng(0)).info

    info = plan("ompl-rrtstar")  # stops at its first solution: a short series, ending with its cost
    assert info["progress"]["best cost"][-1] > 0 and info["progress"]["iterations"][-1] == info["iterations"]
    assert "progress" not in plan("ompl-rrtstar", progress_interval=0)
    assert "progress" not in plan("ompl-rrtconnect")  # no best cost to report
    for bad in (-0.05, float("nan"), "often"):
        with pytest.raises(InvalidSettingError, match="progress_interval"):
            REGISTRY.make("ompl-rrtstar", progress_interval=bad)


SETTINGS_SUITE = """
[suite]
name = "settings"
problems = ["mbm:table_pick/0001"]
seeds = [0]
time_limit = 2.0

[[planners]]
planner = "ompl-rrtconnect"
settings = { simplify = false }

[[planners]]
planner = "straight-line"
"""


@pytest.mark.slow
def test_every_planner_setting_is_kept_defaults_included(tmp_path):
    db_path = tmp_path / "r.db"
    run_benchmark(parse_suite(SETTINGS_SUITE, "settings.toml"), db_path, jobs=1)
    with ResultsDB(db_path, read_only=True) as db:
        rows = {r["planner"]: r for r in db.rows()}
        definition, _ = db.suite_settings("settings")
    ompl = rows["ompl-rrtconnect"]
    assert json.loads(ompl["planner_settings"]) == {"simplify": False}  # the settings given
    config = json.loads(ompl["planner_config"])  # every setting of the planner as built
    assert set(config) == {f.name for f in dataclasses.fields(OMPLConfig)}
    assert config["simplify"] is False and config["collision"] == "primitives" and config["progress_interval"] == 0.05
    assert config["params"] == {"range": 0.5}  # planbench's default of RRT-Connect's own parameter
    assert {p["label"]: p["config"] for p in definition["planners"]}["ompl-rrtconnect"] == config
    assert json.loads(ompl["info"])["ompl_parameters"] == {"intermediate_states": False, "range": 0.5}
    arena = write_planner_arena(list(rows.values()), tmp_path / "arena.db")
    settings = dict(_connect(arena).execute("SELECT name, settings FROM plannerConfigs").fetchall())
    expected = [
        "planner = ompl-rrtconnect;",
        "simplify = false;",
        "collision = primitives;",
        "resolution = 0.01;",
        "progress_interval = 0.05;",
        "params.range = 0.5;",
        "ompl.range = 0.5;",
        "ompl.intermediate_states = false;",
    ]
    assert all(item in settings["ompl-rrtconnect"] for item in expected), settings["ompl-rrtconnect"]
    assert settings["straight-line"].startswith("planner = straight-line;")
    # the same settings reach OMPL's reader through the logs (it keeps each line's newline)
    tools = pytest.importorskip("ompl.tools")
    logs = write_ompl_logs(list(rows.values()), tmp_path / "logs")
    tools.readBenchmarkLog(str(tmp_path / "from_logs.db"), [str(f) for f in logs], False)
    from_logs = _connect(tmp_path / "from_logs.db").execute("SELECT name, settings FROM plannerConfigs")
    assert {name: text.replace("\n", "") for name, text in from_logs} == settings


def test_planner_settings_of_an_older_file_are_the_settings_given():
    row = {"planner": "x", "planner_name": "ompl-rrtstar", "planner_settings": '{"params": {"range": 1.0}}'}
    assert planner_settings(row) == [("planner", "ompl-rrtstar"), ("params.range", "1.0")]
    row = {**row, "planner_config": '{"a": "two\\nlines", "b": [1, 2], "c": {}}', "info": "{}"}
    assert planner_settings(row) == [("planner", "ompl-rrtstar"), ("a", "two lines"), ("b", "[1, 2]"), ("c", "{}")]


def _draw(plot):
    buffer = io.BytesIO()
    plot.save(buffer, format="png", verbose=False, width=4, height=3, dpi=50)
    return len(buffer.getvalue())


def test_plannerarenas_performance_views_draw_a_family(rows, tmp_path):
    performance = pytest.importorskip("plannerarena.performance", reason="pip install plannerarena")
    database = pytest.importorskip("plannerarena.database")
    data = database.load_database(write_planner_arena(rows, tmp_path / "arena.db"))
    box = data["runs"].filter(data["runs"]["experiment"] == "box")
    status = data["enums"].filter(data["enums"]["name"] == "status")
    assert _draw(performance.boxplot(box, "time", [], "o", False)) > 0  # every run of the family
    assert _draw(performance.boxplot(box, "time", "problem", "o", False)) > 0  # "all (separate)": one per problem
    assert _draw(performance.enums_plot(box, status, [])) > 0


def test_plannerarenas_progress_view_draws_best_cost_over_time(rows, tmp_path):
    p9 = pytest.importorskip("plotnine")
    database = pytest.importorskip("plannerarena.database", reason="pip install plannerarena")
    # a family's worth of anytime runs (the view smooths over all runs: a handful of runs of ~20
    # samples is too few for its loess), their samples as an OMPL planner records them
    rng = np.random.default_rng(0)
    anytime = []
    for k, r in enumerate(x for x in rows if x["planner"] == "noisy"):
        t = np.sort(rng.uniform(0.0, 1.0, 21))
        cost = np.minimum.accumulate(2.0 + 1.0 / (0.2 + t) + rng.normal(0.0, 0.1, t.size))
        progress = {"interval": 0.05, "time": t.tolist(), "best cost": [None, *cost[1:].tolist()]}
        anytime.append({**r, "planner": "anytime", "seed": 100 + k, "info": json.dumps({"progress": progress})})
    data = database.load_database(write_planner_arena(rows + anytime, tmp_path / "arena.db"))
    runs = data["runs"].filter(data["runs"]["experiment"] == "box")
    df = data["progress"].join(runs.select(["id", "planner"]), left_on="runid", right_on="id")
    assert df.height == 4 * 21 and set(df["planner"].cast(str).to_list()) == {"anytime"}
    # the plot of plannerarena.progress's plot_object, for the attribute "best cost"
    plot = (
        p9.ggplot(df, p9.aes(x="time", y="best cost", color="planner", fill="planner"))
        + p9.xlab("time (s)")
        + p9.geom_smooth(na_rm=True, method="loess", span=0.1, se=False)
    )
    assert _draw(plot) > 0
