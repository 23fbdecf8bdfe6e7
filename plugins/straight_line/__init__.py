"""The reference planner: a straight line in joint space from start to goal configuration.

An honest baseline and a smoke test of the harness: it checks the segment for collisions with
coal at the same resolution as the harness and reports ``COLLISION`` when it is blocked, so it
succeeds exactly when the straight line is free. It needs a goal configuration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.metrics import densify
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem


@dataclass(frozen=True)
class StraightLineConfig:
    """Settings of the straight-line planner."""

    timed: bool = True
    """Attach time stamps: the segment at the joint velocity limits (slowest joint at its limit)."""
    check_resolution: float = 0.01
    """Largest joint motion between configurations checked for collision [rad]."""

    def __post_init__(self) -> None:
        if not self.check_resolution > 0:
            raise ValueError(f"check_resolution must be > 0 [rad], got {self.check_resolution}")


class StraightLinePlanner(Planner):
    """Two waypoints: the start and the goal configuration."""

    name = "straight-line"
    Config = StraightLineConfig

    def setup(self, problem: Problem) -> None:
        self._checker = CollisionChecker(problem.robot, problem.scene)

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        goal = problem.goal.q
        if goal is None:
            return PlanResult(PlanStatus.INVALID_GOAL, message="straight-line needs a goal configuration")
        robot = problem.robot
        problems = robot.limit_violations(goal)
        if problems:
            return PlanResult(
                PlanStatus.INVALID_GOAL,
                target="configuration",
                message="goal configuration outside joint limits: " + "; ".join(problems),
            )
        path = np.stack([problem.start, goal])
        checker = getattr(self, "_checker", None) or CollisionChecker(robot, problem.scene)
        states, _ = densify(path, self.config.check_resolution)
        for i, q in enumerate(states):
            if checker.in_collision(q):
                return PlanResult(
                    PlanStatus.COLLISION,
                    target="configuration",
                    message=f"the straight line collides {i / (len(states) - 1):.0%} of the way",
                    info={"collision_checks": i + 1},
                )
        times = None
        if self.config.timed:
            duration = float((np.abs(goal - problem.start) / robot.velocity_limit).max())
            times = np.array([0.0, max(duration, 1e-9)])
        return PlanResult(
            PlanStatus.SUCCESS, path, times, target="configuration", info={"collision_checks": len(states)}
        )
