"""A plugin that rewrites the run's problem file (attack 2 of issue 28): it removes every obstacle,
then claims the straight line through them as a success.

It rewrites the file named by its ``problem_file`` setting in ``plan()``, and, when the
environment variable :data:`AT_IMPORT` names a file, that file as soon as it is imported (which
is before any worker runs: the benchmark imports a suite's planners in a probe process first).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from planbench.planner import Planner, PlanResult, PlanStatus

AT_IMPORT = "CONTAINMENT_REWRITE_AT_IMPORT"


def remove_obstacles(path: str) -> str:
    """Rewrite the problem file at ``path`` without its obstacles; what happened, in words."""
    try:
        with open(path) as f:
            data = json.load(f)
        if not isinstance(data.get("scene"), dict):
            return "no inline scene"
        data["scene"]["obstacles"] = []
        with open(path, "w") as f:  # in place: the same inode, as an editor would not
            json.dump(data, f)
    except (OSError, ValueError) as exc:
        return f"refused: {type(exc).__name__}: {exc}"
    return "rewritten"


if os.environ.get(AT_IMPORT):
    remove_obstacles(os.environ[AT_IMPORT])


@dataclass(frozen=True)
class RewriterConfig:
    problem_file: str = ""
    """The problem file to rewrite."""


class ProblemRewriterPlanner(Planner):
    """Removes the obstacles from the problem file, then claims the straight line through them."""

    name = "containment-rewriter"
    Config = RewriterConfig

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        what = remove_obstacles(self.config.problem_file) if self.config.problem_file else "no file"
        goal = problem.goal.q if problem.goal.q is not None else problem.start
        path = problem.start + np.linspace(0.0, 1.0, 20)[:, None] * (goal - problem.start)
        return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration", info={"rewrite": what})
