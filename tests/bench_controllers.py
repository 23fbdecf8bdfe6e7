"""Controllers for the closed-loop benchmark's tests; workers import them by entry point
(``"bench_controllers:ToGoalController"``)."""

from __future__ import annotations

import numpy as np

from planbench.reactive.controller import Controller


class ToGoalController(Controller):
    """Joint-space proportional control toward the goal configuration (sees no obstacle)."""

    name = "bench-to-goal"

    def setup(self, task):
        self.goal_q = np.asarray(task.goal.q)

    def step(self, t, q, observation, goal):
        return 2.0 * (self.goal_q - q)


class RaisingController(ToGoalController):
    """Raises on its 3rd tick: an error row that keeps the trajectory run so far."""

    name = "bench-raising-controller"

    def reset(self, q, rng):
        self.ticks = 0

    def step(self, t, q, observation, goal):
        self.ticks += 1
        if self.ticks == 3:
            raise RuntimeError("bench-raising controller fails on purpose")
        return super().step(t, q, observation, goal)
