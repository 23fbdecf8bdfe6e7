import json

import pytest

import planbench
from planbench.cli.main import main
from planbench.conformance import CHECKS
from planbench.reactive.conformance import CHECKS as CONTROLLER_CHECKS


def test_plan_prints_validated_metrics_and_writes_json(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["plan", "--problem", "mbm:table_pick/0001", "--planner", "straight-line", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "success (validated)" in text and "1/1 solved" in text
    rows = json.loads(out.read_text())
    assert rows[0]["problem"] == "mbm:table_pick/0001" and rows[0]["success"] is True
    assert rows[0]["min_clearance"] > 0
    path = rows[0]["path"]
    assert len(path) >= 2 and len(path[0]) == 7
    assert rows[0]["times"] is None or len(rows[0]["times"]) == len(path)


def test_plan_reports_failures_with_their_reason_and_exits_1_when_nothing_is_solved(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["plan", "--problem", "mbm:box/0001-0002", "--set", "timed=false", "--json", str(out)]) == 1
    text = capsys.readouterr().out
    assert "mbm:box/0001 failed: collision" in text and "0/2 solved" in text
    # strict JSON: the metrics a failed run has not (NaN in Python) are null, never the token NaN
    raw = out.read_text()
    assert "NaN" not in raw and "Infinity" not in raw
    rows = json.loads(raw, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    assert rows[0]["success"] is False and rows[0]["joint_path_length"] is None and rows[0]["message"]
    # one solved problem among failed ones: exit 0
    assert main(["plan", "--problem", "mbm:table_pick/0001", "--set", "timed=false"]) == 0


def test_version_and_defaults_in_help(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"planbench {planbench.__version__}"
    with pytest.raises(SystemExit):
        main(["plan", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: straight-line)" in text and "(default: 10.0)" in text and "(default: None)" not in text


def test_user_errors_exit_2_with_a_message(capsys):
    assert main(["plan", "--problem", "mbm:boxx"]) == 2
    assert "Did you mean 'box'" in capsys.readouterr().err
    assert main(["plan", "--problem", "mbm:box/0001", "--planner", "rrt"]) == 2
    assert main(["plan", "--problem", "mbm:box/0001", "--set", "nope=1"]) == 2
    assert "timed" in capsys.readouterr().err


def test_list_shows_planners_robots_sets_and_suites(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # one row per line
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    assert "straight-line" in text and "panda" in text and "ur5" in text and "mbm" in text
    suites = text[text.index("Suites") :]
    from planbench.bench.suite import builtin_suites, load_suite

    for name in builtin_suites():  # every built-in suite, with its kind and what it runs
        row = next(line for line in suites.splitlines() if line.startswith(f"│ {name} "))
        suite = load_suite(name)
        assert suite.kind in row and suite.description[:40] in row


def test_the_built_in_dynamic_suites_run_every_controller():
    from planbench.bench.suite import load_suite

    built_in = {"matrix-field", "matrix-field-qp", "matrix-field-guided", "edt-field", "distance-field", "ompl-replan"}
    for name in ("dynamic", "dynamic-tune", "dynamic-test"):
        assert {e.planner for e in load_suite(name).planners} == built_in, name


def test_plot_needs_a_planner_with_a_figure(capsys):
    assert main(["plan", "--problem", "mbm:box/0001", "--plot", "x.png"]) == 2
    assert "'straight-line' has none" in capsys.readouterr().err


@pytest.mark.parametrize("columns", [80, 120])
def test_plan_output_is_whole_in_narrow_terminals(monkeypatch, capsys, columns):
    monkeypatch.setenv("COLUMNS", str(columns))
    assert main(["plan", "--problem", "mbm:bookshelf_small/0001-0002", "--set", "timed=false"]) == 1
    text = capsys.readouterr().out
    assert "…" not in text and max(len(line) for line in text.splitlines()) <= columns
    assert "mbm:bookshelf_small/0001" in text and "mbm:bookshelf_small/0002" in text


def after_raises(checks):
    """The checks a checker does not get to when the plugin raises on its first call, as listed."""
    return ", ".join(c for c in checks if c not in ("interface", "settings", "raises"))


def test_check_runs_the_conformance_checker_in_its_own_process(monkeypatch, capsys):
    import os
    from pathlib import Path

    tests = str(Path(__file__).parent)
    monkeypatch.setenv("PYTHONPATH", tests + os.pathsep + os.environ.get("PYTHONPATH", ""))
    monkeypatch.syspath_prepend(tests)
    assert main(["check", "straight-line"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[:2] == ["planner straight-line: conformant", f"  passed: {', '.join(CHECKS)}"]
    assert main(["check", "bench_planners:SuicidePlanner"]) == 1  # it kills its process: not this one
    assert "crashed the check's process (SIGKILL)" in capsys.readouterr().out
    assert main(["check", "bench_planners:RaisingPlanner"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[:2] == ["planner bench_planners:RaisingPlanner: NOT conformant", "  failed: raises"]
    assert out[2].startswith("    - raises: on conformance:trivial: plan raised") and "fails on purpose" in out[2]
    assert out[-2:] == ["  passed: interface, settings", f"  not run: {after_raises(CHECKS)}"]
    assert main(["check", "bench_controllers:RaisingController", "--controller"]) == 1  # printed the same way
    out = capsys.readouterr().out.splitlines()
    assert out[:2] == ["controller bench_controllers:RaisingController: NOT conformant", "  failed: raises"]
    assert out[2].startswith("    - raises: step at tick 2") and "fails on purpose" in out[2]
    assert out[-2:] == ["  passed: interface, settings", f"  not run: {after_raises(CONTROLLER_CHECKS)}"]
    assert main(["check", "no-such-planner"]) == 2
    assert "unknown planner 'no-such-planner'" in capsys.readouterr().err


def test_building_the_parser_imports_no_runner_loop_or_numerics():
    """``planbench --help`` builds every command's parser: the benchmark's runner, the closed loop,
    trimesh, numba, scipy and matplotlib are imported by the commands that use them, not for the
    parser (they were most of its 1-2 s)."""
    import subprocess
    import sys

    heavy = ["planbench.bench.runner", "planbench.reactive.runner", "trimesh", "numba", "scipy", "matplotlib", "ompl"]
    code = (
        "import sys; from planbench.cli.main import build_parser; build_parser(); "
        f"print([m for m in {heavy!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_parsers_copies_are_the_benchmarks_values():
    from planbench.bench.executors import EXECUTORS
    from planbench.bench.export import EXPERIMENT_GROUPS
    from planbench.bench.suite import DEFAULT_MEMORY_LIMIT
    from planbench.cli import bench

    assert bench.EXECUTORS == EXECUTORS and bench.EXPERIMENT_GROUPS == EXPERIMENT_GROUPS
    assert bench.DEFAULT_MEMORY_LIMIT == DEFAULT_MEMORY_LIMIT
