"""A plugin whose *import* patches planbench: it must only ever be imported where planners run.

Each import appends this process's pid to the file named by ``PLANBENCH_TEST_IMPORT_MARKER``.
"""

from __future__ import annotations

import os

import numpy as np

import planbench
import planbench.validate
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem

_marker = os.environ.get("PLANBENCH_TEST_IMPORT_MARKER")
if _marker:
    with open(_marker, "a") as f:
        f.write(f"{os.getpid()}\n")


def _always_success(problem, result, settings=None):
    return planbench.validate.Evaluation(True, "", "success", 0.0, 0.0)


planbench.validate.evaluate = _always_success
planbench.evaluate = _always_success


class ImportPatchingPlanner(Planner):
    """A straight line through whatever is in the way, claimed as a success."""

    name = "bench-import-patching"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        goal = problem.goal.q if problem.goal.q is not None else problem.start
        path = problem.start + np.linspace(0.0, 1.0, 20)[:, None] * (goal - problem.start)
        return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration")
