"""A results file cannot be hit twice: one writer per file whatever name reaches it, no link as a
results path, no output written over a results file, no spreadsheet formula in a CSV export."""

import csv
import fcntl
import hashlib
import io
import math
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from planbench.bench.db import ResultsDB
from planbench.bench.export import write_runs_csv
from planbench.bench.records import failure_record
from planbench.bench.report import to_csv
from planbench.cli.main import main
from planbench.errors import OutputFileError, ResultsFileError, ResultsLockedError
from planbench.files.outputs import check_output, csv_cell

TESTS = Path(__file__).parent
PLANBENCH = [sys.executable, "-m", "planbench.cli.main"]
BENCH = ["bench", "--problems", "mbm:box/0001", "--planners", "straight-line", "--no-progress"]

HOLD = """
import sys, time
from planbench.bench.db import ResultsDB
with ResultsDB(sys.argv[1]) as db, db.lock_for_writing():
    print("locked", flush=True)
    time.sleep(120)
"""

TRY_FLOCK = """
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDONLY)
try:
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    print("free")
except BlockingIOError:
    print("held")
"""


def _fields(seed: int, planner: str = "p", family: str = "box") -> dict:
    return dict(suite="s", problem="mbm:box/0001", family=family, planner=planner, seed=seed, planner_name="p")


def _results(path: Path, n: int = 3) -> Path:
    with ResultsDB(path) as db:
        db.put_suite("s", {"planners": []}, "{}")
        for seed in range(n):
            db.add_run(_fields(seed), failure_record("timeout", "killed"))
    return path


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([*PLANBENCH, *args], capture_output=True, text=True, env=env, timeout=120)


def _refused(done: subprocess.CompletedProcess, *needles: str) -> None:
    """Exit code 2, a named error holding every needle, no traceback."""
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert done.stderr.startswith("planbench: error: ") and "Traceback" not in done.stderr
    for needle in needles:
        assert needle in done.stderr, (needle, done.stderr)


@pytest.fixture
def holder(tmp_path):
    """A process holding the writer's lock of ``tmp_path/r.db`` (killed -9 at the end)."""
    db = _results(tmp_path / "r.db")
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(db)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
    yield proc
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)


# -- one writer per file, whatever its name ------------------------------------------------------------


def test_a_bench_through_a_hard_link_is_refused_while_the_first_runs(holder, tmp_path):
    db, link = tmp_path / "r.db", tmp_path / "link.db"
    before = _sha(db)
    os.link(db, link)
    _refused(_cli(*BENCH, "--out", str(link)), "link.db", "2 hard links", "copy the file")
    _refused(_cli(*BENCH, "--out", str(db)), "r.db", "2 hard links")  # the real name too: which journal is it?
    assert holder.poll() is None  # the first is still running
    assert _sha(db) == before
    with ResultsDB(db, read_only=True) as ro:
        assert ro.count() == 3


def test_the_lock_is_on_the_inode_not_the_name(holder, tmp_path):
    """Names that are not links (a renamed file, a folder reached through a symbolic link) reach
    the same file, nlink 1: the lock itself refuses them, and names the holder."""
    moved = tmp_path / "moved.db"
    os.rename(tmp_path / "r.db", moved)
    with ResultsDB(moved) as second:
        with pytest.raises(ResultsLockedError, match=f"pid {holder.pid} on host "):
            with second.lock_for_writing():
                pass
    alias = tmp_path.parent / f"{tmp_path.name}-alias"
    alias.symlink_to(tmp_path, target_is_directory=True)
    _refused(_cli(*BENCH, "--out", str(alias / "moved.db")), f"pid {holder.pid}", "another benchmark is writing")
    assert holder.poll() is None


def test_a_hard_link_made_after_opening_is_refused_at_the_lock(tmp_path):
    db = _results(tmp_path / "r.db")
    with ResultsDB(db) as w:
        os.link(db, tmp_path / "late.db")
        with pytest.raises(ResultsFileError, match="2 hard links"):
            with w.lock_for_writing():
                pass


def test_symbolic_links_are_refused_as_results_paths(tmp_path):
    db = _results(tmp_path / "r.db")
    (tmp_path / "sym.db").symlink_to(db)
    _refused(_cli(*BENCH, "--out", str(tmp_path / "sym.db")), "symbolic link", f"--out {db}")
    (tmp_path / "dangling.db").symlink_to(tmp_path / "nowhere.db")
    with pytest.raises(ResultsFileError, match="symbolic link"):
        ResultsDB(tmp_path / "dangling.db")
    assert not (tmp_path / "nowhere.db").exists()  # nothing created through the link
    with ResultsDB(tmp_path / "sym.db", read_only=True) as ro:  # reading through a link is harmless
        assert ro.count() == 3


def test_the_lock_survives_sqlite_connections_and_does_not_block_readers(tmp_path):
    """flock on the file is independent of SQLite's POSIX locks: SQLite opening and closing
    connections in the holder keeps it, other processes still read, and SQLite's own lock of
    the writer's connection outlives the writer's lock."""
    db = _results(tmp_path / "r.db")

    def others_see() -> str:
        return subprocess.run([sys.executable, "-c", TRY_FLOCK, str(db)], capture_output=True, text=True).stdout

    with ResultsDB(db) as w:
        with w.lock_for_writing():
            for _ in range(3):
                with ResultsDB(db, read_only=True) as ro:
                    assert ro.count() == 3
                sqlite3.connect(db).close()
            assert others_see().strip() == "held"
            w.add_run(_fields(7), failure_record("crash", "x"))
            assert _cli("export", str(db), "--format", "csv", "--out", str(tmp_path / "r.csv")).returncode == 0
        assert others_see().strip() == "free"
        assert _posix_locks(db), "SQLite's lock of the open connection was dropped with the writer's lock"
    assert not _posix_locks(db)


def _posix_locks(path: Path) -> list[str]:
    """This process's POSIX (fcntl) locks on ``path``, from /proc/locks."""
    if not Path("/proc/locks").exists():
        pytest.skip("no /proc/locks")
    mine = (f" {os.getpid()} ", f":{os.stat(path).st_ino} ")
    return [x for x in Path("/proc/locks").read_text().splitlines() if "POSIX" in x and all(m in x for m in mine)]


def test_flock_is_what_the_lock_takes(tmp_path):
    """The writer's lock is visible to any flock on any name of the file."""
    db = _results(tmp_path / "r.db")
    with ResultsDB(db) as w, w.lock_for_writing():
        fd = os.open(db, os.O_RDONLY)
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)


# -- no output over a results file ---------------------------------------------------------------------


OUTPUT_COMMANDS = {
    "replay": ["replay", "{db}", "--run", "1", "--out", "{out}"],
    "export csv": ["export", "{db}", "--format", "csv", "--out", "{out}"],
    "export planner-arena": ["export", "{db}", "--format", "planner-arena", "--out", "{out}"],
    "export ompl-log": ["export", "{db}", "--format", "ompl-log", "--out", "{out}"],
    "report html": ["report", "{db}", "--html", "{out}"],
    "report csv": ["report", "{db}", "--csv", "{out}"],
    "report markdown": ["report", "{db}", "--markdown", "{out}"],
    "report plots": ["report", "{db}", "--plots", "{out}"],
    "plan json": ["plan", "--problem", "mbm:box/0001", "--json", "{out}"],
    "plan replay": ["plan", "--problem", "mbm:box/0001", "--replay", "{out}"],
    "field": ["field", "--out", "{out}"],
    "kernel": ["kernel", "--out", "{out}"],
}


@pytest.mark.parametrize("command", sorted(OUTPUT_COMMANDS))
def test_no_command_writes_over_a_results_file(command, tmp_path, capsys):
    db = _results(tmp_path / "r.db")
    other = _results(tmp_path / "other.db")
    before = {p: _sha(p) for p in (db, other)}
    reads_db = "{db}" in OUTPUT_COMMANDS[command]
    for out in (db, other):
        args = [a.format(db=db, out=out) for a in OUTPUT_COMMANDS[command]]
        needle = "itself" if out == db and reads_db else "is a SQLite database"
        if out == db:  # the exit code and the message as a user sees them
            _refused(_cli(*args), str(out), needle)
        else:  # the same in-process (quicker)
            assert main(args) == 2 and needle in capsys.readouterr().err
    assert {p: _sha(p) for p in (db, other)} == before
    with ResultsDB(db, read_only=True) as ro:
        assert ro.count() == 3


def test_replay_onto_the_results_file_leaves_it_readable(tmp_path):
    db = _results(tmp_path / "r.db")
    os.link(db, tmp_path / "same.db")  # the same file by another name: refused as itself
    for out in (db, tmp_path / "same.db"):
        _refused(_cli("replay", str(db), "--run", "1", "--out", str(out)), "is the results file", "itself")
    with ResultsDB(db, read_only=True) as ro:
        assert [r["seed"] for r in ro.rows()] == [0, 1, 2]


def test_check_output_passes_new_files_folders_and_other_files(tmp_path):
    db = _results(tmp_path / "r.db")
    assert check_output(tmp_path / "new.html", [db]) == tmp_path / "new.html"
    assert check_output(tmp_path, [db]) == tmp_path
    (tmp_path / "old.html").write_text("<html>")
    assert check_output(tmp_path / "old.html", [db]) == tmp_path / "old.html"
    (tmp_path / "sym.html").symlink_to(db)
    with pytest.raises(OutputFileError, match="itself"):
        check_output(tmp_path / "sym.html", [db])
    with pytest.raises(OutputFileError, match="SQLite database"):
        write_runs_csv([], tmp_path / "sym.html")  # the writers check too, without knowing the input


# -- CSV cells a spreadsheet would run -------------------------------------------------------------------

HOSTILE = ['=HYPERLINK("http://x")', "+1+1", "-2+3", "@SUM(A1)", "\tTAB", "\rCR"]


def test_csv_cells_that_start_a_formula_are_escaped_and_numbers_are_not():
    for text in HOSTILE:
        assert csv_cell(text) == "'" + text
    for value in (-0.5, -3, 0.0, True, None, "plain", "a=b", "'quoted"):
        assert csv_cell(value) == value


def _csv_rows(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def test_the_runs_csv_escapes_attacker_chosen_text(tmp_path):
    db = tmp_path / "r.db"
    with ResultsDB(db) as w:
        for seed, text in enumerate(HOSTILE):
            record = failure_record("error", text, traceback=text, planning_time=-0.5)
            record["evaluation"]["failure"] = text
            w.add_run({**_fields(seed, planner=text, family=text), "planner_settings": {"k": text}}, record)
    out = tmp_path / "runs.csv"
    assert _cli("export", str(db), "--format", "csv", "--out", str(out)).returncode == 0
    head, *body = _csv_rows(out.read_text())
    col = {name: i for i, name in enumerate(head)}
    assert len(body) == len(HOSTILE)
    for row in body:
        for name in ("planner", "family", "message", "traceback", "failure"):
            assert row[col[name]].startswith("'"), (name, row[col[name]])
        assert row[col["planning_time"]] == "-0.5"  # a number: untouched
        assert row[col["setup_time"]] == ""  # NaN: empty
    risky = [cell for row in body for cell in row if cell.startswith(tuple("=+-@\t\r"))]
    assert risky and all(_is_number(cell) for cell in risky)  # only numbers (-0.5, a segment -1) start so


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def test_the_summary_csv_escapes_planner_labels():
    summary = [{"planner": "=cmd|'/C calc'!A0", "solved": 1, "planning_time_median": -0.25, "note": math.nan}]
    head, row = _csv_rows(to_csv(summary))
    assert row == ["'=cmd|'/C calc'!A0", "1", "-0.25", ""]
