"""The reference planner: a straight line in joint space from start to goal configuration.

An honest baseline and a smoke test of the harness: it succeeds exactly when the straight segment
is collision-free (the harness's validation decides that, not this planner), and it needs a goal
configuration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planbench.planner import PlanResult, PlanStatus, Planner
from planbench.problem import Problem


@dataclass(frozen=True)
class StraightLineConfig:
    """Settings of the straight-line planner."""

    timed: bool = True
    """Attach time stamps: the segment at the joint velocity limits (slowest joint at its limit)."""


class StraightLinePlanner(Planner):
    """Two waypoints: the start and the goal configuration."""

    name = "straight-line"
    Config = StraightLineConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        goal = problem.goal.q
        if goal is None:
            return PlanResult(PlanStatus.INVALID_GOAL, message="straight-line needs a goal configuration")
        robot = problem.robot
        problems = robot.limit_violations(goal)
        if problems:
            return PlanResult(PlanStatus.INVALID_GOAL, target="configuration",
                              message="goal configuration outside joint limits: " + "; ".join(problems))
        path = np.stack([problem.start, goal])
        times = None
        if self.config.timed:
            duration = float((np.abs(goal - problem.start) / robot.velocity_limit).max())
            times = np.array([0.0, max(duration, 1e-9)])
        return PlanResult(PlanStatus.SUCCESS, path, times, target="configuration")
