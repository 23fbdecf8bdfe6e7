"""Suite files: the format, the built-in suites, and errors that name the file and the problem."""

import json

import pytest

from planbench.bench.benchmark import select
from planbench.bench.suite import SuiteFileError, builtin_suites, expand_problems, load_suite, parse_seeds, parse_suite
from planbench.errors import UnknownNameError

GOOD = """
[suite]
name = "two-labels"
problems = ["mbm:box/0001-0002", "mbm:cage/0003"]
seeds = 3
time_limit = 2.5

[validation]
required_clearance = 0.002

[[planners]]
planner = "straight-line"

[[planners]]
label = "sl-untimed"
planner = "straight-line"
settings = { timed = false }
"""


def test_parse_a_suite_with_the_same_planner_under_two_labels():
    s = parse_suite(GOOD, "good.toml")
    assert s.name == "two-labels"
    assert s.seeds == (0, 1, 2)
    assert s.time_limit == 2.5
    assert s.validation == {"required_clearance": 0.002}
    assert [(p.label, p.planner, p.settings) for p in s.planners] == [
        ("straight-line", "straight-line", {}),
        ("sl-untimed", "straight-line", {"timed": False}),
    ]
    assert [r.id for r in expand_problems(s.problems)] == ["mbm:box/0001", "mbm:box/0002", "mbm:cage/0003"]
    assert {r.family for r in expand_problems(s.problems)} == {"box", "cage"}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[suite\nname=", "not valid TOML"),
        (
            '[suite]\nname = "x"\nproblems = ["mbm:box/0001"]\nspeed = 3\n[[planners]]\nplanner = "a"',
            "unknown key(s) ['speed']",
        ),
        ('[suite]\nname = "x"\nproblems = ["mbm:box/0001"]\n', "no [[planners]]"),
        ('[suite]\nname = "x"\nproblems = []\n[[planners]]\nplanner = "a"', "problems is empty"),
        ('[suite]\nname = "x"\nproblems = ["m"]\ntime_limit = -1\n[[planners]]\nplanner = "a"', "time_limit must be"),
        ('[suite]\nname = "x"\nproblems = ["m"]\nseeds = [1, 1]\n[[planners]]\nplanner = "a"', "repeat"),
        (
            '[suite]\nname = "x"\nproblems = ["m"]\n[[planners]]\nplanner = "a"\n[[planners]]\nplanner = "a"',
            "more than once",
        ),
        ('[suite]\nname = "x"\nproblems = ["m"]\n[[planners]]\nlabel = "b"', "needs planner"),
        (
            '[suite]\nname = "x"\nproblems = ["m"]\n[validation]\nresolution = 1\n[[planners]]\nplanner = "a"',
            "[validation]",
        ),
        ('[suites]\nname = "x"', "unknown table"),
    ],
)
def test_bad_suite_files_name_the_file_and_the_problem(text, expected):
    with pytest.raises(SuiteFileError) as err:
        parse_suite(text, "my_suite.toml")
    assert str(err.value).startswith("my_suite.toml: ")
    assert expected in str(err.value)


def test_load_suite_by_file_and_unknown_names(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text(GOOD)
    assert load_suite(f).source == str(f)
    with pytest.raises(UnknownNameError, match="smoke"):
        load_suite("smoek")
    with pytest.raises(SuiteFileError, match="no such file"):
        load_suite(tmp_path / "missing.toml")


def test_builtin_suites():
    assert {"smoke", "mbm"} <= set(builtin_suites())
    smoke = load_suite("smoke")
    assert [p.planner for p in smoke.planners] == ["straight-line", "matrix-field"]
    refs = expand_problems(smoke.problems)
    assert len(refs) == 14 and len({r.family for r in refs}) == 7
    assert len(expand_problems(load_suite("mbm").problems)) == 700


def test_seeds_and_command_line_selection():
    assert parse_seeds("3") == (0, 1, 2)
    assert parse_seeds("0,5,7") == (0, 5, 7)
    assert parse_seeds("2-4") == (2, 3, 4)
    assert parse_seeds([4]) == (4,)
    with pytest.raises(SuiteFileError):
        parse_seeds("x")
    s = select(parse_suite(GOOD), planners=["sl-untimed", "bench_planners:NoisyPlanner"], seeds="1", time_limit=1.0)
    assert [(p.label, p.planner) for p in s.planners] == [
        ("sl-untimed", "straight-line"),
        ("NoisyPlanner", "bench_planners:NoisyPlanner"),
    ]
    assert s.seeds == (0,) and s.time_limit == 1.0


def test_seeds_fit_numpy_and_sqlite():
    assert parse_seeds(f"{2**63 - 2}-{2**63 - 1}") == (2**63 - 2, 2**63 - 1)
    for bad in ("99999999999999999999", f"0,{2**63}", f"0-{2**63}", "9-3", [-1], [2**64]):
        with pytest.raises(SuiteFileError, match="seed"):
            parse_seeds(bad)


MEMORY = """
[suite]
name = "m"
problems = ["mbm:box/0001"]
{line}

[[planners]]
planner = "straight-line"
"""


def test_memory_limit_has_a_default_and_can_be_set_or_disabled():
    from planbench.bench.suite import DEFAULT_MEMORY_LIMIT, parse_memory_limit

    assert DEFAULT_MEMORY_LIMIT >= 2048  # far above the ~0.8 GiB address space the shipped planners reach
    assert parse_suite(MEMORY.format(line="")).memory_limit == DEFAULT_MEMORY_LIMIT
    assert parse_suite(MEMORY.format(line="memory_limit = 2000")).memory_limit == 2000
    assert parse_suite(MEMORY.format(line='memory_limit = "none"')).memory_limit == 0
    assert parse_suite(MEMORY.format(line="memory_limit = 0")).memory_limit == 0
    for bad in ("-1", '"lots"', "nan", "true"):
        with pytest.raises(SuiteFileError, match=r"m\.toml: \[suite\] memory_limit"):
            parse_suite(MEMORY.format(line=f"memory_limit = {bad}"), "m.toml")
    assert parse_memory_limit("none") == 0 and parse_memory_limit("512") == 512
    assert "memory_limit" in load_suite("smoke").settings_json()


def test_bench_memory_limit_option_reaches_the_suite():
    import argparse

    from planbench.cli.bench import add_commands

    parser = argparse.ArgumentParser()
    add_commands(parser.add_subparsers(dest="command"))
    from planbench.cli.bench import _bench_suite

    for given, expected in (("none", 0.0), ("1500", 1500.0)):
        args = parser.parse_args(["bench", "--problems", "mbm:box/0001", "--memory-limit", given])
        assert _bench_suite(args).memory_limit == expected
    args = parser.parse_args(["bench", "--problems", "mbm:box/0001"])
    assert _bench_suite(args).memory_limit == load_suite("smoke").memory_limit


def test_settings_name_the_validator_so_older_verdicts_are_never_resumed_into():
    from planbench.validate import VALIDATOR

    assert json.loads(load_suite("smoke").settings_json())["validator"] == VALIDATOR


def test_a_suite_finds_its_problem_files_next_to_itself(tmp_path, monkeypatch):
    import planbench
    from planbench.bench.suite import expand_problems, load_suite

    lab = tmp_path / "lab"
    (lab / "problems").mkdir(parents=True)
    planbench.load_problems("mbm:box/0001")[0].save(lab / "problems" / "p.json")
    (lab / "s.toml").write_text(
        '[suite]\nname = "rel"\nproblems = ["problems/", "mbm:box/0002"]\n[[planners]]\nplanner = "straight-line"\n'
    )
    monkeypatch.chdir(tmp_path)  # planbench runs elsewhere than the suite lives
    suite = load_suite(lab / "s.toml")
    assert suite.problems == (str((lab / "problems").resolve()), "mbm:box/0002")
    refs = expand_problems(suite.problems)
    assert [r.id for r in refs] == ["mbm:box/0001", "mbm:box/0002"]
