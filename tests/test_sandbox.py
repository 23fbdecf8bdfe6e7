"""The pieces that contain a plugin, each on its own: the Landlock sandbox, the cgroup and the
tracking reaper, the snapshots verdicts are computed from, the start-up hook check, the scheduling
that gives each plugin its own workers. The attacks through ``planbench bench`` are in
tests/test_containment.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from collections import deque
from pathlib import Path

import pytest

from planbench.bench import sandbox, snapshot
from planbench.bench.procs import Cgroups, descendants, process_alive
from planbench.bench.runner import Runner, _next_for, plugin_of, startup_hooks
from planbench.bench.task import RunTask
from planbench.errors import PlanbenchError
from planbench.runtime.threads import THREAD_VARIABLES

needs_landlock = pytest.mark.skipif(not sandbox.available(), reason="the kernel offers no Landlock")


def _in_child(code: str, env: dict[str, str] | None = None) -> dict:
    """Run ``code`` in a fresh interpreter; the JSON it prints last."""
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **{name: "1" for name in THREAD_VARIABLES}, **(env or {})},  # one thread, as a worker
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@needs_landlock
def test_a_sandboxed_process_writes_only_its_scratch_folder_and_signals_no_one_outside(tmp_path):
    scratch, outside = tmp_path / "scratch", tmp_path / "outside"
    scratch.mkdir()
    outside.mkdir()
    (outside / "problem.json").write_text("{}")
    result = _in_child(
        f"""
        import json, os, signal
        from planbench.bench import sandbox
        state = sandbox.enter({str(scratch)!r}, True)
        out = {{"state": state}}
        def attempt(name, action):
            try:
                action(); out[name] = "done"
            except OSError as exc:
                out[name] = exc.errno
        attempt("scratch", lambda: open("ok.txt", "w").write("x"))
        attempt("rewrite", lambda: open({str(outside / "problem.json")!r}, "w").write("[]"))
        attempt("create", lambda: open({str(outside / "new.txt")!r}, "w").write("x"))
        attempt("remove", lambda: os.unlink({str(outside / "problem.json")!r}))
        attempt("rename", lambda: os.rename({str(outside / "problem.json")!r}, "stolen.json"))
        attempt("signal_parent", lambda: os.kill(os.getppid(), 0))
        attempt("devnull", lambda: open("/dev/null", "w").write("x"))
        out["cwd"] = os.getcwd()
        print(json.dumps(out))
        """
    )
    assert result["state"].startswith("Landlock"), result
    assert result["scratch"] == "done" and result["devnull"] == "done"
    for attack in ("rewrite", "create", "remove", "rename"):
        assert result[attack] in (13, 1, 18), (attack, result)  # EACCES, EPERM, EXDEV: refused
    assert (outside / "problem.json").read_text() == "{}" and not (outside / "new.txt").exists()
    assert result["cwd"] == str(scratch) and (scratch / "ok.txt").exists()
    if "signals out refused" in result["state"]:
        assert result["signal_parent"] == 1  # EPERM


@needs_landlock
def test_the_sandbox_is_inherited_by_children_and_cannot_be_lifted(tmp_path):
    scratch = tmp_path / "scratch"
    result = _in_child(
        f"""
        import json, subprocess, sys
        from planbench.bench import sandbox
        sandbox.enter({str(scratch)!r}, True)
        sandbox.restrict(["/"])  # a second ruleset only narrows
        code = "open({str(tmp_path / "child.txt")!r}, 'w')"
        child = subprocess.run([sys.executable, "-c", code], capture_output=True)
        print(json.dumps({{"child_rc": child.returncode}}))
        """
    )
    assert result["child_rc"] != 0 and not (tmp_path / "child.txt").exists()


def test_the_sandbox_refuses_a_process_that_already_has_threads(tmp_path):
    result = _in_child(
        f"""
        import json, threading, time
        from planbench.bench import sandbox
        threading.Thread(target=time.sleep, args=(5,), daemon=True).start()
        print(json.dumps({{"state": sandbox.enter({str(tmp_path / "s")!r}, True)}}))
        """
    )
    assert result["state"].startswith(("refused", "unavailable")), result


def _task(label: str, planner: str = "straight-line", suite: str = "s", problem: str = "mbm:box/0001") -> RunTask:
    return RunTask(suite=suite, problem_id=problem, problem_ref=problem, label=label, planner=planner, seed=0)


def test_a_worker_takes_the_next_run_of_its_own_plugin_first():
    pending = deque([_task("a"), _task("b"), _task("a", problem="mbm:box/0002"), _task("b", problem="x")])
    assert _next_for(None, pending) == 0
    assert _next_for(plugin_of(_task("b")), pending) == 1
    assert _next_for(plugin_of(_task("c")), pending) == 0  # none left for it: it is replaced
    assert plugin_of(_task("a")) != plugin_of(_task("a", suite="other"))
    assert plugin_of(_task("a")) != plugin_of(_task("a", planner="matrix-field"))


def test_a_verdict_is_computed_from_the_problem_as_read_before_any_plugin_ran(tmp_path):
    import planbench

    problem = planbench.load_problems("mbm:box/0001")[0]
    path = tmp_path / "p.json"
    problem.save(path)
    snap = snapshot.take("planner", str(path))
    data = json.loads(path.read_text())
    data["scene"]["obstacles"] = []  # a plugin empties the scene after the benchmark read it
    path.write_text(json.dumps(data))
    restored = snapshot.restore(snap)
    assert len(restored.scene) == len(problem.scene) > 0


def test_a_file_the_problem_points_to_that_changed_gives_no_verdict(tmp_path):
    import planbench

    problem = planbench.load_problems("mbm:box/0001")[0]
    robot_dir = tmp_path / "robot"
    settings = problem.robot.settings
    urdf = robot_dir / "arm.urdf"
    robot_dir.mkdir()
    urdf.write_text(Path(settings.urdf).read_text())
    snap = snapshot.take("planner", "mbm:box/0001")
    snap = {**snap, "files": {**snap["files"], str(urdf): snapshot._hash(str(urdf))}}
    urdf.write_text(urdf.read_text().replace("<robot", "<robot data-x='1'", 1))
    with pytest.raises(snapshot.SnapshotChanged, match="arm.urdf changed after the benchmark read it"):
        snapshot.restore(snap)
    with pytest.raises(snapshot.SnapshotChanged, match="could not be read"):
        snapshot.restore({"error": "ProblemFileError: bad"})


def test_a_start_up_hook_planted_during_the_benchmark_stops_new_validators(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    runner = Runner(1)
    runner._hooks = startup_hooks()
    runner._check_hooks()  # nothing changed: fine
    (tmp_path / "evil.pth").write_text("import os\n")
    with pytest.raises(PlanbenchError, match=r"start-up hooks changed during the benchmark \(.*evil.pth"):
        runner._check_hooks()


def _spawn_escapee(tmp_path: Path, cgroup: str) -> tuple[subprocess.Popen, int]:
    """A worker stand-in (joins ``cgroup``, forks the reaper) whose child leaves its session."""
    pid_file = tmp_path / "escapee"
    code = f"""
        import os, subprocess, sys, time
        from planbench.bench.procs import join_cgroup, start_reaper
        os.setsid()  # as detach() does: the reaper kills this process group at the end
        join_cgroup({cgroup!r})
        start_reaper(0.05)
        child = subprocess.Popen([sys.executable, "-c", "import os, time; os.setsid(); time.sleep(300)"])
        open({str(pid_file)!r}, "w").write(str(child.pid))
        time.sleep(300)
        """
    worker = subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)])
    for _ in range(400):
        if pid_file.exists() and pid_file.read_text():
            break
        __import__("time").sleep(0.05)
    return worker, int(pid_file.read_text())


def _gone(pid: int, seconds: float = 10.0) -> bool:
    import time

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not process_alive(pid):
            return True
        time.sleep(0.05)
    return False


@pytest.mark.parametrize("use_cgroups", [True, False])
def test_a_child_that_left_its_session_dies_with_its_worker(tmp_path, monkeypatch, use_cgroups):
    if not use_cgroups:
        monkeypatch.setenv("PLANBENCH_CGROUPS", "0")
    cgroups = Cgroups()
    if use_cgroups and not cgroups.base:
        pytest.skip("this process cannot make cgroups (v2)")
    worker, escapee = _spawn_escapee(tmp_path, cgroups.make("w"))
    try:
        import time

        time.sleep(0.5)  # the tracking reaper has seen it
        assert escapee in descendants(worker.pid) or use_cgroups
        worker.kill()  # as the kernel does to a worker whose benchmark was killed (PDEATHSIG)
        worker.wait()
        assert _gone(escapee), "the escapee outlived its worker"
    finally:
        cgroups.close()
        if process_alive(escapee):
            os.kill(escapee, 9)
