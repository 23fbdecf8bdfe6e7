"""Hostile planner plugins (distribution ``containment-hostile``) for tests/test_containment.py,
one per attack of issue 28. Each claims a success it did not earn: a path that stays at the start
(``bogus``), so its own verdict must be a failure whatever it does to the benchmark.

They find the benchmark as any plugin could: the results file among the open files of the
worker's parent (``/proc/<ppid>/fd``), the validator among the parent's other children.
Everything they achieve or are refused is reported in ``info`` (and, where a test needs it
whatever happens to the row, in a file named by a setting).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import site
import sqlite3
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planbench.planner import Planner, PlanResult, PlanStatus


def bogus(problem: Any, **info: Any) -> PlanResult:
    """A success claimed for a path that never leaves the start."""
    path = np.array([problem.start, problem.start])
    return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration", info=info)


def children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError, ValueError):
            out += [int(x) for x in (task / "children").read_text().split()]
    return out


def cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def write_json(path: str, data: Any) -> None:
    if path:
        tmp = path + ".tmp"
        with open(tmp, "w") as f:
            json.dump(data, f)
        os.replace(tmp, path)


def wait_monotonic(seconds: float) -> None:
    """Sleep ``seconds`` of real time (whatever ``time.perf_counter`` says)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(min(0.05, max(0.0, end - time.monotonic())))


# -- attack 3: the results file ---------------------------------------------------------------------


def find_results_file() -> str:
    """The results database the benchmark (this worker's parent) has open."""
    ppid = os.getppid()
    found = []
    with contextlib.suppress(OSError):
        for fd in os.listdir(f"/proc/{ppid}/fd"):
            with contextlib.suppress(OSError):
                target = os.readlink(f"/proc/{ppid}/fd/{fd}")
                if target.endswith(".db") and os.path.isfile(target):
                    found.append(target)
    if found:
        return found[0]
    args = cmdline(ppid).split(b"\0")  # else its --out, relative to its working directory
    if b"--out" in args:
        out = args[args.index(b"--out") + 1].decode()
        with contextlib.suppress(OSError):
            return os.path.join(os.readlink(f"/proc/{ppid}/cwd"), out)
    return ""


INVENTED = "invented-planner"


def forge_rows(db: str, me: str) -> int:
    """Make this planner's stored runs successes and every other planner's failures, and insert
    rows ahead of the runs still to come: this planner's as successes, the others' as failures,
    and a planner that is not in the suite. How many rows were written."""
    con = sqlite3.connect(db, timeout=5.0)
    try:
        suite, definition, settings = con.execute("SELECT name, definition, settings FROM suites").fetchone()
        d = json.loads(definition)
        mine = [p["label"] for p in d["planners"] if p["planner"] == me]
        others = [p["label"] for p in d["planners"] if p["planner"] != me]
        marks = ",".join("?" * len(mine))
        n = 0
        with con:
            n += con.execute(
                "UPDATE runs SET success=0, status='collision', failure='collision: forged' "
                f"WHERE planner NOT IN ({marks})",
                mine,
            ).rowcount
            n += con.execute(
                f"UPDATE runs SET success=1, status='success', failure='' WHERE planner IN ({marks})", mine
            ).rowcount
            forged = [(label, 1) for label in [*mine, INVENTED]] + [(label, 0) for label in others]
            for problem in d["problems"]:
                family = problem.split(":")[-1].split("/")[0]
                for seed in d["seeds"]:
                    for label, success in forged:
                        n += con.execute(
                            "INSERT OR IGNORE INTO runs (suite, problem, family, planner, seed, planner_name, "
                            "status, success, failure, message, settings, planning_time) "
                            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                            (
                                suite,
                                problem,
                                family,
                                label,
                                seed,
                                label,
                                "success" if success else "collision",
                                success,
                                "" if success else "collision: forged",
                                "forged",
                                settings,
                                0.001,
                            ),
                        ).rowcount
        return n
    finally:
        con.close()


class ResultsWriterPlanner(Planner):
    """Rewrites and adds rows of the results file (see :func:`forge_rows`)."""

    name = "containment-writer"

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        info: dict[str, Any] = {}
        try:
            info["db"] = db = find_results_file()
            info["rows_forged"] = forge_rows(db, self.name) if db else 0
        except Exception as exc:
            info["refused"] = f"{type(exc).__name__}: {exc}"
        return bogus(problem, **info)


@dataclass(frozen=True)
class LockConfig:
    hold: float = 120.0
    """[s] how long to hold the results file's write lock."""


_LOCKS: list[str] = []


class LockHolderPlanner(Planner):
    """Takes an exclusive transaction on the results file in a thread that outlives its run, so the
    benchmark cannot write the row of this run (nor any later one) while it holds it."""

    name = "containment-lock-holder"
    Config = LockConfig

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        db = find_results_file()
        ready = threading.Event()

        def hold() -> None:
            try:
                con = sqlite3.connect(db, timeout=5.0, isolation_level=None, check_same_thread=False)
                con.execute("BEGIN EXCLUSIVE")
                _LOCKS.append("held")
            except Exception as exc:
                _LOCKS.append(f"refused: {type(exc).__name__}: {exc}")
                return
            finally:
                ready.set()
            time.sleep(self.config.hold)
            con.execute("ROLLBACK")

        if db:
            threading.Thread(target=hold, daemon=True).start()
            ready.wait(10.0)
        return bogus(problem, db=db, locks=list(_LOCKS))


# -- attack 4: an interpreter start-up hook, then a new validator -------------------------------------


@dataclass(frozen=True)
class HookConfig:
    pth_name: str = ""
    """The .pth file to write into every site-packages folder."""
    hook_file: str = ""
    """The Python file the .pth line executes (written by the test, harmless)."""
    report_file: str = ""
    """Where to say (JSON, a list: one entry per run) which .pth files were written and which
    processes were killed."""


def pth_line(hook_file: str) -> str:
    h = repr(hook_file)
    return f"import os; os.path.isfile({h}) and exec(compile(open({h}).read(), {h}, 'exec'), {{}})\n"


def site_folders() -> list[str]:
    folders = list(site.getsitepackages())
    with contextlib.suppress(Exception):
        folders.append(site.getusersitepackages())
    return folders


def kill_validators() -> tuple[list[int], list[str]]:
    """SIGKILL the parent's other spawned children (the validator: this worker is the only
    worker with --jobs 1); the pids killed, and the refusals."""
    killed, refused = [], []
    me = os.getpid()
    for pid in children(os.getppid()):
        cmd = cmdline(pid)
        if pid == me or b"spawn_main" not in cmd or b"resource_tracker" in cmd:
            continue
        try:
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
        except OSError as exc:
            refused.append(f"{pid}: {exc}")
    return killed, refused


class HookInstallerPlanner(Planner):
    """Writes a ``.pth`` start-up hook into site-packages and the user site folder, then kills the
    benchmark's validator, so that the one started in its place runs the hook."""

    name = "containment-hook-installer"
    Config = HookConfig

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        runs: list[Any] = []
        with contextlib.suppress(OSError, ValueError):
            runs = json.loads(Path(self.config.report_file).read_text())
        written, refused = [], []
        for folder in site_folders():
            target = os.path.join(folder, self.config.pth_name)
            try:
                os.makedirs(folder, exist_ok=True)
                with open(target, "w") as f:
                    f.write(pth_line(self.config.hook_file))
                written.append(target)
            except OSError as exc:
                refused.append(f"{target}: {exc}")
            write_json(self.config.report_file, [*runs, {"written": written}])  # at once: the test removes them
        killed, kill_refused = kill_validators()
        report = {"written": written, "refused": refused, "killed": killed, "kill_refused": kill_refused}
        write_json(self.config.report_file, [*runs, report])
        wait_monotonic(0.5)  # the benchmark starts the new validator meanwhile
        return bogus(problem, **report)


# -- attack 5: processes that outlive the benchmark ----------------------------------------------------


@dataclass(frozen=True)
class EscapeConfig:
    pid_file: str = ""
    """Where to write (JSON) the pids of the processes it started or killed."""
    kill_reaper: bool = False
    """Also kill the worker's reaper (its forked child) and start a child in the worker's group."""
    hang: bool = False
    """Never return (the test kills the benchmark)."""


class EscaperPlanner(Planner):
    """Starts ``sleep 300`` in a session of its own (out of the worker's process group); with
    ``kill_reaper``, kills the worker's reaper and starts a second ``sleep 300`` in the group."""

    name = "containment-escaper"
    Config = EscapeConfig

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        quiet = dict(stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        pids: dict[str, Any] = {"worker": os.getpid()}
        before = set(children(os.getpid()))
        escaped = subprocess.Popen(["sleep", "300"], start_new_session=True, **quiet)  # os.setsid() in the child
        pids["escaped"] = escaped.pid
        if self.config.kill_reaper:
            own = cmdline(os.getpid())
            reapers = [pid for pid in before if cmdline(pid) == own]  # forked, never exec'd
            for pid in reapers:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
            pids["reapers"] = reapers
            pids["in_group"] = subprocess.Popen(["sleep", "300"], **quiet).pid
        previous = {}
        with contextlib.suppress(OSError, ValueError):
            previous = json.loads(Path(self.config.pid_file).read_text())
        write_json(self.config.pid_file, {**previous, str(len(previous)): pids})
        while self.config.hang:
            time.sleep(1.0)
        return bogus(problem, **{k: v for k, v in pids.items() if k != "reapers"})


# -- attack 6: planning time under-reported ------------------------------------------------------------


@dataclass(frozen=True)
class ClockConfig:
    sleep: float = 1.0
    """[s] real time the plan takes."""


class ClockHalverPlanner(Planner):
    """Replaces ``time.perf_counter`` (the clock the harness times ``plan()`` with) by one that runs
    at half speed from the start of its plan, then takes ``sleep`` seconds: the harness in its
    process measures half of them."""

    name = "containment-clock-halver"
    Config = ClockConfig

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        real = time.perf_counter
        t0 = real()
        time.perf_counter = lambda: t0 + (real() - t0) * 0.5
        wait_monotonic(self.config.sleep)
        return bogus(problem, slept=self.config.sleep)
