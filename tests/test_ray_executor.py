"""``--executor ray``: the same rows as the local executor on a simulated two-node Ray cluster,
crash / timeout / error rows as locally, no orphans after a killed driver, resume, and a clear error
without Ray. Every Ray process stays on 127.0.0.1 and is stopped by the fixture.

The cluster (``ray.cluster_utils.Cluster``, two nodes of one CPU each) is shared by the module's
tests; the test planners (tests/bench_planners.py, bench_adversarial_planners.py) reach the Ray
workers through ``PYTHONPATH``, set before the nodes start (they inherit it)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import planbench.cli.main as cli
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.procs import process_alive
from planbench.bench.sandbox import WRITABLE_VARIABLE
from planbench.bench.suite import parse_suite

# Read when Ray is imported (so set before): every Ray process of these tests binds 127.0.0.1.
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"

TESTS = Path(__file__).parent
LOOPBACK = "127.0.0.1"
NOT_COMPARED = {"id", "planning_time", "setup_time", "wall_time", "validation_time", "elapsed", "worker_pid"}
NOT_COMPARED |= {"host", "finished", "tick_time_median", "tick_time_p99", "field_update_time", "stalled_time"}
"""Row fields that are times, or say which process and when: they may differ between executors."""


def _ray_pids() -> set[int]:
    """Pids of the Ray daemons running now (raylet, gcs_server)."""
    pids = set()
    for stat in Path("/proc").glob("[0-9]*/comm"):
        try:
            if stat.read_text().strip() in ("raylet", "gcs_server"):
                pids.add(int(stat.parent.name))
        except OSError:
            pass
    return pids


def _ray_listeners() -> list[str]:
    """``address:port  process`` of every TCP/UDP socket listening in a Ray process of this user
    (raylet, gcs_server, ``ray::`` workers, this driver); empty without ``ss``."""
    try:
        out = subprocess.run(["ss", "-tulnpH"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    found = []
    for line in out.splitlines():
        fields = line.split()
        users = fields[-1] if fields and fields[-1].startswith("users:") else ""
        names = re.findall(r'\("([^"]+)",pid=(\d+)', users)
        if any(n in ("raylet", "gcs_server") or n.startswith("ray::") or int(p) == os.getpid() for n, p in names):
            found.append(f"{fields[4]}  {users}")
    return found


def _wait_gone(pids: set[int] | list[int], seconds: float = 20.0) -> list[int]:
    deadline = time.monotonic() + seconds
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if process_alive(p)]
        time.sleep(0.1)
    return alive


@pytest.fixture(scope="module")
def plugin_out(tmp_path_factory):
    """A folder the plugins of the cluster's runs may write (their sandbox lets them)."""
    return tmp_path_factory.mktemp("plugin-out")


@pytest.fixture(scope="module")
def cluster(plugin_out):
    """A local Ray cluster of two simulated nodes (1 CPU each), this process connected to it."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'planbench[ray]')")
    from ray.cluster_utils import Cluster

    path = os.environ.get("PYTHONPATH", "")
    os.environ["PYTHONPATH"] = os.pathsep.join([str(TESTS), path]) if path else str(TESTS)
    os.environ[WRITABLE_VARIABLE] = str(plugin_out)  # inherited by the nodes, their actors and workers
    before = _ray_pids()
    c = None
    try:
        c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
        c.add_node(num_cpus=1)
        c.wait_for_nodes()
        ray.init(address=c.address, logging_level="WARNING", log_to_driver=False)
        yield c
    finally:
        ray.shutdown()
        if c is not None:
            c.shutdown()
        os.environ["PYTHONPATH"] = path
        os.environ.pop(WRITABLE_VARIABLE, None)
        if not path:
            del os.environ["PYTHONPATH"]
        started = _ray_pids() - before
        assert _wait_gone(started) == [], "Ray daemons of the test cluster outlived it"


def _rows(db_path: Path) -> list[dict]:
    with ResultsDB(db_path) as db:
        rows = db.rows(with_arrays=True)
    return sorted(rows, key=lambda r: (r["problem"], r["planner"], r["seed"]))


def _comparable(row: dict) -> dict:
    out = {k: v for k, v in row.items() if k not in NOT_COMPARED and k not in ("path", "times")}
    info = json.loads(out["info"]) if isinstance(out.get("info"), str) else out.get("info")
    if isinstance(info, dict):  # the worker's own planning time is a time too
        out["info"] = {k: v for k, v in info.items() if k != "worker_planning_time"}
    for k in ("path", "times"):  # bit for bit
        out[k] = None if row[k] is None else (row[k].shape, np.ascontiguousarray(row[k], "<f8").tobytes())
    return {k: ("nan" if isinstance(v, float) and np.isnan(v) else v) for k, v in out.items()}


def _ray_executor():
    from planbench.bench.ray_executor import RayExecutor

    return RayExecutor()  # uses the connection of this process (the test cluster)


@pytest.mark.slow
def test_the_cluster_stays_on_the_loopback_and_actors_run_on_their_main_thread(cluster):
    import ray

    from planbench.bench.ray_slot import SlotActor

    nodes = [n for n in ray.nodes() if n["Alive"]]
    assert len(nodes) == 2 and {n["NodeManagerAddress"] for n in nodes} == {LOOPBACK}
    assert ray.get_runtime_context().gcs_address.startswith(f"{LOOPBACK}:")
    info = _ray_executor().connect()
    assert (info.nodes, info.workers) == (2, 2)
    actor = ray.remote(num_cpus=1)(SlotActor).remote()
    try:
        where = ray.get(actor.where.remote())
        listeners = _ray_listeners()
    finally:
        ray.kill(actor)
    assert where["main_thread"]  # the slot's processes die with the thread that started them
    assert listeners or shutil.which("ss") is None  # the check below saw Ray's sockets
    outward = [x for x in listeners if not x.startswith((f"{LOOPBACK}:", f"[::ffff:{LOOPBACK}]:"))]
    assert outward == [], "Ray listens on an address other than 127.0.0.1"


STEPS = """
[suite]
name = "smoke-steps"
description = "the smoke suite's problems and planners, every run ended by a step budget, never by time"
problems = ["mbm:*/0001-0002"]
seeds = [0]
time_limit = 120.0
[[planners]]
planner = "straight-line"
[[planners]]
planner = "matrix-field"
settings = { max_steps = 3000 }
"""


@pytest.mark.slow
def test_the_smoke_suite_gives_the_same_rows_on_two_ray_nodes_as_locally(cluster, tmp_path):
    # the smoke suite's matrix-field runs cut by their 5 s limit end where the machine's load let
    # them get (different rows under load); a step budget ends them where the planner decides
    # (at most ~2 s of the 120 s limit on an idle 2-core machine)
    suite = parse_suite(STEPS, "smoke-steps.toml")
    local = run_benchmark(suite, tmp_path / "local.db", jobs=2)
    ray_run = run_benchmark(suite, tmp_path / "ray.db", executor=_ray_executor())
    assert local.ran == ray_run.ran == 28
    a, b = _rows(tmp_path / "local.db"), _rows(tmp_path / "ray.db")
    assert [_comparable(r) for r in a] == [_comparable(r) for r in b]
    assert any(r["success"] for r in b) and any(r["path"] is not None for r in b)
    assert len({r["worker_pid"] for r in b}) >= 2  # the runs were spread over the nodes' workers


MISBEHAVING = """
[suite]
name = "bad"
problems = ["mbm:table_pick/0001"]
seeds = [0, 1]
time_limit = 0.5
grace = 0.3
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
[[planners]]
label = "fresh"
planner = "bench_planners:NoisyPlanner"
fresh_process = true
"""


@pytest.mark.slow
def test_errors_timeouts_and_crashes_are_the_local_rows(cluster, tmp_path):
    suite = parse_suite(MISBEHAVING, "bad.toml")
    run_benchmark(suite, tmp_path / "local.db", jobs=2)
    run_benchmark(suite, tmp_path / "ray.db", executor=_ray_executor())
    a, b = _rows(tmp_path / "local.db"), _rows(tmp_path / "ray.db")
    assert len(a) == len(b) == 10

    def essentials(r: dict) -> tuple:
        first_line = r["message"].splitlines()[0] if r["message"] else ""
        if r["status"] == "timeout":  # the message holds the measured time
            first_line = first_line.split(" ran ")[0]
        return (r["planner"], r["seed"], r["status"], r["success"], first_line)

    assert [essentials(r) for r in a] == [essentials(r) for r in b]
    by = {(r["planner"], r["seed"]): r for r in b}
    assert "SIGKILL" in by["kills-itself", 0]["message"] and "exit code 3" in by["exits", 0]["message"]
    assert "bench-exit planner says goodbye" in by["exits", 0]["traceback"]  # the worker's output tail
    assert "bench_planners.py" in by["sleeps", 0]["traceback"]  # where it hung (faulthandler)
    assert by["fresh", 0]["worker_pid"] != by["fresh", 1]["worker_pid"]  # fresh_process: a new worker


@pytest.mark.slow
def test_a_killed_driver_leaves_no_process_behind_and_resume_completes(cluster, plugin_out, tmp_path):
    pid_file = plugin_out / "pids.json"
    hang = (
        '[[planners]]\nlabel = "hangs"\nplanner = "bench_adversarial_planners:HangingPlanner"\n'
        f'settings = {{ pid_file = "{pid_file}" }}\n'
    )
    noisy = '[[planners]]\nlabel = "noisy"\nplanner = "bench_planners:NoisyPlanner"\n'
    head = '[suite]\nname = "k"\nproblems = ["mbm:box/0001-0002"]\nseeds = [0, 1]\ntime_limit = 600\n'
    suite_file = tmp_path / "k.toml"
    suite_file.write_text(head + noisy + hang)
    db_path = tmp_path / "r.db"
    script = tmp_path / "driver.py"
    script.write_text(
        "from planbench.bench.benchmark import run_benchmark, select\n"
        "from planbench.bench.ray_executor import RayExecutor\n"
        "if __name__ == '__main__':\n"
        f"    ex = RayExecutor(address={cluster.address!r})\n"
        f"    run_benchmark(select({str(suite_file)!r}), {str(db_path)!r}, executor=ex)\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        while not pid_file.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert pid_file.exists(), "the hanging planner never started"
        pids = json.loads(pid_file.read_text())
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    # the driver's actors die with it, their workers with them, and the planner's child with its worker
    assert _wait_gone([pids["worker"], pids["child"]]) == []
    with ResultsDB(db_path) as db:
        before = db.count()
    suite = parse_suite(head + noisy, "k.toml")
    outcome = run_benchmark(suite, db_path, executor=_ray_executor(), resume=True)
    assert (outcome.skipped, outcome.ran) == (before, 4 - before)
    with ResultsDB(db_path) as db:
        keys = [(r["problem"], r["planner"], r["seed"]) for r in db.rows()]
    assert len(keys) == len(set(keys)) == 4


def test_without_ray_the_cli_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    args = ["bench", "--executor", "ray", "--out", str(tmp_path / "r.db"), "--no-progress"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "pip install 'planbench[ray]'" in err and "Traceback" not in err
    assert not (tmp_path / "r.db").exists()


def test_an_address_needs_the_ray_executor(tmp_path, capsys):
    assert cli.main(["bench", "--address", "auto", "--out", str(tmp_path / "r.db")]) == 2
    assert "--executor ray" in capsys.readouterr().err
