"""Bad input to the command line and to the results database: each is a named error (exit code 2,
no traceback) naming the thing that is wrong, and nothing the user gave is changed by it.

Runs are made in-process with ``failure_record`` or the worker's ``run_one`` wherever the test
is about the file rather than the benchmark, so that few tests pay for worker processes."""

import hashlib
import json
import logging
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import planbench
from planbench.bench.db import ResultsDB
from planbench.bench.records import failure_record
from planbench.bench.suite import expand_problems
from planbench.cli.main import main
from planbench.errors import (
    DuplicateProblemError,
    ProblemFileError,
    ResultsFileError,
    ResultsLockedError,
    UnstorableValueError,
)
from planbench.problem import Problem

TESTS = Path(__file__).parent
PLANBENCH = [sys.executable, "-m", "planbench.cli.main"]


def _fields(problem: str, seed: int, suite: str = "s") -> dict:
    return dict(suite=suite, problem=problem, family="box", planner="p", seed=seed, planner_name="p", settings={})


def _record(n_waypoints: int = 40) -> dict:
    rec = failure_record("timeout", "killed")
    rec["path"] = np.random.default_rng(0).normal(size=(n_waypoints, 7))  # pages of blobs, like real runs
    return rec


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """A small planbench results file: 30 runs with paths (about 20 pages)."""
    path = tmp_path_factory.mktemp("results") / "r.db"
    with ResultsDB(path) as db:
        db.put_suite("s", {"planners": []}, "{}")
        for i in range(30):
            db.add_run(_fields(f"mbm:box/{i + 1:04d}", 0), _record())
    return path


def _copy(src: Path, dst: Path) -> Path:
    shutil.copy(src, dst)
    return dst


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _run(args: list[str], **kw) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([*PLANBENCH, *args], capture_output=True, text=True, env=env, timeout=120, **kw)


def _refused(args: list[str], capsys, *needles: str) -> str:
    """main(args) exits 2 with a message holding every needle; returns stderr."""
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("planbench: error: ") and "Traceback" not in err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


# -- time limits and seeds ---------------------------------------------------------------------


@pytest.mark.parametrize("value", ["-1", "nan", "inf", "0"])
def test_plan_refuses_a_time_limit_that_is_not_a_positive_finite_number(value, capsys):
    _refused(["plan", "--problem", "mbm:box/0001", "--time-limit", value], capsys, "--time-limit", "finite")


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_bench_refuses_a_bad_time_limit_before_touching_the_results_file(value, tmp_path, capsys):
    out = tmp_path / "r.db"
    _refused(["bench", "--time-limit", value, "--out", str(out)], capsys, "--time-limit")
    assert not out.exists()


@pytest.mark.parametrize(
    "seeds, needle",
    [
        ("99999999999999999999", "seed count"),
        ("0-99999999999999999999", "0 <= seed < 2**63"),
        ("0,9223372036854775808", "0 <= seed < 2**63"),
        ("5-2", "lo <= hi"),
    ],
)
def test_bench_refuses_seeds_numpy_or_sqlite_cannot_take(seeds, needle, tmp_path, capsys):
    _refused(["bench", "--seeds", seeds, "--out", str(tmp_path / "r.db")], capsys, "--seeds", needle)


@pytest.mark.parametrize("seed", ["99999999999999999999", "-1"])
def test_plan_refuses_a_seed_out_of_range(seed, capsys):
    _refused(["plan", "--problem", "mbm:box/0001", "--seed", seed], capsys, "--seed", "2**63")


def test_a_suite_file_with_a_huge_seed_names_the_file(tmp_path, capsys):
    suite = tmp_path / "big.toml"
    suite.write_text(
        '[suite]\nname = "b"\nproblems = ["mbm:box/0001"]\nseeds = [9223372036854775808]\n'
        '[[planners]]\nplanner = "straight-line"\n'
    )
    _refused(["bench", "--suite", str(suite), "--out", str(tmp_path / "r.db")], capsys, str(suite), "2**63")


def test_other_bad_bench_options_are_named(tmp_path, capsys):
    out = str(tmp_path / "r.db")
    _refused(["bench", "--jobs", "-1", "--out", out], capsys, "--jobs")
    _refused(["bench", "--planners", ",", "--out", out], capsys, "--planners")
    _refused(["bench", "--resume", "--overwrite", "--out", out], capsys, "--resume", "--overwrite")
    _refused(["bench", "--memory-limit", "-5", "--out", out], capsys, "--memory-limit")
    _refused(["bench", "--memory-limit", "lots", "--out", out], capsys, "--memory-limit")
    assert not (tmp_path / "r.db").exists()  # options are checked before the results file is opened
    _refused(["bench", "--problems", "mbm:box/0500", "--out", out], capsys, "mbm:box/0500")
    empty = tmp_path / "empty"
    empty.mkdir()
    _refused(["bench", "--problems", str(empty), "--out", out], capsys, "no problem .json")
    _refused(["bench", "--problems", "mbm:box/0001", "--out", str(empty)], capsys, str(empty), "is a folder")
    _refused(["report", str(empty)], capsys, str(empty), "is a folder")


def test_unreadable_suite_files_are_named(tmp_path, capsys):
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    _refused(["bench", "--suite", str(binary)], capsys, str(binary), "cannot read")
    broken = tmp_path / "broken.toml"
    broken.write_text("[suite\nname=")
    _refused(["bench", "--suite", str(broken)], capsys, str(broken), "not valid TOML")
    _refused(["bench", "--suite", str(tmp_path / "missing.toml")], capsys, "missing.toml", "no such file")


def test_an_unknown_export_format_is_an_argparse_error(results, capsys):
    with pytest.raises(SystemExit) as info:
        main(["export", str(results), "--format", "yaml"])
    assert info.value.code == 2
    assert "invalid choice: 'yaml'" in capsys.readouterr().err


# -- problem files -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def problem_dict() -> dict:
    d = planbench.load_problems("mbm:box/0001")[0].to_dict()
    d["id"] = "mine"
    return d


@pytest.mark.parametrize(
    "change, field",
    [
        ({"robot_overrides": [1, 2]}, "'robot_overrides'"),
        ({"robot_overrides": {"fixed_joints": [1]}}, "'robot_overrides.fixed_joints'"),
        ({"robot_overrides": {"fixed_joints": {"panda_finger_joint1": "x"}}}, "'robot_overrides.fixed_joints'"),
        ({"robot_overrides": {"position_limits": {"panda_joint1": [0]}}}, "position_limits.panda_joint1"),
        ({"robot_overrides": {"nope": 1}}, "nope"),
        ({"robot": 5}, "'robot'"),
        ({"robot": "r2d2"}, "robot 'r2d2'"),
        ({"id": {"a": 1}}, "'id'"),
        ({"start": "abc"}, "'start'"),
        ({"start": [[0.1, 0.2]]}, "'start'"),
        ({"start": [0.1, True]}, "'start'"),
        ({"goal": [1]}, "'goal'"),
        ({"goal": {"q": "x"}}, "'goal.q'"),
        ({"goal": {"pose": [1, 2]}}, "'goal.pose'"),
        ({"goal": {"pose": {"position": [1], "orientation_xyzw": [0, 0, 0, 1]}}}, "'goal.pose.position'"),
        ({"goal": {"pose": {"position": [0.3, 0, 0.5]}}}, "orientation_xyzw"),
        ({"goal": {"pose": {"position": [0.3, 0, 0.5], "orientation_xyzw": [0, 0, 0, 1], "frame": 3}}}, "frame"),
        ({"tolerances": [1]}, "'tolerances'"),
        ({"tolerances": {"position": "a"}}, "'tolerances.position'"),
        ({"tolerances": {"speed": 1}}, "'speed'"),
        ({"metadata": [1]}, "'metadata'"),
        ({"scene": 5}, "'scene'"),
    ],
)
def test_a_wrong_type_in_a_problem_file_names_the_file_and_the_field(problem_dict, change, field, tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**problem_dict, **change}))
    with pytest.raises(ProblemFileError) as info:
        Problem.load(path)
    assert str(path) in str(info.value) and field in str(info.value)


def test_robot_overrides_list_through_the_cli(problem_dict, tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**problem_dict, "robot_overrides": [1, 2]}))
    proc = _run(["plan", "--problem", str(path)])
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"{path}: field 'robot_overrides' must be a JSON object, got [1, 2]" in proc.stderr


def test_a_good_problem_file_still_loads(problem_dict, tmp_path):
    path = tmp_path / "good.json"
    path.write_text(json.dumps(problem_dict))
    assert Problem.load(path).id == "mine"


# -- duplicate problem ids -----------------------------------------------------------------------


def _two_files_one_id(problem_dict, folder: Path) -> tuple[Path, Path]:
    folder.mkdir()
    a, b = folder / "a.json", folder / "b.json"
    a.write_text(json.dumps({**problem_dict, "id": "same"}))
    b.write_text(json.dumps({**problem_dict, "id": "same", "start": problem_dict["goal"]["q"]}))
    return a, b


def test_two_files_with_one_id_name_both_files(problem_dict, tmp_path, capsys):
    a, b = _two_files_one_id(problem_dict, tmp_path / "probs")
    for selectors in ([str(a), str(b)], [str(tmp_path / "probs")]):
        with pytest.raises(DuplicateProblemError) as info:
            expand_problems(selectors)
        assert str(a) in str(info.value) and str(b) in str(info.value) and "'same'" in str(info.value)
    with pytest.raises(DuplicateProblemError):
        planbench.load_problems(tmp_path / "probs")
    _refused(["plan", "--problem", str(tmp_path / "probs")], capsys, str(a), str(b))
    out = tmp_path / "r.db"
    _refused(["bench", "--problems", str(a), str(b), "--out", str(out)], capsys, str(a), str(b))
    # the same file twice, or overlapping MotionBenchMaker selectors, is one problem, not a clash
    assert len(expand_problems([str(a), str(tmp_path / "probs" / "a.json")])) == 1
    assert len(expand_problems(["mbm:box/0001-0002", "mbm:box/0002"])) == 2


def test_a_file_with_a_builtin_problem_id_names_both(problem_dict, tmp_path):
    path = tmp_path / "fake.json"
    path.write_text(json.dumps({**problem_dict, "id": "mbm:box/0001"}))
    with pytest.raises(DuplicateProblemError, match="built-in problem mbm:box/0001") as info:
        expand_problems(["mbm:box/0001", str(path)])
    assert str(path) in str(info.value)


# -- results files: read-only, not planbench's, damaged ---------------------------------------------


def test_report_and_export_leave_the_results_file_byte_identical(results, tmp_path, capsys):
    db = _copy(results, tmp_path / "r.db")
    before = _sha(db)
    assert main(["report", str(db), "--csv", str(tmp_path / "t.csv")]) == 0
    assert main(["export", str(db), "--format", "csv", "--out", str(tmp_path / "runs.csv")]) == 0
    assert _sha(db) == before
    with ResultsDB(db, read_only=True) as ro:
        assert ro.count() == 30
        with pytest.raises(ResultsFileError, match="read-only"):
            ro.add_run(_fields("mbm:box/0099", 0), _record())
    assert _sha(db) == before


def test_read_only_reads_an_older_file_without_migrating_it(results, tmp_path):
    db = _copy(results, tmp_path / "old.db")
    with ResultsDB(db) as w, w.conn:  # a file from before validation_checks had its column
        w.conn.execute("UPDATE runs SET collision_checks = 7, info = '{\"collision_checks\": 3}'")
        w.conn.execute("ALTER TABLE runs DROP COLUMN validation_checks")
    before = _sha(db)
    with ResultsDB(db, read_only=True) as ro:
        rows = ro.rows()
    assert _sha(db) == before
    assert {(r["collision_checks"], r["validation_checks"]) for r in rows} == {(3, 7)}
    with ResultsDB(db) as w:  # the writer's migration gives the same rows
        assert [(r["collision_checks"], r["validation_checks"]) for r in w.rows()] == [(3, 7)] * 30


def test_a_sqlite_file_that_is_not_planbench_is_refused_and_left_alone(tmp_path, capsys):
    other = tmp_path / "other.db"
    conn = sqlite3.connect(other)
    conn.execute("CREATE TABLE t (x)")
    conn.commit()
    conn.close()
    before = _sha(other)
    _refused(["report", str(other)], capsys, str(other), "not a planbench results file")
    _refused(["export", str(other), "--format", "csv", "--out", str(tmp_path / "x.csv")], capsys, str(other))
    _refused(["bench", "--out", str(other), "--problems", "mbm:box/0001"], capsys, "not a planbench results file")
    assert _sha(other) == before
    conn = sqlite3.connect(other)
    assert [r[0] for r in conn.execute("SELECT name FROM sqlite_master")] == ["t"]
    conn.close()
    text = tmp_path / "notes.db"
    text.write_text("not a database at all " * 100)
    _refused(["report", str(text)], capsys, str(text), "not a SQLite file")
    _refused(["report", str(tmp_path / "missing.db")], capsys, "missing.db", "no such results database")


def _damage(src: Path, dst: Path) -> Path:
    """A copy of ``src`` with garbage written over bytes in its middle."""
    shutil.copy(src, dst)
    size = dst.stat().st_size
    with dst.open("r+b") as f:
        f.seek(size // 2)
        f.write(bytes(range(256)) * 16)
    return dst


def test_a_damaged_results_file_is_named_by_report_export_and_resume(results, tmp_path, capsys):
    db = _damage(results, tmp_path / "damaged.db")
    _refused(["report", str(db)], capsys, str(db), "damaged", ".recover")
    _refused(["export", str(db), "--format", "csv", "--out", str(tmp_path / "x.csv")], capsys, "damaged")
    args = ["bench", "--resume", "--out", str(db), "--problems", "mbm:box/0001", "--planners", "straight-line"]
    _refused(args, capsys, str(db), "damaged")
    proc = _run(["report", str(db)])
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "damaged" in proc.stderr


def test_damage_met_at_query_time_is_named(results, tmp_path, monkeypatch):
    db = _copy(results, tmp_path / "r.db")
    with ResultsDB(db, read_only=True) as ro:
        ro.conn.close()
        ro.conn = _Failing()  # what a bad page does to a query after the open succeeded
        with pytest.raises(ResultsFileError, match="damaged"):
            ro.rows()


class _Failing:
    def execute(self, *args):
        raise sqlite3.DatabaseError("database disk image is malformed")

    def close(self):
        pass


def test_outputs_may_not_replace_the_results_file(results, tmp_path, capsys):
    db = _copy(results, tmp_path / "r.db")
    before = _sha(db)
    _refused(["export", str(db), "--format", "planner-arena", "--out", str(db)], capsys, "itself")
    _refused(["report", str(db), "--csv", str(db)], capsys, "itself")
    other = _copy(results, tmp_path / "other.db")
    _refused(["export", str(db), "--format", "planner-arena", "--out", str(other)], capsys, "is a SQLite database")
    assert _sha(other) == _sha(results)
    _refused(["report", str(db), "--markdown", str(tmp_path / "no" / "t.md")], capsys, "cannot write")
    assert _sha(db) == before


# -- writing runs: duplicate keys, unstorable values ------------------------------------------------


def test_a_duplicate_run_key_keeps_the_stored_row(tmp_path, caplog):
    with ResultsDB(tmp_path / "r.db") as db:
        assert db.add_run(_fields("mbm:box/0001", 0), _record()) is True
        with caplog.at_level(logging.WARNING, logger="planbench.bench.db"):
            assert db.add_run(_fields("mbm:box/0001", 0), failure_record("crash", "second")) is False
        assert "already stored" in caplog.text
        (row,) = db.rows()
        assert row["status"] == "timeout"


@pytest.mark.parametrize(
    "field, value, column",
    [
        ("seed", 2**64, "seed"),
        ("family", object(), "family"),
        ("planner_settings", {"x": object()}, "planner_settings"),
        ("family", "bad \udcff text", "family"),
    ],
)
def test_values_sqlite_cannot_store_are_named_and_nothing_is_written(field, value, column, tmp_path):
    with ResultsDB(tmp_path / "r.db") as db:
        with pytest.raises(UnstorableValueError) as info:
            db.add_run({**_fields("mbm:box/0001", 0), field: value}, _record())
        assert info.value.column == column and repr(column) in str(info.value)
        assert db.count() == 0


def test_big_numbers_inside_json_columns_are_kept_as_text(tmp_path):
    rec = _record()
    rec["info"] = {"collision_checks": 2**64}
    with ResultsDB(tmp_path / "r.db") as db:
        assert db.add_run(_fields("mbm:box/0001", 0), rec)
        assert json.loads(db.rows()[0]["info"]) == {"collision_checks": 2**64}


# -- one writer at a time ----------------------------------------------------------------------------

HOLD = """
import sys, time
from planbench.bench.db import ResultsDB
with ResultsDB(sys.argv[1]) as db, db.lock_for_writing():
    print("locked", flush=True)
    time.sleep(120)
"""


def _holder(db: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(db)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
    return proc


def test_a_second_writer_is_refused_with_the_holder_and_the_lock_dies_with_it(tmp_path, capsys):
    db = tmp_path / "r.db"
    holder = _holder(db)
    try:
        with ResultsDB(db) as second:
            with pytest.raises(ResultsLockedError, match=f"pid {holder.pid} on host "):
                with second.lock_for_writing():
                    pass
        args = ["bench", "--out", str(db), "--problems", "mbm:box/0001", "--planners", "straight-line"]
        err = _refused(args, capsys, f"pid {holder.pid}", "another benchmark is writing")
        assert "started 20" in err  # its start time
    finally:
        os.kill(holder.pid, signal.SIGKILL)  # kill -9: the kernel drops the flock
        holder.wait(10)
    with ResultsDB(db) as db2, db2.lock_for_writing():
        holder_path = db2.holder_path
        assert json.loads(holder_path.read_text())["pid"] == os.getpid()
    assert not holder_path.exists()


NOISY_SUITE = """
[suite]
name = "slow"
problems = ["mbm:table_pick/0001"]
seeds = [0, 1, 2]
time_limit = 5.0

[[planners]]
label = "noisy"
planner = "bench_planners:NoisyPlanner"
settings = { delay = 0.7 }
"""


@pytest.mark.slow
def test_two_bench_processes_on_one_file(tmp_path):
    suite = tmp_path / "slow.toml"
    suite.write_text(NOISY_SUITE)
    db = tmp_path / "r.db"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    args = [*PLANBENCH, "bench", "--suite", str(suite), "--out", str(db), "--jobs", "1", "--no-progress"]
    first = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not list(tmp_path.glob(".planbench-writer-*")):
            time.sleep(0.05)
        second = subprocess.run([*args, "--resume"], env=env, capture_output=True, text=True, timeout=120)
        assert first.poll() is None, "the first benchmark ended before the second started"
        assert second.returncode == 2 and "Traceback" not in second.stderr
        assert f"pid {first.pid} on host" in second.stderr and "another benchmark is writing" in second.stderr
        assert first.wait(120) == 0, first.stderr.read() if first.stderr else ""
    finally:
        if first.poll() is None:
            first.kill()
    assert not list(tmp_path.glob(".planbench-writer-*"))
    with ResultsDB(db, read_only=True) as ro:
        assert ro.count() == 3
    third = subprocess.run([*args, "--resume"], env=env, capture_output=True, text=True, timeout=120)
    assert third.returncode == 0 and "0 to run" in third.stdout


def test_a_bench_refused_before_any_run_leaves_no_results_file(tmp_path, capsys):
    out = tmp_path / "new.db"
    _refused(["bench", "--suite", "smoke", "--problems", "mbm:box/9990-9999", "--out", str(out)], capsys, "9990")
    assert not list(tmp_path.iterdir())  # nor its journal nor the writer's description
