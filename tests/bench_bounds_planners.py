"""Planners whose paths are costly to validate, for tests/test_validation_bounds.py.

Workers import them by entry point (``"bench_bounds_planners:HugePathPlanner"``); spawned workers
inherit the test process's ``sys.path``, which holds this folder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem


def huge_path(problem: Problem, waypoints: int, shape: str) -> np.ndarray:
    """``"zigzag"``: start, goal, start, goal, ... (every segment the whole motion); ``"still"``:
    the start repeated (no motion, but every waypoint costs memory)."""
    if shape == "still":
        return np.repeat(problem.start[None], waypoints, axis=0)
    goal = problem.goal.q if problem.goal.q is not None else problem.start
    return np.where((np.arange(waypoints) % 2 == 0)[:, None], problem.start, goal)


@dataclass(frozen=True)
class HugePathConfig:
    waypoints: int = 1_000_000
    """Within the wire's limit (planbench.bench.wire.MAX_WAYPOINTS)."""
    shape: str = "zigzag"


class HugePathPlanner(Planner):
    """Returns :func:`huge_path`, claiming success."""

    name = "bench-huge-path"
    Config = HugePathConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        path = huge_path(problem, self.config.waypoints, self.config.shape)
        return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration")
