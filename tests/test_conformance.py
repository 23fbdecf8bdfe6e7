import importlib.util
import time

import numpy as np
import pytest

import planbench
from planbench import PlanResult, PlanStatus
from planbench.conformance import CHECKS, ConformanceReport, Finding, check_planner, planner_report
from planbench_plugins.straight_line import StraightLinePlanner

# OMPL's PRM* grows its roadmap while a second thread searches it: same seed, possibly another path
# (documented in docs/planners.md). Nothing else may be wrong with it.
NOT_REPRODUCIBLE = {"ompl-prmstar"}
# vamp-rrtc hands back VAMP's own path uncertified, so that a benchmark counts the VAMP paths that
# planbench refuses (docs/planners.md, "VAMP"): a false success is what it is there to show.
UNCERTIFIED = {"vamp-rrtc"}
# planners of an optional extra: the module each needs (not installed: the test is skipped, saying so)
OPTIONAL = {"vamp-rrtc": "vamp"}


@pytest.mark.parametrize("name", planbench.REGISTRY.names())
def test_every_registered_planner_conforms(name):
    if name in OPTIONAL and importlib.util.find_spec(OPTIONAL[name]) is None:
        pytest.skip(f"{name} needs the optional module {OPTIONAL[name]!r}, not installed (planbench[vamp])")
    if planbench.REGISTRY.spec(name).distribution != "planbench":
        # an installed third-party plugin: checked in a process of its own, so that one that
        # crashes the interpreter fails its own check, not this test session
        from planbench.cli.check import check_in_subprocess

        outcome = check_in_subprocess(name)
        assert outcome.failure == "" and outcome.findings == []
        return
    problems = check_planner(name)
    if name in NOT_REPRODUCIBLE:
        problems = [p for p in problems if p.check != "non-deterministic"]
    if name in UNCERTIFIED:
        problems = [p for p in problems if p.check != "false-success"]
    assert problems == []


class Good(StraightLinePlanner):
    name = "good"


class ClaimsSuccessThroughWalls(Good):
    name = "through-walls"

    def plan(self, problem, *, time_limit, rng):
        # never checks for collisions, so also claims success on the problem with an obstacle
        return PlanResult(PlanStatus.SUCCESS, np.stack([problem.start, problem.goal.q]), target="configuration")


class Broken(planbench.Planner):
    name = "Broken_Name"

    def plan(self, problem, *, time_limit, rng):
        return PlanResult(PlanStatus.SUCCESS, np.stack([problem.start + 0.1, problem.goal.q]))


class Unseeded(Good):
    name = "unseeded"

    def plan(self, problem, *, time_limit, rng):
        noise = np.random.default_rng().normal(size=problem.robot.nq) * 1e-3
        return PlanResult(PlanStatus.TIMEOUT, np.stack([problem.start, problem.start + noise]))


class Raises(Good):
    name = "raises"

    def plan(self, problem, *, time_limit, rng):
        raise RuntimeError("bug")


class Slow(Good):
    name = "slow"

    def plan(self, problem, *, time_limit, rng):
        time.sleep(time_limit * 2 + 0.6)
        return PlanResult(PlanStatus.TIMEOUT)


def test_a_correct_planner_has_no_problems():
    assert check_planner(Good) == []


@pytest.mark.parametrize(
    "planner, check, expected",
    [
        (ClaimsSuccessThroughWalls, "false-success", "claims success but validation fails: collision"),
        (Broken, "interface", "kebab-case"),
        (Unseeded, "non-deterministic", "different paths"),
        (Raises, "raises", "plan raised: planner raised in plan(): RuntimeError: bug"),
    ],
)
def test_deliberately_broken_planners_are_flagged_under_the_check_s_name(planner, check, expected):
    found = check_planner(planner)
    assert any(f.check == check and expected in f.message for f in found), found
    assert all(f.check in CHECKS for f in found) and str(found[0]).startswith(f"{found[0].check}: ")


class CutByTheClock(Good):
    """Deterministic steps along the straight line, as many as its (here: simulated) clock allowed."""

    name = "cut-by-the-clock"

    def plan(self, problem, *, time_limit, rng):
        steps = int(np.random.default_rng().integers(2, 50))  # how far a loaded machine let it get
        s = np.linspace(0.0, 1.0, 60)[:steps, None]
        return PlanResult(PlanStatus.TIMEOUT, problem.start + s * (problem.goal.q - problem.start))


def test_runs_cut_by_the_time_limit_are_compared_up_to_the_shorter_one():
    """A deterministic planner cut at different points by a loaded machine is not "unseeded"; one
    whose cut paths disagree before either ends is (``Unseeded`` above, also cut by the clock)."""
    assert not [f for f in check_planner(CutByTheClock) if f.check == "non-deterministic"]
    assert [f for f in check_planner(Unseeded) if f.check == "non-deterministic"]


def test_path_not_starting_at_start_is_flagged():
    class Offset(Good):
        name = "offset"

        def plan(self, problem, *, time_limit, rng):
            return PlanResult(PlanStatus.SUCCESS, np.stack([problem.start + 0.1, problem.goal.q]))

    found = check_planner(Offset)
    assert any(f.check == "wrong-start" and "path[0] must equal problem.start" in f.message for f in found), found


@pytest.mark.slow
def test_overrunning_the_time_limit_is_flagged():
    found = check_planner(Slow, time_limit=0.05)
    assert any(f.check == "time-limit" and "with a time limit of 0.05 s" in f.message for f in found), found


def test_the_report_says_which_named_checks_passed_failed_or_did_not_run():
    good = planner_report(Good)
    assert good.conformant and good.checks == tuple(CHECKS) and good.with_status("passed") == list(CHECKS)
    assert good.lines() == [f"passed: {', '.join(CHECKS)}"]

    raises = planner_report(Raises)  # plan raises on every problem: nothing after the call is looked at
    assert raises.with_status("failed") == ["raises"]
    assert raises.with_status("passed") == ["interface", "settings"]
    assert raises.with_status("not run") == [c for c in CHECKS if c not in ("interface", "settings", "raises")]
    assert raises.lines()[0] == "failed: raises"
    assert raises.lines()[1].startswith("  - raises: on conformance:trivial: plan raised")

    broken = planner_report(Broken)  # a bad interface: the planner is not run
    assert broken.status("interface") == "failed" and broken.status("non-deterministic") == "not run"

    class NoPlan:
        name = "no-plan"
        Config = Good.Config

    no_plan = planner_report(NoPlan)
    assert [f.check for f in no_plan.findings] == ["interface", "interface"]  # no setup(), no plan()
    assert no_plan.with_status("not run") == [c for c in CHECKS if c not in ("interface", "settings")]
    given = planner_report(Good, config=Good.Config(), problems=[planbench.load_problems("mbm:box/0001")[0]])
    assert given.with_status("not run") == ["settings", "trivial-unsolved"] and given.conformant


def test_a_report_crosses_processes_as_checked_plain_data():
    report = ConformanceReport(("a", "b", "c"), (Finding("a", "x" * 5000),), frozenset({"c"}))
    back = ConformanceReport.from_data(report.to_data())
    assert back.checks == report.checks and back.not_run == report.not_run
    assert back.findings == (Finding("a", "x" * 2000),)
    for bad in ({}, {"checks": "a", "findings": [], "not_run": []}, {"checks": [], "findings": [["a"]], "not_run": []}):
        with pytest.raises(TypeError):
            ConformanceReport.from_data(bad)


def test_the_checkers_take_settings_as_a_mapping_and_name_a_refused_one():
    """A mapping of settings is checked and built as a suite's are: a refused one is a ``settings``
    finding naming it (not an error raised from the planner's own code), an accepted one is run."""
    from planbench.reactive.conformance import check_controller

    [found] = check_controller("ompl-replan", {"evade": "flee"})
    assert found.check == "settings" and "evade" in found.message and "retreat" in found.message
    [found] = check_planner("straight-line", {"nope": 1})
    assert found.check == "settings" and "nope" in found.message and "check_resolution" in found.message
    assert check_planner("straight-line", {"check_resolution": 0.02}) == []
