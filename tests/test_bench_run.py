"""The benchmark runner end to end: isolation of misbehaving planners, determinism across --jobs,
resume after kill -9, and the CLI. Test planners live in tests/bench_planners.py; spawned workers
import them by "module:Attr" (they inherit the parent's sys.path)."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import planbench.cli.main as cli
from planbench.bench import benchmark
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.suite import parse_suite
from planbench.errors import PlanbenchError

TESTS = Path(__file__).parent
SOLVABLE = "mbm:table_pick/0001"  # the straight line is free here


def suite(planners: str, problems=(SOLVABLE,), seeds=(0,), name="t", time_limit=1.0) -> str:
    head = f"""
[suite]
name = "{name}"
problems = {list(problems)!r}
seeds = {list(seeds)!r}
time_limit = {time_limit}
grace = 0.5
"""
    return head + planners


MISBEHAVING = suite(
    """
[[planners]]
planner = "straight-line"
[[planners]]
label = "raises"
planner = "bench_planners:RaisingPlanner"
[[planners]]
label = "sleeps"
planner = "bench_planners:SleepingPlanner"
[[planners]]
label = "kills-itself"
planner = "bench_planners:SuicidePlanner"
[[planners]]
label = "exits"
planner = "bench_planners:ExitPlanner"
""",
    problems=(SOLVABLE, "mbm:box/0001"),
)


@pytest.mark.slow
def test_raise_timeout_and_crash_are_recorded_and_the_rest_completes(tmp_path):
    db_path = tmp_path / "r.db"
    outcome = run_benchmark(parse_suite(MISBEHAVING, "misbehaving.toml"), db_path, jobs=2)
    assert (outcome.total, outcome.ran, outcome.skipped) == (10, 10, 0)
    with ResultsDB(db_path) as db:
        rows = {(r["planner"], r["problem"]): r for r in db.rows()}
    assert len(rows) == 10
    sl = rows["straight-line", SOLVABLE]
    assert sl["status"] == "success" and sl["success"] and sl["planning_time"] > 0
    assert rows["straight-line", "mbm:box/0001"]["status"] == "collision"
    for problem in (SOLVABLE, "mbm:box/0001"):
        err = rows["raises", problem]
        assert err["status"] == "error" and not err["success"]
        assert "RuntimeError: bench-raising planner fails on purpose" in err["message"]
        assert "Traceback" in err["traceback"] and "bench_planners.py" in err["traceback"]
        slept = rows["sleeps", problem]
        assert slept["status"] == "timeout" and "past the time limit of 1.0 s" in slept["message"]
        assert "bench_planners.py" in slept["traceback"]  # where it hung, from faulthandler
        assert slept["planning_time"] >= 1.5
        killed = rows["kills-itself", problem]
        assert killed["status"] == "crash" and "SIGKILL" in killed["message"]
        exited = rows["exits", problem]
        assert exited["status"] == "crash" and "exit code 3" in exited["message"]
        assert "bench-exit planner says goodbye" in exited["traceback"]
    versions = rows["straight-line", SOLVABLE]["versions"]
    assert '"planbench"' in versions and '"numpy"' in versions and rows["straight-line", SOLVABLE]["host"]


NOISY = suite(
    """
[[planners]]
planner = "straight-line"
[[planners]]
label = "noisy"
planner = "bench_planners:NoisyPlanner"
settings = { scale = 0.02 }
""",
    problems=(SOLVABLE, "mbm:box/0001"),
    seeds=(0, 1, 2),
)


@pytest.mark.slow
def test_same_paths_and_statuses_whatever_the_number_of_jobs(tmp_path):
    s = parse_suite(NOISY, "noisy.toml")
    run_benchmark(s, tmp_path / "j1.db", jobs=1)
    run_benchmark(s, tmp_path / "j2.db", jobs=2)
    with ResultsDB(tmp_path / "j1.db") as a, ResultsDB(tmp_path / "j2.db") as b:
        ra, rb = a.rows(with_arrays=True), b.rows(with_arrays=True)
    assert len(ra) == len(rb) == 12
    for x, y in zip(ra, rb, strict=True):
        assert (x["problem"], x["planner"], x["seed"], x["status"], x["success"]) == (
            y["problem"],
            y["planner"],
            y["seed"],
            y["status"],
            y["success"],
        )
        if x["path"] is None:
            assert y["path"] is None and x["planner"] == "straight-line" and x["status"] == "collision"
        else:
            assert np.array_equal(x["path"], y["path"])
    noisy = [r["path"] for r in ra if r["planner"] == "noisy" and r["problem"] == SOLVABLE]
    assert not np.array_equal(noisy[0], noisy[1])  # the seed reaches the planner


SLOW = suite(
    """
[[planners]]
label = "slow"
planner = "bench_planners:NoisyPlanner"
settings = { delay = 0.15 }
""",
    problems=("mbm:box/0001-0004", "mbm:cage/0001-0004"),
    seeds=(0, 1),
    name="slow",
)


@pytest.mark.slow
def test_kill_minus_nine_then_resume_runs_only_what_is_missing(tmp_path):
    suite_file = tmp_path / "slow.toml"
    suite_file.write_text(SLOW)
    db_path = tmp_path / "r.db"
    code = f"from planbench.bench import benchmark; benchmark({str(suite_file)!r}, out={str(db_path)!r}, jobs=2)"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        n = 0
        while time.monotonic() < deadline and proc.poll() is None:
            if db_path.exists():
                with ResultsDB(db_path) as db:
                    n = db.count()
                if n >= 3:
                    break
            time.sleep(0.05)
        assert proc.poll() is None, "the benchmark finished before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    with ResultsDB(db_path) as db:
        before = db.count()
    assert 3 <= before < 16
    s = parse_suite(SLOW, str(suite_file))
    with pytest.raises(PlanbenchError, match="--resume"):
        run_benchmark(s, db_path, jobs=2)
    outcome = run_benchmark(s, db_path, jobs=2, resume=True)
    assert (outcome.skipped, outcome.ran) == (before, 16 - before)
    with ResultsDB(db_path) as db:
        keys = [(r["problem"], r["planner"], r["seed"]) for r in db.rows()]
    assert len(keys) == len(set(keys)) == 16
    again = run_benchmark(s, db_path, jobs=2, resume=True)
    assert again.ran == 0


@pytest.mark.slow
def test_resume_refuses_changed_settings(tmp_path):
    s = parse_suite(suite('[[planners]]\nplanner = "straight-line"\n', problems=("mbm:box/0001",)), "a.toml")
    run_benchmark(s, tmp_path / "r.db", jobs=1)
    with pytest.raises(PlanbenchError, match="resuming would mix them"):
        run_benchmark(s.with_changes(time_limit=2.0), tmp_path / "r.db", jobs=1, resume=True)


def _main(argv):
    return cli.main(argv)


@pytest.mark.slow
def test_cli_bench_report_and_library_table(tmp_path, capsys, monkeypatch):
    suite_file = tmp_path / "s.toml"
    suite_file.write_text(NOISY)
    db = tmp_path / "r.db"
    assert (
        _main(["bench", "--suite", str(suite_file), "--out", str(db), "--jobs", "2", "--seeds", "1", "--no-progress"])
        == 0
    )
    out = capsys.readouterr().out
    assert "4 runs" in out and "straight-line" in out and "noisy" in out
    # the same command again: every run is stored, so it only reports them
    assert _main(["bench", "--suite", str(suite_file), "--out", str(db), "--seeds", "1", "--no-progress"]) == 0
    assert "0 to run" in capsys.readouterr().out
    # more runs asked for than stored: an interrupted or extended benchmark needs an explicit --resume
    assert _main(["bench", "--suite", str(suite_file), "--out", str(db), "--seeds", "0,1"]) == 2
    assert "--resume" in capsys.readouterr().err
    md, csv_file, html, plots = tmp_path / "t.md", tmp_path / "t.csv", tmp_path / "r.html", tmp_path / "plots"
    args = ["report", str(db), "--by", "family", "--markdown", str(md), "--csv", str(csv_file)]
    assert _main([*args, "--plots", str(plots), "--html", str(html)]) == 0
    assert md.read_text().startswith("| planner | family | solved |")
    assert csv_file.read_text().count("\n") == 5  # header + 2 planners x 2 families
    # a subset of the problems (e.g. a held-out set): only their runs are summarized
    assert _main([*args, "--problems", "mbm:box/0001-0005"]) == 0
    subset = list(csv.DictReader(csv_file.read_text().splitlines()))
    assert [(r["family"], r["runs"]) for r in subset] == [("box", "1"), ("box", "1")]  # 2 planners, seed 1
    assert _main(["report", str(db), "--problems", "mbm:cage/0001"]) == 1
    assert "holds no runs of problems mbm:cage/0001" in " ".join(capsys.readouterr().out.split())
    assert _main([*args]) == 0
    pngs = sorted(p.name for p in plots.glob("*.png"))
    assert {"time_to_success.png", "success_by_family.png", "ecdf_planning_time.png", "box_min_clearance.png"} <= set(
        pngs
    )
    assert all((plots / p).read_bytes().startswith(b"\x89PNG") for p in pngs)
    page = html.read_text()
    assert page.count("data:image/png;base64,") == len(pngs) and "<table>" in page and "noisy" in page
    table = benchmark(str(suite_file), out=db, jobs=1, resume=True, seeds="1")
    assert [row["planner"] for row in table] == ["noisy", "straight-line"]
    assert table[1]["solved"] == 1 and table[1]["runs"] == 2


def test_planner_and_validation_check_counts_have_their_own_columns_also_in_older_files(tmp_path):
    # the straight line counts its configurations, the harness its distance queries: two different counts
    planners = '[[planners]]\nplanner = "straight-line"\nsettings = { check_resolution = 0.005 }\n'
    s = parse_suite(suite(planners), "sl.toml")
    run_benchmark(s, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        (row,) = db.rows()
    assert row["success"] and row["collision_checks"] > 0 and row["validation_checks"] > 0
    assert row["collision_checks"] != row["validation_checks"]
    assert row["collision_checks"] == json.loads(row["info"])["collision_checks"]
    # a file from before validation_checks existed: its collision_checks column held the harness's count
    with ResultsDB(tmp_path / "r.db") as db, db.conn:
        db.conn.execute("UPDATE runs SET collision_checks = validation_checks")
        db.conn.execute("ALTER TABLE runs DROP COLUMN validation_checks")
    with ResultsDB(tmp_path / "r.db") as db:
        (old,) = db.rows()
    assert (old["collision_checks"], old["validation_checks"]) == (row["collision_checks"], row["validation_checks"])


@pytest.mark.slow
def test_no_setup_time_holds_numba_compilation(tmp_path, monkeypatch):
    """With an empty numba cache, the first run of a worker would compile the loop's step and the
    field sampler in its timed setup (several seconds); the worker compiles them untimed first."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-cache"))  # cold: nothing compiled yet
    s = parse_suite(
        suite('[[planners]]\nplanner = "matrix-field"\n', problems=("mbm:box/0001", "mbm:box/0002"), time_limit=5.0),
        "cold.toml",
    )
    run_benchmark(s, tmp_path / "cold.db", jobs=1)
    with ResultsDB(tmp_path / "cold.db") as db:
        rows = db.rows()
    assert len(rows) == 2 and all(r["status"] == "success" for r in rows)
    assert (tmp_path / "numba-cache").is_dir()  # it did compile, into the cache the test gave it
    assert max(r["setup_time"] for r in rows) < 1.5  # a compile is 5-8 s; a field and one step, ~0.1 s
