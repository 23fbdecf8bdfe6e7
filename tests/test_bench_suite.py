"""Suite files: the format, the built-in suites, and errors that name the file and the problem."""

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
collision_resolution = 0.02

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
    assert s.validation == {"collision_resolution": 0.02}
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
