"""Planners that misbehave on purpose, for the benchmark's isolation tests.

Workers import them by entry point (``"bench_planners:RaisingPlanner"``); the tests put this
folder on the workers' ``PYTHONPATH``.
"""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass

import numpy as np

from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem


class RaisingPlanner(Planner):
    """Raises in plan(): recorded as ERROR with its traceback."""

    name = "bench-raising"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        raise RuntimeError("bench-raising planner fails on purpose")


class SleepingPlanner(Planner):
    """Ignores its time limit: killed by the runner, recorded as TIMEOUT."""

    name = "bench-sleeping"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        time.sleep(3600)
        return PlanResult(PlanStatus.TIMEOUT)


class SuicidePlanner(Planner):
    """Kills its own process with SIGKILL: recorded as CRASH."""

    name = "bench-suicide"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        os.kill(os.getpid(), signal.SIGKILL)
        return PlanResult(PlanStatus.ERROR)


class ExitPlanner(Planner):
    """Leaves the interpreter with os._exit(3) after printing to stderr: recorded as CRASH."""

    name = "bench-exit"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        os.write(2, b"bench-exit planner says goodbye\n")
        os._exit(3)


@dataclass(frozen=True)
class NoisyConfig:
    scale: float = 0.05
    """Size of the random detour [rad]."""
    delay: float = 0.0
    """Time to sleep before answering [s] (to make a benchmark last long enough to kill it)."""


class NoisyPlanner(Planner):
    """A straight line with random intermediate waypoints drawn from the run's rng, so paths
    differ per seed and are reproducible only if the seed reaches the planner."""

    name = "bench-noisy"
    Config = NoisyConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        time.sleep(self.config.delay)
        goal = problem.goal.q if problem.goal.q is not None else problem.start
        s = np.linspace(0.0, 1.0, 6)[:, None]
        path = problem.start + s * (goal - problem.start)
        path[1:-1] += rng.normal(scale=self.config.scale, size=path[1:-1].shape)
        return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration")
