"""matrix-field-guided: a global path tracked with the matrix field keeping clearance."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import planbench
from planbench import PlanStatus
from planbench.errors import InvalidConfigError
from planbench_plugins.matrix_field_guided import MatrixFieldGuidedConfig
from planbench_plugins.matrix_field_guided import planner as guided
from planbench_plugins.matrix_field_guided.reference import Reference, departure


def test_the_reference_passes_every_waypoint_at_its_slowest_joints_speed():
    w = np.array([[0.0, 0.0], [1.0, 0.5], [1.0, 2.5]])
    ref = Reference(w, np.array([2.0, 1.0]))
    assert ref.durations.tolist() == [0.5, 2.0] and ref.duration == 2.5
    q, qd, remaining = ref.at(0.25)
    assert np.allclose(q, [0.5, 0.25]) and np.allclose(qd, [2.0, 1.0])
    assert remaining == pytest.approx(np.hypot(0.5, 0.25) + 2.0)
    assert ref.next_time(0.45, 0.1) == 0.5  # a step ends on the corner, not past it
    assert ref.next_time(0.5, 0.1) == pytest.approx(0.6)
    assert np.array_equal(ref.at(9.0)[0], w[-1]) and not ref.at(9.0)[1].any() and ref.at(9.0)[2] == 0.0


def test_departure_is_the_distance_to_the_polyline():
    w = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    points = np.array([[0.5, 0.0], [0.5, 0.3], [1.4, 0.5], [-1.0, 0.0], [1.0, 1.0]])
    assert np.allclose(departure(points, w), [0.0, 0.3, 0.4, 1.0, 0.0])


@pytest.fixture(scope="module")
def table_pick():
    return planbench.load_problems("mbm:table_pick/0002")[0]


def test_without_a_push_the_arm_follows_the_global_path_exactly(table_pick):
    result = planbench.plan(table_pick, "matrix-field-guided", seed=0, repulsion_gain=0.0)
    assert result.status is PlanStatus.SUCCESS and result.info["fallback"] is None
    global_path = np.asarray(result.info["global_path"])
    assert len(result.path) > 5 * len(global_path)  # tracked at dt, not the waypoints
    assert result.info["departure_max"] < 1e-9
    assert np.array_equal(result.path[-1], global_path[-1])
    assert planbench.evaluate(table_pick, result).success


def test_the_global_path_is_ompl_rrtconnects_own_and_the_push_gains_clearance(table_pick):
    alone = planbench.plan(table_pick, "ompl-rrtconnect", seed=0)
    result = planbench.plan(table_pick, "matrix-field-guided", seed=0)
    assert np.array_equal(np.asarray(result.info["global_path"]), alone.path)
    assert result.info["fallback"] is None and result.info["attempts"] == ["free"]
    tracked, bare = planbench.evaluate(table_pick, result), planbench.evaluate(table_pick, alone)
    assert tracked.success and bare.success
    assert tracked.min_clearance > bare.min_clearance + 0.005  # measured: 18 mm against 0.4 mm
    assert 0 < result.info["departure_max"] <= MatrixFieldGuidedConfig().max_lag + 0.05
    assert np.allclose(np.diff(result.times), 0.01)


def test_a_refused_tracked_path_is_tried_again_quieter_then_the_global_path_is_returned(table_pick, monkeypatch):
    real = guided.verdict_checker

    class Refuses:
        def __init__(self, checker):
            self.checker, self.seen = checker, []

        def check_path(self, path):
            self.seen.append(len(path))
            return SimpleNamespace(free=False, segment=len(path) // 2, fraction=0.5)

    refuses = Refuses(real(table_pick))
    monkeypatch.setattr(guided, "verdict_checker", lambda problem: refuses)
    result = planbench.plan(table_pick, "matrix-field-guided", seed=0, retries=2)
    assert result.status is PlanStatus.SUCCESS and result.info["fallback"] == "collision"
    assert result.info["attempts"] == ["collision"] * 3 and len(refuses.seen) == 3
    assert np.array_equal(result.path, np.asarray(result.info["global_path"]))
    assert result.info["quiet"]  # the push was switched off around the refused segment
    assert planbench.evaluate(table_pick, result).success


def test_a_failed_global_plan_is_passed_on_with_its_status():
    problem = planbench.load_problems("mbm:box/0001")[0]
    result = planbench.plan(problem, "matrix-field-guided", seed=0, global_planner="straight-line")
    alone = planbench.plan(problem, "straight-line", seed=0)
    assert alone.status is not PlanStatus.SUCCESS
    assert result.status is alone.status
    assert result.message.startswith("global plan (straight-line): ")
    assert result.info["global_status"] == alone.status.value


def test_settings_are_checked():
    with pytest.raises(InvalidConfigError, match="global_planner"):
        MatrixFieldGuidedConfig(global_planner="matrix-field-guided")
    with pytest.raises(InvalidConfigError, match="tracking_gain"):
        MatrixFieldGuidedConfig(tracking_gain=200.0)
    with pytest.raises(InvalidConfigError, match="retries"):
        MatrixFieldGuidedConfig(retries=-1)
    with pytest.raises(InvalidConfigError, match="global_time_share"):
        MatrixFieldGuidedConfig(global_time_share=0.0)
    with pytest.raises(InvalidConfigError, match="global_settings"):
        MatrixFieldGuidedConfig(global_settings=[1, 2])
    with pytest.raises(planbench.errors.InvalidSettingError, match="rnage"):
        planbench.plan(planbench.load_problems("mbm:box/0001")[0], "matrix-field-guided", global_settings={"rnage": 1})
