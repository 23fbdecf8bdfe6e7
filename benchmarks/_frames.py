"""What the sensing benchmarks share: one scene in motion, and the median time of a step.

``mbm:box/0001`` plus a ball of radius 5 cm crossing it at 0.6 m height, the Panda moving from
its start toward its goal configuration; frame ``k`` of ``n`` puts both ``k / n`` of the way.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

import planbench
from planbench.scene import Obstacle, Scene

__all__ = ["MovingScene", "median_ms"]


def median_ms(frames: int, body: Callable[[int], object]) -> float:
    """Median wall time [ms] of ``body(k)`` for k = 1..frames, after an untimed ``body(0)`` (the
    warm-up: compilation, caches, first allocation)."""
    body(0)
    times = []
    for k in range(1, frames + 1):
        t0 = time.perf_counter()
        body(k)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


class MovingScene:
    """The scene and the arm at frame ``k`` of ``n`` (module docstring)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.problem = planbench.load_problems("mbm:box/0001")[0]
        self.robot = self.problem.robot
        self.start = np.asarray(self.problem.start)
        goal = self.problem.goal.q
        self.goal = np.asarray(goal) if goal is not None else self.start

    def scene(self, k: int) -> Scene:
        ball = Obstacle("ball", "sphere", position=(0.6, -0.4 + 0.8 * k / self.n, 0.6), radius=0.05)
        return self.problem.scene.with_obstacles([ball])

    def q(self, k: int) -> np.ndarray:
        return self.start + (self.goal - self.start) * k / self.n
