"""Issue 28, "Contain every plugin": hostile plugins, installed as a user installs them, run through
``planbench bench`` (the command line, in a subprocess), must change nothing of the other runs.

Each attacker (tests/containment_plugins/) is installed with an honest plugin into a temporary
folder as two distributions (``<name>-0.1.dist-info`` with ``METADATA`` and ``entry_points.txt``,
group ``planbench.planners``) on the benchmark's ``PYTHONPATH``; workers are spawned and inherit
it. Every test checks, against the same benchmark without the attacker (:func:`baseline`):

- no verdict, time or stored row of the other runs changes (the honest plugin and straight-line);
- the attacker's own runs are failure rows, never the success it claims without earning it (a path
  that never leaves the start, or the straight line through the obstacles);
- the benchmark exits (code 0) with every run stored and no invented one;
- nothing the attacker started outlives the benchmark: no process that carries this test's tag in
  its environment runs a few seconds after ``planbench bench`` returned (survivors are killed at
  the end of the test, by pid).

Attacks that only the kernel sandbox (``planbench/bench/sandbox.py``, ``available()``) can block are
skipped without it (:func:`require_sandbox`); ``PLANBENCH_TEST_UNSANDBOXED=1`` runs them anyway, to
see the attack go through.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import math
import os
import re
import shutil
import signal
import site
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import pytest

import planbench
from planbench.bench.db import ResultsDB
from planbench.bench.procs import process_alive
from planbench.bench.sandbox import WRITABLE_VARIABLE

pytestmark = pytest.mark.slow

PLUGINS = Path(__file__).parent / "containment_plugins"
ROOT = Path(planbench.__file__).resolve().parents[1]  # the planbench these tests import
PLANBENCH = [sys.executable, "-m", "planbench.cli.main"]
TAG = "PLANBENCH_CONTAINMENT_TAG"
HOOK_DIR = "PLANBENCH_CONTAINMENT_HOOK"
BENCH_TIMEOUT = 45.0
"""[s] a benchmark of a few runs that takes longer did not end: it is killed and the test fails."""

BOX, TABLE = "mbm:box/0001", "mbm:table_pick/0001"  # the straight line collides / is valid
PROBLEMS = (BOX, TABLE)
HONEST_SLEEP = 0.2  # containment_honest.SLEEP
HONEST = {"label": "b-honest", "planner": "containment-honest"}
STRAIGHT = {"label": "straight-line", "planner": "straight-line"}

DISTRIBUTIONS = {
    "containment-hostile": (
        ("containment_hostile", "containment_shapeshifter", "containment_rewriter"),
        {
            "containment-shapeshifter": "containment_shapeshifter:ShapeshifterPlanner",
            "containment-rewriter": "containment_rewriter:ProblemRewriterPlanner",
            "containment-writer": "containment_hostile:ResultsWriterPlanner",
            "containment-lock-holder": "containment_hostile:LockHolderPlanner",
            "containment-hook-installer": "containment_hostile:HookInstallerPlanner",
            "containment-escaper": "containment_hostile:EscaperPlanner",
            "containment-clock-halver": "containment_hostile:ClockHalverPlanner",
        },
    ),
    "containment-honest": (("containment_honest",), {"containment-honest": "containment_honest:HonestPlanner"}),
}

# Columns that differ between two runs of the same benchmark (or name the suite).
VOLATILE = {
    "id",
    "suite",
    "planning_time",
    "setup_time",
    "wall_time",
    "validation_time",
    "elapsed",
    "worker_pid",
    "host",
    "versions",
    "finished",
    "traceback",
}

TIME_NOTE = re.compile(r"\s*\[[^\]]*\d s\b[^\]]*\]")
"""A note in a row's message that holds a time (e.g. "[planning time: the worker reported 0.208 s, ...]"):
its numbers differ from one benchmark to the next."""

# -- the sandbox guard ---------------------------------------------------------------------------------


def _sandboxed() -> bool:
    """Whether planbench confines workers with the kernel sandbox (``planbench.bench.sandbox``)."""
    if importlib.util.find_spec("planbench.bench.sandbox") is None:
        return False
    from planbench.bench import sandbox  # type: ignore[attr-defined]

    return bool(sandbox.available())


def require_sandbox(why: str) -> None:
    if not _sandboxed() and os.environ.get("PLANBENCH_TEST_UNSANDBOXED") != "1":
        pytest.skip(f"needs the kernel sandbox (planbench.bench.sandbox.available()): {why}")


# -- plugins installed as a user installs them -----------------------------------------------------------


def install_plugins(folder: Path) -> Path:
    """``folder`` as a site-packages folder holding the two plugin distributions."""
    folder.mkdir(parents=True, exist_ok=True)
    for dist, (modules, entry_points) in DISTRIBUTIONS.items():
        info = folder / f"{dist.replace('-', '_')}-0.1.dist-info"
        info.mkdir()
        files = []
        for module in modules:
            shutil.copy(PLUGINS / f"{module}.py", folder / f"{module}.py")
            files.append(f"{module}.py")
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
        lines = "".join(f"{name} = {value}\n" for name, value in entry_points.items())
        (info / "entry_points.txt").write_text(f"[planbench.planners]\n{lines}")
        (info / "INSTALLER").write_text("pip\n")
        record = [*files, *(f"{info.name}/{n}" for n in ("METADATA", "entry_points.txt", "INSTALLER", "RECORD"))]
        (info / "RECORD").write_text("".join(f"{f},,\n" for f in record))
    return folder


def toml_value(value: Any) -> str:
    return json.dumps(value)  # strings, booleans and numbers are the same in TOML


def suite_text(
    name: str, planners: list[dict[str, Any]], problems=PROBLEMS, time_limit: float = 5.0, grace: float = 2.0
) -> str:
    lines = [
        "[suite]",
        f"name = {toml_value(name)}",
        f"problems = {json.dumps(list(problems))}",
        "seeds = [0]",
        f"time_limit = {time_limit}",
        f"grace = {grace}",
        "",
    ]
    for p in planners:
        lines += ["[[planners]]", f"label = {toml_value(p['label'])}", f"planner = {toml_value(p['planner'])}"]
        if p.get("settings"):
            items = ", ".join(f"{k} = {toml_value(v)}" for k, v in p["settings"].items())
            lines.append(f"settings = {{ {items} }}")
        lines.append("")
    return "\n".join(lines)


# -- processes -------------------------------------------------------------------------------------------


def tagged(tag: str) -> list[int]:
    """Running processes (zombies excluded) whose environment holds ``TAG=tag``: everything the
    benchmark of one test started, and what its plugins started in turn."""
    needle = f"{TAG}={tag}".encode()
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            environ = Path(f"/proc/{entry}/environ").read_bytes()
        except OSError:
            continue
        if needle in environ.split(b"\0") and process_alive(int(entry)):
            out.append(int(entry))
    return out


def wait_gone(pids: list[int], seconds: float = 5.0) -> list[int]:
    """The pids still running after up to ``seconds``."""
    deadline = time.monotonic() + seconds
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if process_alive(p)]
        time.sleep(0.05)
    return alive


def describe(pids: list[int]) -> str:
    out = []
    for pid in pids:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            cmd = "?"
        out.append(f"{pid} ({cmd.strip()[:100]})")
    return ", ".join(out)


def kill_all(pids: list[int]) -> None:
    for pid in pids:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)


class Bench:
    """``planbench bench`` with the plugins of :func:`install_plugins` on its ``PYTHONPATH``, and a
    tag in its environment that every process it starts inherits."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.site = install_plugins(tmp / "site-packages")
        self.tag = uuid.uuid4().hex
        path = [str(self.site), str(ROOT), os.environ.get("PYTHONPATH", "")]
        self.env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in path if p), **{TAG: self.tag})
        self.env.pop(HOOK_DIR, None)
        self.out = tmp / "plugin-out"
        """The one folder besides their scratch that the plugins may write (they say their pids there)."""
        self.out.mkdir()
        self.env[WRITABLE_VARIABLE] = str(self.out)

    def write_suite(self, name: str, planners: list[dict[str, Any]], **kw: Any) -> Path:
        path = self.tmp / f"{name}.toml"
        path.write_text(suite_text("containment", planners, **kw))
        return path

    def command(self, suite: Path, db: Path, *extra: str) -> list[str]:
        return [*PLANBENCH, "bench", "--suite", str(suite), "--out", str(db), "--jobs", "1", "--no-progress", *extra]

    def start(self, suite: Path, db: Path, *extra: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        return subprocess.Popen(
            self.command(suite, db, *extra),
            env={**self.env, **(env or {})},
            cwd=self.tmp,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )

    def run(self, suite: Path, db: Path, *extra: str, env: dict[str, str] | None = None) -> str:
        """Run the benchmark to its end; its output. Fails the test when it exits with another code
        than 0 or runs past :data:`BENCH_TIMEOUT`."""
        proc = self.start(suite, db, *extra, env=env)
        try:
            out, _ = proc.communicate(timeout=BENCH_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
            pytest.fail(f"planbench bench did not end within {BENCH_TIMEOUT:g} s; its output:\n{out[-3000:]}")
        assert proc.returncode == 0, f"planbench bench exited with {proc.returncode}; its output:\n{out[-3000:]}"
        return out

    def run_suite(
        self, name: str, planners: list[dict[str, Any]], env: dict[str, str] | None = None, **kw: Any
    ) -> tuple[dict[tuple[str, str, int], dict[str, Any]], Path, Path]:
        """Run a suite to its end into a new results file: its rows by (problem, label, seed), the
        suite file and the results file. Fails the test when a process it started outlives it."""
        suite, db = self.write_suite(name, planners, **kw), self.tmp / f"{name}.db"
        self.run(suite, db, env=env)
        self.assert_nothing_survives()
        return read_rows(db), suite, db

    def assert_nothing_survives(self, seconds: float = 5.0) -> None:
        alive = wait_gone(tagged(self.tag), seconds)
        assert not alive, f"processes started by the benchmark outlive it: {describe(alive)}"

    def cleanup(self) -> None:
        kill_all(tagged(self.tag))


@pytest.fixture
def bench(tmp_path):
    b = Bench(tmp_path)
    try:
        yield b
    finally:
        b.cleanup()


# -- rows ------------------------------------------------------------------------------------------------


def read_rows(db: Path) -> dict[tuple[str, str, int], dict[str, Any]]:
    with ResultsDB(db, read_only=True) as results:
        return {(r["problem"], r["planner"], int(r["seed"])): r for r in results.rows(with_arrays=True)}


def stable(row: dict[str, Any]) -> dict[str, Any]:
    """The columns of a row that two runs of the same benchmark share (NaN as text, arrays as lists)."""
    out = {}
    for k, v in row.items():
        if k in VOLATILE:
            continue
        if k == "message" and isinstance(v, str):
            v = TIME_NOTE.sub("", v)
        elif k == "info" and isinstance(v, str) and v.startswith("{"):
            v = {ik: iv for ik, iv in json.loads(v).items() if ik != "worker_planning_time"}  # a time
        elif isinstance(v, float) and math.isnan(v):
            v = "nan"
        elif hasattr(v, "tolist"):
            v = v.tolist()
        out[k] = v
    return out


def differences(a: dict[str, Any], b: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    sa, sb = stable(a), stable(b)
    return {k: (str(sa.get(k))[:200], str(sb.get(k))[:200]) for k in sa.keys() | sb.keys() if sa.get(k) != sb.get(k)}


def assert_contained(
    rows: dict[tuple[str, str, int], dict[str, Any]],
    baseline: dict[tuple[str, str, int], dict[str, Any]],
    attacker: str,
    others: tuple[dict[str, Any], ...],
    problems: tuple[str, ...],
    time_limit: float = 5.0,
) -> None:
    """The runs of ``others`` are those of ``baseline`` (verdicts, metrics, paths, messages; times
    sane), the attacker's runs are all there and failed, and no other planner was stored."""
    other_labels = {p["label"] for p in others}
    labels = {label for _, label, _ in rows}
    assert labels == other_labels | {attacker}, f"stored planners {sorted(labels)}"
    theirs = {k: r for k, r in rows.items() if k[1] in other_labels}
    expected = sorted((problem, label, 0) for problem in problems for label in other_labels)
    assert sorted(theirs) == expected, f"the other planners' runs: {sorted(theirs)}"
    changed = {k: d for k, r in theirs.items() if (d := differences(baseline[k], r))}
    assert not changed, f"rows of other runs changed (column: (alone, with {attacker})): {changed}"
    for key, row in theirs.items():
        t = row["planning_time"]
        assert math.isfinite(t) and 0.0 <= t < time_limit, f"{key}: planning time {t}"
        if key[1] == HONEST["label"]:  # (a halved clock says 0.1 s; a parent's stamp may be a little late)
            assert t >= 0.75 * HONEST_SLEEP, f"{key}: planning time {t} s, but the planner took {HONEST_SLEEP} s"
    mine = {k: r for k, r in rows.items() if k[1] == attacker}
    assert sorted(k[0] for k in mine) == sorted(problems), f"runs of {attacker}: {sorted(mine)}"
    for key, row in mine.items():
        assert not row["success"], f"{key}: the attacker's unearned success was stored: {row['status']}, {row['info']}"


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """The rows of the other planners, benchmarked without any attacker."""
    b = Bench(tmp_path_factory.mktemp("baseline"))
    try:
        rows, _, _ = b.run_suite("baseline", [HONEST, STRAIGHT])
    finally:
        b.cleanup()
    for key, row in rows.items():
        assert json.loads(row["info"]).get("patched", False) is False, (key, row["info"])
    assert {k: r["success"] for k, r in rows.items() if k[1] == "straight-line"} == {
        (BOX, "straight-line", 0): False,
        (TABLE, "straight-line", 0): True,
    }
    return rows


# -- 1: a worker shared with another plugin --------------------------------------------------------------


def test_a_plugin_that_patches_its_worker_reaches_no_other_plugin(bench, baseline):
    """The shapeshifter patches its process on import and in plan() (the clock, numpy, the harness, a
    marker); the honest plugin runs after it (labels sort "a-" first), --jobs 1, and must see
    none of it: a worker never runs code of two plugins or two planner labels."""
    attacker = {"label": "a-shapeshifter", "planner": "containment-shapeshifter"}
    rows, _, _ = bench.run_suite("shapeshift", [attacker, HONEST, STRAIGHT], problems=(TABLE,))
    seen = {k: json.loads(r["info"]) for k, r in rows.items() if k[1] == HONEST["label"]}
    assert all(info["patched"] is False for info in seen.values()), f"the honest plugin saw patches: {seen}"
    assert_contained(rows, baseline, "a-shapeshifter", (HONEST, STRAIGHT), (TABLE,))


# -- 2: the problem file rewritten ---------------------------------------------------------------------


def write_problem_file(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "box.json"
    planbench.load_problems(BOX)[0].save(path)
    return path


@pytest.fixture(scope="module")
def file_baseline(tmp_path_factory):
    """The other planners' rows on the problem file, without any attacker."""
    b = Bench(tmp_path_factory.mktemp("file-baseline"))
    try:
        problem = write_problem_file(b.tmp / "problems")
        rows, _, _ = b.run_suite("file-baseline", [STRAIGHT], problems=(str(problem),))
    finally:
        b.cleanup()
    assert {r["success"] for r in rows.values()} == {False}  # the straight line collides
    return rows


@pytest.mark.parametrize("when", ["plan", "import"])
def test_a_plugin_that_rewrites_the_problem_file_changes_no_verdict(bench, file_baseline, when):
    """The rewriter removes the obstacles from the problem file (in plan(), or on import, which is in
    the benchmark's probe before any worker runs), then claims the straight line through them. The
    validator judges against the problem as it was before any plugin ran."""
    problem = write_problem_file(bench.tmp / "problems")
    original = problem.read_bytes()
    attacker = {"label": "a-rewriter", "planner": "containment-rewriter", "settings": {"problem_file": str(problem)}}
    env = {"CONTAINMENT_REWRITE_AT_IMPORT": str(problem)} if when == "import" else {}
    rows, _, _ = bench.run_suite(f"rewrite-{when}", [attacker, STRAIGHT], env=env, problems=(str(problem),))
    (mine,) = [r for k, r in rows.items() if k[1] == "a-rewriter"]
    assert not mine["success"], f"the straight line through the removed obstacles was judged {mine['status']}"
    assert_contained(rows, file_baseline, "a-rewriter", (STRAIGHT,), (BOX,))
    if _sandboxed():
        assert problem.read_bytes() == original, "the sandbox let the plugin write the problem file"


# -- 3: the results file -------------------------------------------------------------------------------


def test_a_plugin_that_writes_into_the_results_file_changes_no_row(bench, baseline):
    """The writer (labels sort "z-" last, so other rows exist) opens the --out file with sqlite3:
    makes its own rows successes and the others' failures, and inserts rows ahead of the runs
    to come (its own as successes, the others' as failures, an invented planner). No stored row
    changes; a later --resume works and changes nothing."""
    require_sandbox("only the kernel can keep a plugin from writing a file its user may write")
    attacker = {"label": "z-writer", "planner": "containment-writer"}
    rows, suite, db = bench.run_suite("writer", [STRAIGHT, attacker])
    assert_contained(rows, baseline, "z-writer", (STRAIGHT,), PROBLEMS)
    out = bench.run(suite, db, "--resume")
    assert "0 to run" in " ".join(out.split()), out[-2000:]
    again = read_rows(db)
    assert sorted(again) == sorted(rows)
    assert {k: d for k in rows if (d := differences(rows[k], again[k]))} == {}


def test_a_plugin_that_holds_the_results_file_locked_stalls_nothing(bench, baseline):
    """The lock holder takes an exclusive SQLite transaction on the --out file in a thread that
    outlives its run (120 s). The benchmark still ends, in its usual time, with every row."""
    require_sandbox("only the kernel can keep a plugin from locking a file its user may write")
    attacker = {"label": "a-lock-holder", "planner": "containment-lock-holder", "settings": {"hold": 120.0}}
    rows, suite, db = bench.run_suite("lock", [attacker, STRAIGHT], problems=(BOX,))
    assert_contained(rows, baseline, "a-lock-holder", (STRAIGHT,), (BOX,))
    bench.run(suite, db, "--resume")
    assert sorted(read_rows(db)) == sorted(rows)


# -- 4: an interpreter start-up hook, then a killed validator ------------------------------------------

HOOK_SOURCE = '''
# Written by tests/test_containment.py; does nothing unless PLANBENCH_CONTAINMENT_HOOK names a folder.
import os, sys
_dir = os.environ.get("PLANBENCH_CONTAINMENT_HOOK", "")
if _dir and os.path.isdir(_dir):
    with open(os.path.join(_dir, "ran.txt"), "a") as f:
        f.write(f"{os.getpid()}\\n")
    import importlib.abc, importlib.machinery

    class _ForgeVerdicts(importlib.abc.MetaPathFinder):
        """planbench.validate.evaluate, once imported, says success (and notes where it did)."""

        def find_spec(self, name, path, target=None):
            if name != "planbench.validate":
                return None
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            if spec is None or spec.loader is None:
                return None
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                real = module.evaluate

                def evaluate(problem, result, settings=None):
                    e = real(problem, result, settings)
                    with open(os.path.join(_dir, "forged.txt"), "a") as f:
                        f.write(f"{os.getpid()}\\n")
                    return module.Evaluation(True, "", "success", e.planning_time, e.setup_time)

                module.evaluate = evaluate

            spec.loader.exec_module = exec_module
            return spec

    sys.meta_path.insert(0, _ForgeVerdicts())
'''


def site_folders() -> list[Path]:
    """Where the hook installer writes (containment_hostile.site_folders, in this interpreter)."""
    return [Path(p) for p in site.getsitepackages()] + [Path(site.getusersitepackages())]


def first_missing(folder: Path) -> Path:
    """The topmost folder of ``folder``'s chain that does not exist."""
    while not folder.parent.exists():
        folder = folder.parent
    return folder


def test_a_start_up_hook_and_a_killed_validator_forge_no_verdict(bench, baseline):
    """The hook installer writes a .pth file into site-packages and the user site folder (its line
    runs a hook that makes planbench.validate.evaluate say success), then SIGKILLs the
    benchmark's validator so that a new interpreter takes its place. The write is refused, the
    kill is refused, or the new validator loads no hook: no verdict is forged.

    Whatever the plugin manages to write into site-packages is removed at the end (the hook does
    nothing outside this test's processes: it needs PLANBENCH_CONTAINMENT_HOOK)."""
    require_sandbox("without it the benchmark stops at the planted hook (tests/test_sandbox.py)")
    hook_dir = bench.tmp / "hook"
    hook_dir.mkdir()
    hook_file = bench.tmp / "containment_hook.py"
    hook_file.write_text(HOOK_SOURCE)
    pth_name = f"planbench_containment_{bench.tag}.pth"
    report = bench.tmp / "hook-report.json"
    targets = [folder / pth_name for folder in site_folders()]
    made = [(folder, first_missing(folder)) for folder in site_folders() if not folder.exists()]
    settings = {"pth_name": pth_name, "hook_file": str(hook_file), "report_file": str(report)}
    attacker = {"label": "a-hook-installer", "planner": "containment-hook-installer", "settings": settings}
    try:
        rows, _, _ = bench.run_suite("hook", [attacker, STRAIGHT], env={HOOK_DIR: str(hook_dir)}, problems=(BOX,))
    finally:
        written = []
        with contextlib.suppress(OSError, ValueError):
            written = [Path(p) for run in json.loads(report.read_text()) for p in run["written"]]
        for path in {*targets, *written}:
            if path.name == pth_name:
                with contextlib.suppress(OSError):
                    path.unlink()
        for folder, top in made:  # the folders the plugin created (a user site folder), if still empty
            with contextlib.suppress(OSError):
                while True:
                    folder.rmdir()
                    if folder == top:
                        break
                    folder = folder.parent
    said = report.read_text() if report.exists() else "(no report)"
    forged = hook_dir / "forged.txt"
    assert not forged.exists(), f"the hook forged verdicts in processes {forged.read_text().split()}; plugin: {said}"
    assert_contained(rows, baseline, "a-hook-installer", (STRAIGHT,), (BOX,))


# -- 5: processes that outlive the benchmark -----------------------------------------------------------


def started_pids(pid_file: Path) -> dict[str, list[int]]:
    runs = json.loads(pid_file.read_text())
    out: dict[str, list[int]] = {}
    for run in runs.values():
        for key, value in run.items():
            out.setdefault(key, []).extend(value if isinstance(value, list) else [value])
    return out


def test_processes_a_plugin_starts_die_with_the_benchmark(bench, baseline):
    """The escaper starts ``sleep 300`` in a session of its own (out of the worker's process group),
    kills the worker's reaper and starts another ``sleep 300`` in the group. Once planbench
    bench has returned, none of them runs."""
    pid_file = bench.out / "pids.json"
    settings = {"pid_file": str(pid_file), "kill_reaper": True}
    attacker = {"label": "a-escaper", "planner": "containment-escaper", "settings": settings}
    suite, db = bench.write_suite("escape", [attacker, STRAIGHT], problems=(TABLE,)), bench.tmp / "escape.db"
    bench.run(suite, db)
    pids = started_pids(pid_file)
    alive = wait_gone(pids["escaped"] + pids["in_group"])
    assert not alive, f"started by the plugin, alive after the benchmark: {describe(alive)} (all: {pids})"
    bench.assert_nothing_survives()
    assert_contained(read_rows(db), baseline, "a-escaper", (STRAIGHT,), (TABLE,))


def test_processes_a_plugin_starts_die_when_the_benchmark_is_killed(bench):
    """As above, but the escaper then hangs and the benchmark is killed (SIGKILL) mid-run: its worker,
    the reaper's victims and the escaped session die with it."""
    require_sandbox("only the kernel can end a process that left the worker's session once the benchmark is gone")
    pid_file = bench.out / "pids.json"
    settings = {"pid_file": str(pid_file), "kill_reaper": True, "hang": True}
    attacker = {"label": "a-escaper", "planner": "containment-escaper", "settings": settings}
    suite = bench.write_suite("escape-kill", [attacker], problems=(TABLE,), time_limit=60.0)
    proc = bench.start(suite, bench.tmp / "escape-kill.db")
    try:
        deadline = time.monotonic() + BENCH_TIMEOUT
        while not pid_file.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert pid_file.exists(), f"the plugin never ran; output:\n{proc.communicate(timeout=10)[0][-3000:]}"
        time.sleep(0.2)  # it hangs now
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    pids = started_pids(pid_file)
    alive = wait_gone(pids["worker"] + pids["escaped"] + pids["in_group"])
    assert not alive, f"alive after the benchmark was killed: {describe(alive)} (all: {pids})"
    bench.assert_nothing_survives()


# -- 6: planning time under-reported -------------------------------------------------------------------


def test_a_plugin_that_slows_its_clock_is_charged_its_real_planning_time(bench, baseline):
    """The clock halver makes time.perf_counter (the harness's clock in the worker) run at half speed,
    then plans for 2 s: its stored planning time is the parent's measurement (about 2 s), not the 1 s
    its process measured. The honest plugin after it is charged its own time, not half of it."""
    attacker = {"label": "a-clock-halver", "planner": "containment-clock-halver", "settings": {"sleep": 2.0}}
    rows, _, _ = bench.run_suite("clock", [attacker, HONEST], problems=(TABLE,))
    (mine,) = [r for k, r in rows.items() if k[1] == "a-clock-halver"]
    # (its own clock says 1 s; the parent's stamps may be a little late, or early by a hand-off)
    assert mine["planning_time"] >= 1.5, f"planning 2 s was stored as {mine['planning_time']} s"
    assert_contained(rows, baseline, "a-clock-halver", (HONEST,), (TABLE,))
