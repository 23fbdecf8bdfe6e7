"""Path metrics with exact definitions: durations with and without acceleration limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

import planbench
from planbench.metrics import execution_duration, limited_duration


@pytest.mark.parametrize("length, v, a", [(2.0, 1.0, 2.0), (0.2, 1.0, 2.0), (1.0, 0.5, 10.0)])
def test_a_straight_move_takes_the_bang_bang_time_under_acceleration_limits(length, v, a):
    """One joint moving ``length`` [rad] from rest to rest: accelerate, cruise at ``v`` if it gets
    there, decelerate; ``L/v + v/a`` when ``L >= v^2/a``, else ``2 sqrt(L/a)``."""
    path = np.zeros((11, 2))
    path[:, 0] = np.linspace(0.0, length, 11)  # waypoints along a straight line (another joint still)
    vmax, amax = np.array([v, 3.0]), np.array([a, 3.0])
    exact = length / v + v / a if length >= v * v / a else 2 * math.sqrt(length / a)
    assert limited_duration(path, vmax, amax) == pytest.approx(exact, rel=0.03)
    assert limited_duration(path, vmax, amax) > execution_duration(path, vmax) == pytest.approx(length / v)


def test_no_acceleration_limit_no_figure_and_a_still_path_takes_no_time():
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert math.isnan(limited_duration(path, np.ones(2), np.array([1.0, np.nan])))
    assert limited_duration(np.zeros((5, 2)), np.ones(2), np.ones(2)) == 0.0


def test_every_validated_plan_reports_both_durations():
    problem = planbench.load_problems("mbm:table_pick/0001")[0]
    e = planbench.evaluate(problem, planbench.plan(problem, "straight-line"))
    assert e.success and 0 < e.duration < e.duration_limited < 10 * e.duration
