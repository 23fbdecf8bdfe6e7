"""Leaving local minima (plugins/ik_loop/escape.py): bounded random escapes in the shared loop."""

from __future__ import annotations

import numpy as np
import pytest

import planbench
from planbench import PlanStatus
from planbench.errors import InvalidConfigError
from planbench_plugins.ik_loop.escape import escape_motion
from planbench_plugins.matrix_field import MatrixFieldConfig


def test_an_escape_moves_at_the_velocity_limits_to_a_free_configuration():
    q = np.zeros(3)
    lower, upper, qd_max = -np.ones(3), np.ones(3), np.array([1.0, 2.0, 4.0])
    segments = []

    def in_collision(c):
        return bool(c[0] > 0)  # half the space is blocked: the first draws may land there

    def segment_free(a, b):
        segments.append((a.copy(), b.copy()))
        return bool(b[1] < 0)  # and half the motions

    rng = np.random.default_rng(3)
    motion, draws, toward = escape_motion(q, rng, in_collision, segment_free, lower, upper, qd_max, 0.01, 0.5, 50)
    assert motion is not None and draws >= 2 and not toward
    target = motion[-1]
    assert target[0] <= 0 and target[1] < 0 and np.all(target >= lower) and np.all(target <= upper)
    assert np.array_equal(segments[-1][0], q) and np.array_equal(segments[-1][1], target)  # its motion, checked
    steps = np.diff(np.vstack((q, motion)), axis=0)
    assert np.all(np.abs(steps) <= qd_max * 0.01 + 1e-12)  # within the velocity limits
    assert np.allclose(steps, steps[0])  # a straight line at constant speed


def test_an_escape_gives_up_after_its_draws():
    blocked = (lambda c: True, lambda a, b: True)
    motion, draws, _ = escape_motion(
        np.zeros(2), np.random.default_rng(0), *blocked, -np.ones(2), np.ones(2), np.ones(2), 0.01, 0.5, 7
    )
    assert motion is None and draws == 7


def test_every_other_draw_heads_part_of_the_way_to_the_goal_configuration():
    q, goal = np.zeros(3), np.array([0.8, -0.4, 0.2])
    limits = (-np.ones(3), np.ones(3), np.ones(3))
    free = (lambda c: False, lambda a, b: True)
    rng = np.random.default_rng(0)
    motion, draws, toward = escape_motion(q, rng, *free, *limits, 0.01, 1e-9, 5, goal=goal, toward_goal=True)
    assert draws == 1 and toward  # the first draw: towards the goal
    u = motion[-1] @ goal / (goal @ goal)
    assert 0.2 <= u <= 1.0 and np.allclose(motion[-1], u * goal, atol=1e-6)
    # refused, the second draw is a detour around the arm's own configuration
    seen = []
    motion, draws, toward = escape_motion(
        q,
        rng,
        lambda c: seen.append(c.copy()) or len(seen) == 1,
        free[1],
        *limits,
        0.01,
        1e-9,
        5,
        goal=goal,
        toward_goal=True,
    )
    assert draws == 2 and not toward and np.allclose(motion[-1], q, atol=1e-6)
    motion, _, toward = escape_motion(q, rng, *free, *limits, 0.01, 1e-9, 5, goal=goal, toward_goal=False)
    assert not toward and np.allclose(motion[-1], q, atol=1e-6)


@pytest.mark.parametrize(
    ("problem_id", "ended"),
    [("mbm:bookshelf_small/0008", PlanStatus.LOCAL_MINIMUM), ("mbm:table_under_pick/0011", PlanStatus.COLLISION)],
)
def test_escapes_turn_a_stall_or_a_collision_into_a_validated_path(problem_id, ended):
    problem = planbench.load_problems(problem_id)[0]
    plain = planbench.plan(problem, "matrix-field", seed=0, escape_attempts=0)
    assert plain.status is ended and plain.info["escapes"] == 0
    result = planbench.plan(problem, "matrix-field", seed=0)  # the defaults escape
    verdict = planbench.evaluate(problem, result)
    assert verdict.success, verdict.failure
    assert 1 <= result.info["escapes"] <= MatrixFieldConfig().escape_attempts
    assert len(result.info["escape_after"]) == len(result.info["escape_steps"]) == result.info["escapes"]
    assert set(result.info["escape_after"]) <= {"local_minimum", "collision"}
    assert verdict.max_velocity_ratio <= 1.0 + 1e-9  # escapes move within the velocity limits
    again = planbench.plan(problem, "matrix-field", seed=0)
    assert np.array_equal(again.path, result.path)  # the query's rng: reproducible
    if ended is PlanStatus.COLLISION:
        assert "collision" in result.info["escape_after"]


def test_escape_settings_are_checked():
    for bad in ({"escape_attempts": -1}, {"escape_attempts": 1.5}, {"escape_draws": 0}, {"escape_radius": 0.0}):
        with pytest.raises(InvalidConfigError, match=next(iter(bad))):
            MatrixFieldConfig(**bad)


def test_the_qp_variant_escapes_only_to_where_its_constraints_hold():
    """matrix-field-qp keeps pairs ``collision_safety`` apart on convex hulls; an escape target
    free on the meshes but closer on the hulls would start its next step in violation (measured:
    a UR5 step that grazed its own wrist from such a target), so it is refused."""
    problem = planbench.load_problems("mbm:box/0001")[0]
    planner = planbench.make_planner("matrix-field-qp")
    planner.setup(problem)
    q = np.array(problem.start)
    gap = float(planner.distances.near_at(q).distance.min())
    assert 0.003 < gap < 0.1
    assert planner.escape_target_ok(q)
    strict = planbench.make_planner("matrix-field-qp", collision_safety=gap + 0.001)
    strict.setup(problem)
    assert not strict.escape_target_ok(q)
    assert planbench.make_planner("matrix-field").escape_target_ok(q)  # the field planners: any free target


def test_draws_cycle_through_the_radii_in_pairs():
    # scales=2: draws 1-2 at the full radius, 3-4 at half of it, 5-6 at the full radius again...
    q = np.zeros(6)
    limits = (-1e3 * np.ones(6), 1e3 * np.ones(6), np.ones(6))
    seen: list[np.ndarray] = []
    blocked = (lambda c: seen.append(c.copy()) or True, lambda a, b: True)
    escape_motion(q, np.random.default_rng(0), *blocked, *limits, 0.01, 1.0, 4000, scales=2)
    spread = np.array([np.std(np.array(seen[i::4])) for i in range(4)])
    assert np.allclose(spread, [1.0, 1.0, 0.5, 0.5], rtol=0.05)
    # scales=1 draws exactly what the escape drew before radii could cycle
    one, before = [], []
    escape_motion(
        q, np.random.default_rng(1), lambda c: one.append(c.copy()) or True, lambda a, b: True, *limits, 0.01, 0.7, 9
    )
    rng = np.random.default_rng(1)
    before = [np.clip(q + rng.normal(0.0, 0.7, size=6), limits[0], limits[1]) for _ in range(9)]
    assert np.array_equal(np.array(one), np.array(before))


def test_an_escape_without_a_target_rewinds_further_along_the_path():
    """``escape_backtrack``: where no target is found, the loop rewinds ``escape_backtrack_window``
    further back, then twice as far each time, and tries again from there; the path is cut at the
    configuration the escape left from, so the trajectory stays continuous."""
    from planbench_plugins.matrix_field import MatrixFieldPlanner

    class Refusing(MatrixFieldPlanner):
        """Finds no escape target before its ``refusals``-th try (records where each try started)."""

        def __init__(self, refusals: int, **settings):
            super().__init__(**settings)
            self.refusals, self.tries = refusals, []

        def _escape(self, q, rng, checker, inputs, path, diag, k, n_max):
            self.tries.append((k, q.copy()))
            if len(self.tries) <= self.refusals:
                return 0, False
            return super()._escape(q, rng, checker, inputs, path, diag, k, n_max)

    problem = planbench.load_problems("mbm:table_under_pick/0011")[0]
    plain = Refusing(refusals=10**6, escape_backtrack=0)  # as before issue 32
    ended = planbench.plan(problem, plain, seed=0)
    assert ended.status is PlanStatus.COLLISION and ended.info["escapes"] == 0 and len(plain.tries) == 1
    frm = plain.tries[0][0]
    assert frm >= 40  # the first collision is late enough for three rewinds (table_under_pick: link 5)
    wedged = Refusing(refusals=10**6, escape_backtrack=3, escape_backtrack_window=0.1)
    planbench.plan(problem, wedged, seed=0)
    assert [k for k, _ in wedged.tries] == [frm, frm - 10, frm - 20, frm - 40]  # 0.1, 0.2, 0.4 s back
    for k, q in wedged.tries:
        assert np.array_equal(q, ended.path[k])  # each try starts on the path as planned
    far = Refusing(refusals=10**6, escape_backtrack=5, escape_backtrack_window=frm * 0.006)
    planbench.plan(problem, far, seed=0)
    assert [k for k, _ in far.tries] == [frm, frm - round(frm * 0.6), 0]  # never before the start
    freed = Refusing(refusals=2, escape_backtrack=3, escape_backtrack_window=0.1)
    result = planbench.plan(problem, freed, seed=0)
    assert result.info["escapes"] >= 1 and result.info["escape_steps"][0] == frm - 20
    assert np.array_equal(result.path[: frm - 20 + 1], ended.path[: frm - 20 + 1])  # cut where it left
    assert planbench.evaluate(problem, result).max_velocity_ratio <= 1.0 + 1e-9
    for bad in ({"escape_backtrack": -1}, {"escape_backtrack_window": 0.0}):
        with pytest.raises(InvalidConfigError, match=next(iter(bad))):
            MatrixFieldConfig(**bad)
