"""Certified collision checking of control ticks against obstacles that move.

During a tick ``[t0, t1]`` the arm moves on the straight joint-space segment ``q0 -> q1`` (constant
joint velocity) while each moving obstacle follows its motion. The static certified checker
(:mod:`planbench.checking.certified`) proves a segment free against fixed geometry; a moving obstacle is
reduced to that case by a bound on its motion:

- Every point of obstacle ``i`` moves at most ``v_i`` [m/s] (:meth:`Motion.speed_bound`), so over
  the tick it stays within ``v_i (t1 - t0) / 2`` of where it is at the tick's middle ``tm``.
- Place the obstacle at its pose at ``tm`` and require that pair's distance to be at least that
  margin along the whole segment (:attr:`CertifiedChecker.pair_margin`): then at any time of the
  tick the true distance is at least the certified one minus the margin, at least zero.
- The test compares any configuration of the segment with any time of the tick, so it is
  conservative. When it fails on a moving obstacle, the tick is split in two halves in time (the
  arm at the middle configuration), each with half the margin, down to ``max_splits`` levels; a
  pair still not certified there is reported as a collision. The margin at the last level is
  ``v (t1 - t0) / 2**(max_splits + 1)``: for 1 m/s and a 10 ms tick, 10 micrometres.

An obstacle present at any moment of the tick (``appear`` / ``disappear``) counts for the whole
tick; one absent during the whole tick is moved far away. Static obstacles, self-collision and
the robot's geometry are exactly those of the static checker.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pinocchio as pin

from planbench.checking.certified import CertificationSettings, CertifiedChecker, PathVerdict
from planbench.reactive.scenario import Scenario
from planbench.scene import Scene

__all__ = ["TickChecker"]

_FAR = np.array([1.0e4, 1.0e4, 1.0e4])  # where an absent obstacle waits [m]


class TickChecker:
    """Certifies ticks of a closed-loop run against a scenario's true, moving geometry."""

    def __init__(self, scenario: Scenario, max_splits: int = 8, settings: CertificationSettings | None = None) -> None:
        self.scenario = scenario
        self.max_splits = int(max_splits)
        cfg = settings or CertificationSettings()
        self.settings = replace(cfg, measure_clearance=False)
        problem = scenario.problem
        rest = Scene(tuple(problem.scene.obstacles) + tuple(m.obstacle for m in scenario.moving), problem.scene.name)
        self.checker = CertifiedChecker(problem.robot, rest, self.settings)
        self._speeds = [m.speed_bound() for m in scenario.moving]
        self._pairs_of = [self.checker.pairs_with(m.name) for m in scenario.moving]  # pair indices per moving obstacle
        self._moving_pair = {f"obstacle:{m.name}" for m in scenario.moving}

    def place(self, t0: float, t1: float | None = None) -> None:
        """Put every moving obstacle at its pose at the middle of ``[t0, t1]`` with the margin of
        half its travel (``t1`` omitted: at ``t0``, no margin); absent ones far away."""
        t1 = t0 if t1 is None else t1
        tm, half = 0.5 * (t0 + t1), 0.5 * (t1 - t0)
        checker = self.checker
        margins = checker.pair_margin
        for m, speed, pairs in zip(self.scenario.moving, self._speeds, self._pairs_of, strict=True):
            if m.present(t0, t1):
                M = m.motion.pose(m.obstacle.placement(), tm)
                margin = speed * half
            else:
                M, margin = pin.SE3(np.eye(3), _FAR), 0.0
            checker.place_obstacle(m.name, M)
            for k in pairs:
                margins[k] = margin

    def check_tick(self, q0: np.ndarray, q1: np.ndarray, t0: float, t1: float) -> PathVerdict:
        """Certify the arm moving ``q0 -> q1`` during ``[t0, t1]`` [s] (module docstring)."""
        return self._check(np.asarray(q0, dtype=float), np.asarray(q1, dtype=float), t0, t1, 0)

    def _check(self, q0: np.ndarray, q1: np.ndarray, t0: float, t1: float, level: int) -> PathVerdict:
        self.place(t0, t1)
        verdict = self.checker.check_segment(q0, q1)
        if verdict.free or level >= self.max_splits or not (self._moving_pair & set(verdict.pair)):
            return verdict
        tm, qm = 0.5 * (t0 + t1), 0.5 * (q0 + q1)
        first = self._check(q0, qm, t0, tm, level + 1)
        if not first.free:
            return replace(first, fraction=0.5 * first.fraction)
        second = self._check(qm, q1, tm, t1, level + 1)
        return second if second.free else replace(second, fraction=0.5 + 0.5 * second.fraction)

    def clearance(self, q: np.ndarray, t: float) -> float:
        """Smallest distance [m] between the arm at ``q`` and the obstacles present at ``t`` [s]
        (negative when penetrating; ``inf`` without obstacles)."""
        self.place(t)
        d = self.checker.clearance(np.asarray(q, dtype=float))
        return d if d < 1.0e3 else math.inf  # only the parked absent obstacles were left
