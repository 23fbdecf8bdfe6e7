"""The benchmark's processes: a run's children die with it, workers die with the main process
(kill -9 included), and a planner's output never reaches the terminal (its tail is in the row).
Planners in tests/bench_adversarial_planners.py."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.procs import OUTPUT_HEADER, WORKER_DIR_LOCK, WORKER_DIR_PREFIX, process_alive, worker_dir
from planbench.bench.sandbox import WRITABLE_VARIABLE
from planbench.bench.suite import parse_suite

TESTS = Path(__file__).parent


@pytest.fixture(autouse=True)
def plugins_may_write_tmp_path(tmp_path, monkeypatch):
    """The planners here say their pids in a file under tmp_path: their sandbox lets them."""
    monkeypatch.setenv(WRITABLE_VARIABLE, str(tmp_path))


A = "bench_adversarial_planners"
PROBLEM = "mbm:table_pick/0001"


def suite(planners: str, time_limit: float = 0.3, name: str = "p") -> str:
    return f"""
[suite]
name = "{name}"
problems = ["{PROBLEM}"]
seeds = [0]
time_limit = {time_limit}
grace = 0.3
{planners}
"""


def hanging(pid_file: Path) -> str:
    return f'[[planners]]\nlabel = "hangs"\nplanner = "{A}:HangingPlanner"\nsettings = {{ pid_file = "{pid_file}" }}\n'


def wait_gone(pids: list[int], seconds: float = 5.0) -> list[int]:
    """The pids still running after up to ``seconds``."""
    deadline = time.monotonic() + seconds
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if process_alive(p)]
        time.sleep(0.05)
    return alive


def children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def test_a_run_killed_on_timeout_takes_its_child_processes_with_it(tmp_path):
    pid_file = tmp_path / "pids.json"
    run_benchmark(parse_suite(suite(hanging(pid_file)), "hang.toml"), tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        (row,) = db.rows()
    assert row["status"] == "timeout" and "worker process killed" in row["message"]
    pids = json.loads(pid_file.read_text())
    assert wait_gone([pids["worker"], pids["child"]]) == []


def ended_pid() -> int:
    """The pid of a process that has ended (a child started and waited for)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_workers_and_their_children_die_when_the_main_process_is_killed(tmp_path, monkeypatch):
    """And the next benchmark removes the folder of output files that the killed one left."""
    pid_file = tmp_path / "pids.json"
    suite_file = tmp_path / "hang.toml"
    suite_file.write_text(suite(hanging(pid_file), time_limit=600.0))
    db_path = tmp_path / "r.db"
    code = (
        "from planbench.bench import benchmark\n"
        "if __name__ == '__main__':\n"
        f"    benchmark({str(suite_file)!r}, out={str(db_path)!r}, jobs=1)\n"
    )
    script = tmp_path / "run.py"
    script.write_text(code)
    temp = tmp_path / "temp"  # its temporary folder
    temp.mkdir()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]), TMPDIR=str(temp))
    proc = subprocess.Popen([sys.executable, str(script)], env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not pid_file.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert pid_file.exists(), "the hanging planner never started"
        pids = json.loads(pid_file.read_text())
        spawned = children(proc.pid)  # the worker and the validator
        assert pids["worker"] in spawned
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert wait_gone([pids["worker"], pids["child"], *spawned]) == []
    left = [p.name for p in temp.iterdir()]
    assert left == [next(n for n in left if n.startswith(f"{WORKER_DIR_PREFIX}{proc.pid}-"))]
    assert (temp / left[0] / WORKER_DIR_LOCK).exists()  # its lock, released with the process
    gone = ended_pid()
    held = temp / f"{WORKER_DIR_PREFIX}{gone}-elsewhere"  # a pid not ours (another pid namespace): its lock held
    held.mkdir()
    holder = os.open(held / WORKER_DIR_LOCK, os.O_RDWR | os.O_CREAT)
    fcntl.flock(holder, fcntl.LOCK_EX)
    lockless_gone = temp / f"{WORKER_DIR_PREFIX}{gone}-old"  # no lock file: by its pid, which is gone
    lockless_live = temp / f"{WORKER_DIR_PREFIX}{os.getpid()}-old"  # no lock file, its pid runs
    other = temp / f"{WORKER_DIR_PREFIX}old"  # not a name the sweep knows
    for d in (lockless_gone, lockless_live, other):
        d.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    try:
        made, lock = worker_dir()
        os.close(lock)
    finally:
        os.close(holder)
    made_name = Path(made).name
    assert Path(made).parent == temp and made_name.startswith(f"{WORKER_DIR_PREFIX}{os.getpid()}-")
    assert sorted(p.name for p in temp.iterdir()) == sorted([made_name, held.name, lockless_live.name, other.name])


def test_a_planner_flooding_stdout_reaches_neither_the_terminal_nor_the_disk_unbounded(tmp_path, capfd, monkeypatch):
    workdir = tmp_path / "workers"
    workdir.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(workdir))  # where the runner keeps output files
    sizes = [0]
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            for f in workdir.glob("*/*.out"):
                with contextlib.suppress(OSError):
                    sizes[0] = max(sizes[0], f.stat().st_size)
            time.sleep(0.01)

    watcher = threading.Thread(target=watch)
    watcher.start()
    planners = (
        f'[[planners]]\nlabel = "floods"\nplanner = "{A}:FloodPlanner"\nsettings = {{ mib = 48, pause = 0.01 }}\n'
    )
    planners += '[[planners]]\nplanner = "straight-line"\n'
    try:
        run_benchmark(parse_suite(suite(planners, time_limit=30.0), "flood.toml"), tmp_path / "r.db", jobs=1)
    finally:
        done.set()
        watcher.join()
    out, err = capfd.readouterr()
    assert "FLOOD" not in out and "FLOOD" not in err
    assert 0 < sizes[0] < 32 * 2**20  # cut back past 16 MiB while the planner went on to 48
    with ResultsDB(tmp_path / "r.db") as db:
        rows = {r["planner"]: r for r in db.rows()}
    tb = rows["floods"]["traceback"]
    assert OUTPUT_HEADER in tb and tb.rstrip().endswith("FLOOD-END the last words")
    assert "bytes before this]" in tb and len(tb) < 10_000
    assert rows["floods"]["status"] == "step_limit"
    assert OUTPUT_HEADER not in rows["straight-line"]["traceback"]  # each row holds its own run's output
    assert rows["straight-line"]["success"]


def test_a_validation_past_its_timeout_kills_the_validator_and_the_next_run_gets_a_new_one(tmp_path):
    text = suite('[[planners]]\nplanner = "straight-line"\n', time_limit=2.0).replace(
        f'problems = ["{PROBLEM}"]', f'problems = ["{PROBLEM}", "mbm:box/0001"]\nvalidation_timeout = 0.0001'
    )  # 0.1 ms: below a validator's round trip (at 10 ms a quick collision verdict came back in time once)
    run_benchmark(parse_suite(text, "validation.toml"), tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        rows = db.rows()
    assert len(rows) == 2
    for row in rows:
        assert row["status"] == "timeout" and not row["success"]
        assert "validation ran past 0.0001 s; validator process killed" in row["message"]
        assert row["planning_time"] >= 0  # the planner's time is kept
