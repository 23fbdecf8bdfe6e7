"""Planner settings: one way to build a planner (``Registry.configure``), one error for a bad setting
(``InvalidSettingError``) whichever way the setting came (Python, ``planbench plan --set``,
``planbench bench --set``, a suite file), and settings parsed to their ``Config`` field's type
before anything runs. Also the benchmark's run record (``RunTask``) as wire data."""

import ast
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest

import planbench
from planbench import PlanResult, PlanStatus, Registry
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.probe import probe_planners
from planbench.bench.suite import parse_suite
from planbench.bench.task import RunTask
from planbench.bench.wire import BadMessage, decode, encode
from planbench.cli.main import main
from planbench.conformance import check_planner
from planbench.errors import InvalidConfigError, InvalidSettingError
from planbench.harness import DEFAULT_TIME_LIMIT, resolve_planner
from planbench.settings import PlannerSetup

# A real float setting of a real planner, and the message every way of giving it 'abc' must carry.
BAD = ("matrix-field", "speed_max", "abc")
BAD_TEXT = "planner 'matrix-field': setting speed_max = 'abc' is not accepted: expected a number (float)"
TYPO_TEXT = "planner 'matrix-field': setting spead_max = 0.3 is not accepted: the planner has no such setting"


@dataclass(frozen=True)
class KitchenSinkConfig:
    gain: float = 1.0
    steps: int = 10
    on: bool = True
    mode: str = "a"
    limit: float | None = None
    kind: Literal["fast", "slow"] = "fast"
    weights: tuple[float, ...] = (1.0,)
    options: dict[str, Any] = field(default_factory=dict)
    anything: Any = None

    def __post_init__(self) -> None:
        if self.gain < 0:
            raise ValueError(f"gain must be >= 0, got {self.gain}")


class KitchenSinkPlanner(planbench.Planner):
    name = "kitchen-sink"
    Config = KitchenSinkConfig

    def plan(self, problem, *, time_limit, rng):
        return PlanResult(PlanStatus.TIMEOUT, problem.start[None, :])


@pytest.fixture
def registry():
    r = Registry(discover=False)
    r.register(KitchenSinkPlanner)
    return r


def test_command_line_text_is_read_as_each_field_s_type(registry):
    text = {
        "gain": "2.5",
        "steps": "7",
        "on": "no",
        "mode": "123",
        "limit": "none",
        "kind": "slow",
        "weights": "0.5, 1,2e-1",
        "options": '{"eps": 1e-8}',
        "anything": "[1, 2]",
    }
    setup = registry.configure("kitchen-sink", text=text)
    c = setup.config
    assert (c.gain, c.steps, c.on, c.mode, c.limit, c.kind) == (2.5, 7, False, "123", None, "slow")
    assert type(c.gain) is float and type(c.steps) is int and c.on is False
    assert c.weights == (0.5, 1.0, 0.2) and all(type(w) is float for w in c.weights)
    assert c.options == {"eps": 1e-8} and c.anything == [1, 2]
    assert setup.settings["weights"] == (0.5, 1.0, 0.2) and set(setup.settings) == set(text)
    assert isinstance(setup.build(), KitchenSinkPlanner)
    for words, value in ((("true", "1", "yes", "ON"), True), (("false", "0", "No", "off"), False)):
        for word in words:
            assert registry.configure("kitchen-sink", text={"on": word}).config.on is value
    assert registry.configure("kitchen-sink", text={"limit": "null", "weights": "[3, 4]"}).config.weights == (3.0, 4.0)
    assert registry.configure("kitchen-sink", text={"anything": "plain words"}).config.anything == "plain words"


def test_python_and_suite_values_are_checked_and_converted_the_same_way(registry):
    given = {"gain": 2, "steps": 3.0, "weights": [1, 2], "on": 1, "limit": "none"}
    c = registry.configure("kitchen-sink", given).config
    assert (c.gain, c.steps, c.weights, c.on, c.limit) == (2.0, 3, (1.0, 2.0), True, None)
    assert type(c.gain) is float and type(c.steps) is int
    assert registry.configure("kitchen-sink", {"anything": "[1, 2]"}).config.anything == "[1, 2]"  # Any: as given
    assert registry.configure("kitchen-sink", {"steps": np.int64(4)}).config.steps == 4
    bad = [
        ({"gain": "fast"}, "setting gain = 'fast' is not accepted: expected a number (float), got 'fast' (str)"),
        ({"gain": True}, "setting gain = True is not accepted: expected a number (float)"),
        ({"steps": 2.5}, "setting steps = 2.5 is not accepted: expected a whole number (int)"),
        ({"on": "maybe"}, "setting on = 'maybe' is not accepted: expected true or false"),
        ({"mode": 3}, "setting mode = 3 is not accepted: expected text (str)"),
        ({"limit": "lots"}, "setting limit = 'lots' is not accepted: expected a number (float) or none"),
        ({"kind": "medium"}, "setting kind = 'medium' is not accepted: expected one of 'fast', 'slow'"),
        ({"weights": "1,x"}, "setting weights = '1,x' is not accepted: expected a number (float)"),
        ({"options": "[1]"}, "setting options = '[1]' is not accepted: expected a mapping (dict)"),
        ({"gian": 1.0}, "setting gian = 1.0 is not accepted: the planner has no such setting; did you mean 'gain'?"),
        ({"gain": -1}, "setting gain = -1.0 is not accepted: gain must be >= 0, got -1.0"),  # the Config's own check
    ]
    for settings, message in bad:
        with pytest.raises(InvalidSettingError) as info:
            registry.configure("kitchen-sink", settings)
        assert str(info.value).startswith("planner 'kitchen-sink': " + message), str(info.value)
        assert info.value.setting == next(iter(settings)) and info.value.planner == "kitchen-sink"


def test_an_error_crosses_processes_as_data_and_reads_the_same():
    with pytest.raises(InvalidSettingError) as info:
        planbench.make_planner(*BAD[:1], **{BAD[1]: BAD[2]})
    again = InvalidSettingError.from_data(json.loads(json.dumps(info.value.to_data())), where="x.toml")
    assert str(again) == f"x.toml: {info.value}"
    with pytest.raises(TypeError):
        InvalidSettingError.from_data({"planner": 1, "setting": None, "shown": "", "expected": ""})


def test_the_same_bad_setting_gives_the_same_error_every_way(tmp_path, monkeypatch, capsys):
    from planbench_plugins.matrix_field import MatrixFieldPlanner

    planner, key, value = BAD
    problem = planbench.load_problems("mbm:box/0001")[0]
    ways = {
        "Registry.make": lambda: planbench.REGISTRY.make(planner, **{key: value}),
        "make_planner": lambda: planbench.make_planner(planner, **{key: value}),
        "plan by name": lambda: planbench.plan(problem, planner, **{key: value}),
        "plan by class": lambda: planbench.plan(problem, MatrixFieldPlanner, **{key: value}),
        "resolve_planner": lambda: resolve_planner(MatrixFieldPlanner, **{key: value}),
    }
    for way, call in ways.items():
        with pytest.raises(InvalidSettingError) as info:
            call()
        assert str(info.value).startswith(BAD_TEXT), (way, str(info.value))
    with pytest.raises(InvalidSettingError, match=TYPO_TEXT):
        planbench.plan(problem, planner, spead_max=0.3)

    # the command line: exit 2 with the message, before any problem is loaded
    def no_problems(*args, **kwargs):
        raise AssertionError("problems were loaded before the settings were checked")

    monkeypatch.setattr(planbench, "load_problems", no_problems)
    assert main(["plan", "--problem", "mbm:box/0001", "--planner", planner, "--set", f"{key}={value}"]) == 2
    err = capsys.readouterr().err
    assert BAD_TEXT in err and "Traceback" not in err
    assert main(["plan", "--problem", "mbm:box/0001", "--planner", planner, "--set", "spead_max=0.3"]) == 2
    assert TYPO_TEXT in capsys.readouterr().err
    monkeypatch.undo()

    # the benchmark: --set and a suite file, refused before any run; no results file is left behind
    out = tmp_path / "r.db"
    args = ["bench", "--suite", "smoke", "--planners", planner, "--out", str(out), "--no-progress"]
    assert main([*args, "--set", f"{key}={value}"]) == 2
    err = capsys.readouterr().err
    assert BAD_TEXT in err and "Traceback" not in err and not out.exists()
    text = '[suite]\nname = "s"\nproblems = ["mbm:box/0001"]\n[[planners]]\nlabel = "mf"\nplanner = "matrix-field"\n'
    with pytest.raises(InvalidSettingError) as info:
        run_benchmark(parse_suite(text + 'settings = { speed_max = "abc" }\n', "bad.toml"), out, jobs=1)
    assert str(info.value).startswith("bad.toml, planner label 'mf': " + BAD_TEXT)
    with pytest.raises(InvalidSettingError, match=TYPO_TEXT):
        run_benchmark(parse_suite(text + "settings = { spead_max = 0.3 }\n", "bad.toml"), out, jobs=1)
    assert not out.exists()


def test_plan_set_values_reach_the_planner_as_their_types(monkeypatch, capsys):
    seen = []
    build = PlannerSetup.build

    def spy(self):
        seen.append(self.config)
        return build(self)

    monkeypatch.setattr(PlannerSetup, "build", spy)
    monkeypatch.setattr(planbench, "load_problems", lambda selector: [])
    sets = ["verify_path=false", "repulsion_gain=2", "speed_max=0.3", "max_steps=50", "field_mode=lazy"]
    argv = ["plan", "--problem", "mbm:box/0001", "--planner", "matrix-field"]
    assert main([*argv, *(x for s in sets for x in ("--set", s))]) == 1  # no problem loaded: none solved
    (config,) = seen
    assert config.verify_path is False and config.repulsion_gain == 2.0 and config.field_mode == "lazy"
    assert config.speed_max == 0.3 and type(config.speed_max) is float and type(config.max_steps) is int
    assert main([*argv, "--set", "dt=0.1", "--set", "dt=0.2"]) == 2
    assert "--set dt is given twice" in capsys.readouterr().err


def test_the_probe_parses_settings_and_sends_them_back_as_data():
    answers = probe_planners(
        [
            ("matrix-field", {"speed_max": 1, "control_points": {"panda_link7": []}}, {"verify_path": "false"}),
            ("ompl:RRTstar", {}, {"params": '{"range": 0.3}'}),
            ("straight-line", {}, {"timed": "perhaps"}),
        ]
    )
    assert answers[0]["ok"] and answers[0]["settings"] == {
        "speed_max": 1.0,
        "control_points": {"panda_link7": []},  # Any: as given
        "verify_path": False,
    }
    assert type(answers[0]["settings"]["speed_max"]) is float
    assert answers[1]["ok"] and answers[1]["settings"] == {"params": {"range": 0.3}}
    assert not answers[2]["ok"] and answers[2]["setting_error"]["setting"] == "timed"
    assert "setting timed = 'perhaps' is not accepted" in answers[2]["error"]


@pytest.mark.slow
def test_bench_set_stores_the_parsed_settings(tmp_path):
    out = tmp_path / "r.db"
    suite = tmp_path / "s.toml"
    head = '[suite]\nname = "s"\nproblems = ["mbm:table_pick/0001"]\n'
    suite.write_text(head + '[[planners]]\nplanner = "straight-line"\n')
    argv = ["bench", "--suite", str(suite), "--out", str(out), "--no-progress", "--jobs", "1"]
    assert main([*argv, "--set", "timed=no", "--set", "check_resolution=0.02"]) == 0
    with ResultsDB(out) as db:
        (row,) = db.rows()
    settings = row["planner_settings"]
    settings = json.loads(settings) if isinstance(settings, str) else settings
    assert settings == {"timed": False, "check_resolution": 0.02}
    assert row["time_limit"] == 5.0  # the suite's default, as the suite module defines it
    # the same settings written as a suite's values are the same run: nothing to redo
    suite.write_text(suite.read_text() + 'settings = { timed = "false", check_resolution = 0.02 }\n')
    assert main(argv) == 0


def test_run_task_round_trips_through_the_wire_format():
    task = RunTask(
        suite="s",
        problem_id="mbm:box/0001",
        problem_ref="mbm:box/0001",
        label="mf",
        planner="matrix-field",
        seed=2**62,
        settings={"weights": (1.0, 2.0), "limit": None, "on": False},
        family="box",
        time_limit=1.5,
        memory_limit=0.0,
        validation={"required_clearance": 0.01},
        fresh_process=True,
        run_settings={"time_limit": 1.5},
    )
    header, arrays = decode(encode({"type": "run", "run": 3, "task": task.to_wire()}))
    back = RunTask.from_wire(header["task"])
    assert back == dataclasses.replace(task, settings={"weights": [1.0, 2.0], "limit": None, "on": False})
    assert back.key == ("s", "mbm:box/0001", "mf", 2**62) and arrays == {}
    assert RunTask.from_wire(back.to_wire()) == back
    wire = task.to_wire()
    for broken, named in (
        ({k: v for k, v in wire.items() if k != "seed"}, "missing ['seed']"),
        ({**wire, "extra": 1}, "unknown ['extra']"),
        ({**wire, "seed": "0"}, "'seed': expected int"),
        ({**wire, "fresh_process": 1}, "'fresh_process': expected bool"),
        ({**wire, "time_limit": float("nan")}, "'time_limit': expected float"),
        ([], "JSON object"),
    ):
        with pytest.raises(BadMessage, match=named.replace("[", r"\[").replace("]", r"\]")):
            RunTask.from_wire(broken)
    assert RunTask.from_wire({**wire, "time_limit": 2}).time_limit == 2.0  # JSON has one number type


def test_defaults_are_written_once():
    import inspect

    from planbench.bench import suite as suite_module
    from planbench.cli.main import build_parser

    assert inspect.signature(planbench.plan).parameters["time_limit"].default == DEFAULT_TIME_LIMIT
    plan_args = build_parser().parse_args(["plan", "--problem", "x"])
    assert plan_args.time_limit == DEFAULT_TIME_LIMIT
    s = parse_suite('[suite]\nname = "s"\nproblems = ["x"]\n[[planners]]\nplanner = "straight-line"\n')
    task = RunTask("s", "x", "x", "l", "straight-line", 0)
    for name in ("time_limit", "grace", "setup_timeout", "validation_timeout", "memory_limit"):
        default = getattr(suite_module, f"DEFAULT_{name.upper()}")
        assert getattr(s, name) == getattr(task, name) == default, name


def test_settings_with_an_instance_and_a_broken_default_are_named():
    with pytest.raises(InvalidConfigError, match="can only be given with a planner name or class"):
        resolve_planner(KitchenSinkPlanner(), gain=2.0)

    @dataclass(frozen=True)
    class NeedsValue:
        size: float

    class NoDefaults(KitchenSinkPlanner):
        name = "no-defaults"
        Config = NeedsValue

    found = check_planner(NoDefaults)
    expected = "Config() must work with defaults only: planner 'no-defaults'"
    assert any(f.check == "settings" and f.message.startswith(expected) for f in found), found


def _imports(path: Path) -> list[tuple[int, str]]:
    """Every module ``path`` imports, anywhere in it (``from planbench import cli``: ``planbench.cli``)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out += [(node.lineno, node.module)] + [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def test_settings_reads_no_registry_and_the_benchmark_no_command_line():
    """``planbench.settings`` stands below the registries (it imports none: no cycle), and the
    benchmark reads ``--set`` through it, never through ``planbench.cli`` (ast: nothing is imported)."""
    package = Path(planbench.__file__).parent
    assert not [m for _, m in _imports(package / "settings.py") if m.startswith("planbench.registry")]
    bad = [
        f"{path.relative_to(package)}:{line} imports {module}"
        for path in sorted((package / "bench").rglob("*.py"))
        for line, module in _imports(path)
        if module == "planbench.cli" or module.startswith("planbench.cli.")
    ]
    assert not bad, bad
