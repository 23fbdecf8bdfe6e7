import time

import numpy as np
import pytest

import planbench
from planbench import PlanResult, PlanStatus
from planbench.conformance import check_planner
from planbench_plugins.straight_line import StraightLinePlanner

# OMPL's PRM* grows its roadmap while a second thread searches it: same seed, possibly another path
# (documented in docs/planners.md). Nothing else may be wrong with it.
NOT_REPRODUCIBLE = {"ompl-prmstar"}


@pytest.mark.parametrize("name", planbench.REGISTRY.names())
def test_every_registered_planner_conforms(name):
    if planbench.REGISTRY.spec(name).distribution != "planbench":
        # an installed third-party plugin: checked in a process of its own, so that one that
        # crashes the interpreter fails its own check, not this test session
        from planbench.cli.check import check_in_subprocess

        outcome = check_in_subprocess(name)
        assert outcome.failure == "" and outcome.findings == []
        return
    problems = check_planner(name)
    if name in NOT_REPRODUCIBLE:
        problems = [p for p in problems if "gave different paths" not in p]
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
    "planner, expected",
    [
        (ClaimsSuccessThroughWalls, "claims success but validation fails: collision"),
        (Broken, "kebab-case"),
        (Unseeded, "different paths"),
        (Raises, "plan raised: planner raised in plan(): RuntimeError: bug"),
    ],
)
def test_deliberately_broken_planners_are_flagged(planner, expected):
    found = check_planner(planner)
    assert any(expected in f for f in found), found


def test_path_not_starting_at_start_is_flagged():
    class Offset(Good):
        name = "offset"

        def plan(self, problem, *, time_limit, rng):
            return PlanResult(PlanStatus.SUCCESS, np.stack([problem.start + 0.1, problem.goal.q]))

    found = check_planner(Offset)
    assert any("path[0] must equal problem.start" in f for f in found), found


@pytest.mark.slow
def test_overrunning_the_time_limit_is_flagged():
    found = check_planner(Slow, time_limit=0.05)
    assert any("with a time limit of 0.05 s" in f for f in found), found
