"""The benchmark's trust boundary: verdicts computed where no planner code ran, results received as
data (never unpickled), every malformed result an error row naming the bad field, the memory limit
an error row. Planners in tests/bench_adversarial_planners.py."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

import planbench
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.runner import _fields_from
from planbench.bench.sandbox import WRITABLE_VARIABLE
from planbench.bench.suite import parse_suite
from planbench.bench.wire import BadField, BadMessage, clean_result, decode, encode
from planbench.bench.worker import error_fields

COLLIDING = "mbm:box/0001"  # the straight line from start to goal goes through the box
A = "bench_adversarial_planners"


def suite(planners: str, problems=(COLLIDING,), name="t", time_limit=2.0, extra="") -> str:
    head = f"""
[suite]
name = "{name}"
problems = {list(problems)!r}
seeds = [0]
time_limit = {time_limit}
grace = 1.0
{extra}
"""
    return head + planners


def test_the_problem_collides_on_the_straight_line():
    problem = planbench.load_problems(COLLIDING)[0]
    from bench_adversarial_planners import straight_path

    result = planbench.PlanResult(planbench.PlanStatus.SUCCESS, path=straight_path(problem), target="configuration")
    assert not planbench.evaluate(problem, result).success
    sl = planbench.plan(problem, "straight-line")
    assert not planbench.evaluate(problem, sl).success


def test_a_planner_that_patches_validation_changes_no_verdict(tmp_path):
    planners = f"""
[[planners]]
label = "a-patcher"
planner = "{A}:PatchingPlanner"
[[planners]]
label = "straight-line"
planner = "straight-line"
"""
    db_path = tmp_path / "r.db"
    run_benchmark(parse_suite(suite(planners), "patch.toml"), db_path, jobs=1)
    with ResultsDB(db_path) as db:
        rows = {r["planner"]: r for r in db.rows()}
    patcher, sl = rows["a-patcher"], rows["straight-line"]
    assert patcher["status"] == "success"  # what it claimed
    assert '"in_process_verdict_fooled": true' in patcher["info"]  # the patch works where it ran ...
    assert not patcher["success"] and "collision" in patcher["failure"]  # ... and changes no verdict
    assert patcher["worker_pid"] != sl["worker_pid"]  # one plugin per process: the patch went with it
    assert not sl["success"], sl["failure"]


def test_a_plugin_that_patches_on_import_never_runs_in_the_main_process(tmp_path, monkeypatch):
    marker = tmp_path / "imported.txt"
    monkeypatch.setenv("PLANBENCH_TEST_IMPORT_MARKER", str(marker))
    monkeypatch.setenv(WRITABLE_VARIABLE, str(tmp_path))  # the plugin's sandbox lets it write the marker
    planners = '[[planners]]\nlabel = "patcher"\nplanner = "bench_import_patcher:ImportPatchingPlanner"\n'
    run_benchmark(parse_suite(suite(planners), "import.toml"), tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        (row,) = db.rows()
    assert row["status"] == "success" and not row["success"] and "collision" in row["failure"]
    imported_in = marker.read_text().split()
    assert imported_in and str(os.getpid()) not in imported_in  # the probe and the worker, not here
    assert str(row["worker_pid"]) in imported_in


MALFORMED = {  # kind -> text the row's message must hold (the field it names)
    "huge_int": "info['collision_checks']: integer 18446744073709551616",
    "exception_message": "message: a RuntimeError, not text",
    "unserializable": "info['thing']: a object",
    "gigantic_info": "info: 6.1 MiB as JSON, more than the 1024 KiB kept",
    "reduce_bomb": "info['bomb']: a bench_adversarial_planners._Bomb",
    "wrong_shape": "path must be an (N, nq) array, got shape (5,)",
    "bad_status": "status must be a PlanStatus, got 'totally-solved'",
    "not_a_result": "plan() returned dict, not a PlanResult",
}


@pytest.mark.slow
def test_malformed_results_are_error_rows_naming_the_field_and_the_rest_goes_on(tmp_path):
    marker = tmp_path / "unpickled.txt"
    planners = "".join(
        f'[[planners]]\nlabel = "{kind}"\nplanner = "{A}:MalformedPlanner"\n'
        f'settings = {{ kind = "{kind}", marker = "{marker}" }}\n'
        for kind in [*MALFORMED, "nan_path"]
    )
    planners += '[[planners]]\nplanner = "straight-line"\n'
    problems = (COLLIDING, "mbm:table_pick/0001")
    s = parse_suite(suite(planners, problems=problems), "malformed.toml")
    db_path = tmp_path / "r.db"
    outcome = run_benchmark(s, db_path, jobs=2)
    assert outcome.ran == 2 * (len(MALFORMED) + 2)
    with ResultsDB(db_path) as db:
        rows = {(r["planner"], r["problem"]): r for r in db.rows()}
    assert len(rows) == outcome.ran
    for kind, text in MALFORMED.items():
        for problem in problems:
            row = rows[kind, problem]
            assert row["status"] == "error" and not row["success"], (kind, row["failure"])
            assert text in row["message"], (kind, row["message"])
            assert text in row["failure"], (kind, row["failure"])
    for problem in problems:
        nan = rows["nan_path", problem]
        assert not nan["success"] and "NaN" in nan["failure"]
    assert rows["straight-line", "mbm:table_pick/0001"]["success"]
    assert rows["straight-line", COLLIDING]["status"] == "collision"
    # a __reduce__ never ran in this process (the worker sends data, nothing is unpickled here)
    pids = marker.read_text().split() if marker.exists() else []
    assert str(os.getpid()) not in pids
    # --resume works on this file
    again = run_benchmark(s, db_path, jobs=1, resume=True)
    assert (again.ran, again.skipped) == (0, outcome.ran)
    more = s.with_changes(problems=(*problems, "mbm:box/0002"))
    third = run_benchmark(more, db_path, jobs=2, resume=True)
    assert third.ran == len(MALFORMED) + 2


def test_the_parent_catches_what_a_patched_worker_lets_through(tmp_path):
    planners = f'''
[[planners]]
label = "a-bypass"
planner = "{A}:MalformedPlanner"
settings = {{ kind = "bypass_worker_check" }}
[[planners]]
planner = "straight-line"
'''
    s = parse_suite(suite(planners, problems=("mbm:table_pick/0001",)), "bypass.toml")
    run_benchmark(s, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        rows = {r["planner"]: r for r in db.rows()}
    bad = rows["a-bypass"]
    assert bad["status"] == "error" and "info['collision_checks']: integer 18446744073709551616" in bad["message"]
    assert "found on receipt" in bad["message"]
    assert rows["straight-line"]["success"]  # the next run is intact, in a worker of its own
    assert rows["straight-line"]["worker_pid"] != bad["worker_pid"]


@pytest.mark.slow
def test_a_pickle_sent_to_the_parent_is_refused_unread(tmp_path):
    marker = tmp_path / "unpickled.txt"
    planners = f"""
[[planners]]
label = "pickler"
planner = "{A}:MalformedPlanner"
settings = {{ kind = "pickle_to_parent", marker = "{marker}" }}
[[planners]]
planner = "straight-line"
"""
    s = parse_suite(suite(planners, problems=("mbm:table_pick/0001",), time_limit=10.0), "pickle.toml")
    run_benchmark(s, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        rows = {r["planner"]: r for r in db.rows()}
    bad = rows["pickler"]
    assert bad["status"] == "error" and "the worker sent a malformed message" in bad["message"]
    assert "worker process killed" in bad["message"]
    assert not marker.exists()  # nothing unpickled it, here or anywhere
    assert rows["straight-line"]["success"]


@pytest.mark.slow
def test_memory_limit_turns_a_hog_into_an_error_row_and_the_benchmark_goes_on(tmp_path):
    planners = f'[[planners]]\nlabel = "hog"\nplanner = "{A}:MemoryHogPlanner"\n'
    planners += '[[planners]]\nplanner = "straight-line"\n'
    problems = ("mbm:table_pick/0001",)
    limited = parse_suite(suite(planners, problems=problems, extra="memory_limit = 4096"), "hog.toml")
    run_benchmark(limited, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        rows = {r["planner"]: r for r in db.rows()}
    hog = rows["hog"]
    assert hog["status"] == "error" and "MemoryError" in hog["message"], hog["message"]
    assert "memory limit of 4096 MiB" in hog["message"] and "memory limit of 4096 MiB" in hog["failure"]
    assert rows["straight-line"]["success"]  # in a fresh worker: the hog's ended after its run
    assert rows["straight-line"]["worker_pid"] != hog["worker_pid"]
    # the same reservation without a limit succeeds: it was the limit that stopped it
    unlimited = limited.with_changes(name="unlimited", memory_limit=0, planners=limited.planners[:1])
    run_benchmark(unlimited, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        (free,) = db.rows("unlimited")
    assert free["status"] == "step_limit" and "reserved" in free["message"]


# -- the parent's own checks, without processes ---------------------------------------------------


def _done(result: dict, arrays: dict | None = None) -> tuple[dict, dict]:
    return decode(encode({"type": "done", "run": 1, "result": result}, arrays))


def _fields(**changes) -> dict:
    f = error_fields("m")
    f.update(status="success", planning_time=0.1, setup_time=0.0, wall_time=0.2)
    f.pop("path"), f.pop("times")
    f.update(changes)
    return f


def test_the_parent_rechecks_what_the_worker_sent():
    path = np.zeros((3, 7))
    header, arrays = _done(_fields(), {"path": path})
    fields = _fields_from(header, arrays)
    assert fields["status"] == "success" and np.array_equal(fields["path"], path)
    bad = {
        "info": ({"collision_checks": 2**64}, "info['collision_checks']"),
        "message": (["not", "text"], "message"),
        "status": ("won", "status"),
        "planning_time": ("fast", "planning_time"),
        "pid": (-3, "pid"),
        "target": ("moon", "target"),
    }
    for name, (value, named) in bad.items():
        header, arrays = _done(_fields(**{name: value}))
        with pytest.raises(BadField, match=named.replace("[", r"\[").replace("]", r"\]")):
            _fields_from(header, arrays)
    header, arrays = _done(_fields(), {"path": np.zeros((3, 7)), "times": np.zeros(2)})
    with pytest.raises(BadField, match="times"):
        _fields_from(header, arrays)
    header, arrays = _done(_fields(extra=1))
    with pytest.raises(BadField, match="unknown"):
        _fields_from(header, arrays)


def test_malformed_messages_are_refused_before_anything_is_built():
    good = encode({"type": "x"}, {"path": np.ones((2, 3))})
    assert decode(good)[1]["path"].shape == (2, 3)
    for data in (b"", b"nope" * 5, good[:-8], good + b"\x00", good.replace(b"[2, 3]", b"[9, 9]")):
        with pytest.raises(BadMessage):
            decode(data)
    with pytest.raises(BadMessage):
        decode(b"PBW1" + (10**6).to_bytes(8, "little") + b"{}")


def test_clean_result_keeps_json_data_and_names_everything_else():
    info = {"n": np.int64(3), "x": np.float32(0.5), "a": np.arange(3), "big": np.zeros(5000), 1: "one", "nan": math.nan}
    f = clean_result({**_fields(info=info), "path": None, "times": None})
    assert f["info"]["n"] == 3 and f["info"]["a"] == [0, 1, 2] and f["info"]["1"] == "one"
    assert f["info"]["big"].startswith("<array (5000,)") and math.isnan(f["info"]["nan"])
    nested: dict = {}
    nested["self"] = nested
    for info, named in (({"s": {1, 2}}, "info['s']"), (nested, "nested deeper"), ({"t": "\ud800"}, "UTF-8")):
        with pytest.raises(BadField, match=named.replace("[", r"\[").replace("]", r"\]")):
            clean_result({**_fields(info=info), "path": None, "times": None})


@pytest.mark.slow
def test_planners_are_checked_in_a_probe_process_with_named_errors(tmp_path):
    from planbench.errors import InvalidSettingError, PlanbenchError

    bad = '[[planners]]\nlabel = "missing"\nplanner = "no_such_module_here:Planner"\n'
    with pytest.raises(PlanbenchError, match="planner 'missing': cannot load planner entry point"):
        run_benchmark(parse_suite(suite(bad), "bad.toml"), tmp_path / "a.db", jobs=1)
    settings = f'[[planners]]\nlabel = "hog"\nplanner = "{A}:MemoryHogPlanner"\nsettings = {{ nope = 1 }}\n'
    with pytest.raises(InvalidSettingError, match="planner label 'hog'.*setting nope = 1 is not accepted.*gib"):
        run_benchmark(parse_suite(suite(settings), "bad.toml"), tmp_path / "b.db", jobs=1)
    optional = bad.replace('label = "missing"', 'label = "missing"\noptional = true')
    optional += '[[planners]]\nplanner = "straight-line"\n'
    outcome = run_benchmark(parse_suite(suite(optional), "opt.toml"), tmp_path / "c.db", jobs=1)
    assert outcome.ran == 1 and outcome.skipped_planners and "missing" in outcome.skipped_planners[0]


@pytest.mark.slow
def test_a_planner_that_freezes_the_worker_clock_is_charged_the_time_the_parent_saw(tmp_path):
    planners = f'[[planners]]\nlabel = "liar"\nplanner = "{A}:ClockLiarPlanner"\nfresh_process = true\n'
    s = parse_suite(suite(planners, time_limit=3.0), "liar.toml")
    run_benchmark(s, tmp_path / "r.db", jobs=1)
    with ResultsDB(tmp_path / "r.db") as db:
        (row,) = db.rows()
    assert row["planning_time"] >= 0.95  # it slept 1 s; its own process measured about 0
    assert json.loads(row["info"])["worker_planning_time"] < 0.5  # the worker's word, kept as information
