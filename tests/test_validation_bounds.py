"""Bounded validation: a path too costly to validate is refused after counting, before any state is
built; validation memory stays flat on long paths; the validator's address space is limited during
a validation and running out is a refused row, never a lost run. Planners in
tests/bench_bounds_planners.py."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from bench_bounds_planners import huge_path

import planbench
import planbench.checking.certified
import planbench.validate
from planbench.bench.benchmark import run_benchmark
from planbench.bench.db import ResultsDB
from planbench.bench.suite import parse_suite
from planbench.checking.certified import CertificationSettings, CertifiedChecker
from planbench.metrics import TIMING_SPACING, densify
from planbench.planner import PlanResult, PlanStatus
from planbench.validate import ValidationSettings, validation_states

FREE = "mbm:table_pick/0001"  # the straight line from start to goal is free
B = "bench_bounds_planners"


@pytest.fixture(scope="module")
def problem():
    return planbench.load_problems(FREE)[0]


def claimed(path: np.ndarray) -> PlanResult:
    return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration")


def test_a_huge_zigzag_is_refused_from_its_count_without_building_states(problem):
    path = huge_path(problem, 1_000_000, "zigzag")
    result = claimed(path)
    needed = validation_states(path, ValidationSettings().ee_resolution)
    assert needed > 1e8  # ~27 GB of interpolated states, were they built
    tracemalloc.start()
    try:
        ev = planbench.evaluate(problem, result)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert not ev.success and ev.status == "success" and ev.n_waypoints == len(path)
    assert f"path needs {needed:.3g} interpolated states" in ev.failure, ev.failure
    assert "above the validation limit of 2.5e+05 (ValidationSettings.max_validation_states)" in ev.failure
    assert ev.validation_checks == 0  # no distance query either
    assert peak < 32 * 2**20, peak / 2**20  # counting, a block at a time; the path itself is 53 MB


def test_the_count_covers_the_states_validation_builds():
    assert validation_states(np.array([[0.0], [1.0]]), 0.01) == 1 + 100 + 50
    assert validation_states(np.zeros((1, 7)), 0.01) == 1
    assert validation_states(np.array([[0.0], [1e308], [-1e308]]), 0.01) == math.inf
    rng = np.random.default_rng(0)
    for _ in range(20):
        path = rng.uniform(-2, 2, (int(rng.integers(2, 40)), 7)) * rng.uniform(0, 1, 7)
        length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
        built = len(densify(path, 0.01)[0]) + length / TIMING_SPACING
        assert built <= validation_states(path, 0.01) <= built + len(path) + 1


def test_touching_is_a_collision_and_two_micrometres_away_is_free(problem):
    # docs/validation.md: every distance is lowered by coal's 1 um before it counts
    q = problem.start
    checker = CertifiedChecker(problem.robot, problem.scene)
    s = checker._new_sample(-1.0, q)
    gap = min(checker._query("exact", s, k) for k in range(checker.n_pairs))  # obstacles and links
    for distance, free in ((0.0, False), (0.9e-6, False), (2e-6, True)):
        settings = CertificationSettings(required_clearance=gap - distance)  # as if `distance` apart
        assert CertifiedChecker(problem.robot, problem.scene, settings).check_path(q[None]).free is free, distance


def _same(a, b) -> None:
    assert (a.success, a.failure, a.validation_checks, a.collision_segment) == (
        b.success,
        b.failure,
        b.validation_checks,
        b.collision_segment,
    )
    for name in ("ee_path_length", "min_clearance", "min_clearance_bound", "mean_clearance", "duration_limited"):
        assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-12, abs=1e-15), name


@pytest.mark.parametrize(("ref", "planner"), [(FREE, "straight-line"), ("mbm:bookshelf_small/0007", "ompl-rrtconnect")])
def test_shipped_planners_paths_validate_as_before(monkeypatch, ref, planner):
    p = planbench.load_problems(ref)[0]
    result = planbench.plan(p, planner, time_limit=5.0, seed=0)
    assert result.path is not None
    ev = planbench.evaluate(p, result)
    assert ev.success, ev.failure
    assert validation_states(result.path, 0.01) < ValidationSettings().max_validation_states / 100
    # the long-path ways (the end-effector length a few states at a time, the motion bounds' rows
    # one pair at a time) give the same verdict and metrics as the at-once ways a short path takes
    monkeypatch.setattr(planbench.validate, "EE_CHUNK", 7)
    monkeypatch.setattr(planbench.checking.certified, "CUM_TABLE_FLOATS", 0)
    CertifiedChecker.forget(p)
    _same(planbench.evaluate(p, result), ev)


def test_memory_stays_flat_on_a_long_path_under_the_limit(problem):
    # 100,000 waypoints back and forth: 2.5 GB of motion-bound table (pairs x waypoints) before
    n = 100_000
    path = problem.start + ((np.arange(n) % 200) / 200 * 0.5)[:, None] * (problem.goal.q - problem.start)
    checker = CertifiedChecker(problem.robot, problem.scene, CertificationSettings(max_queries=2_000))
    tracemalloc.start()
    try:
        verdict = checker.check_path(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert checker.n_pairs * n * 8 > 100 * 2**20  # what the table would have taken
    assert peak < 30 * 2**20, peak / 2**20  # the joints' travel (7 x n) and a pair's row
    assert not verdict.free and "distance queries" in verdict.reason


def suite(planners: str, extra: str = "") -> str:
    return f"""
[suite]
name = "bounds"
problems = ["{FREE}"]
seeds = [0]
time_limit = 10.0
grace = 5.0
{extra}
{planners}
"""


def rows_of(db_path) -> dict:
    with ResultsDB(db_path) as db:
        return {r["planner"]: r for r in db.rows()}


@pytest.mark.slow
def test_a_benchmark_refuses_the_huge_zigzag_and_the_next_run_is_intact(tmp_path, problem):
    planners = f"""
[[planners]]
label = "a-zigzag"
planner = "{B}:HugePathPlanner"
[[planners]]
label = "b-after"
planner = "straight-line"
"""
    run_benchmark(parse_suite(suite(planners), "zigzag.toml"), tmp_path / "r.db", jobs=1)
    rows = rows_of(tmp_path / "r.db")
    zigzag, after = rows["a-zigzag"], rows["b-after"]
    needed = validation_states(huge_path(problem, 1_000_000, "zigzag"), 0.01)
    assert zigzag["status"] == "success" and not zigzag["success"]
    assert f"path needs {needed:.3g} interpolated states" in zigzag["failure"], zigzag["failure"]
    assert "(ValidationSettings.max_validation_states)" in zigzag["failure"]
    assert zigzag["validation_checks"] == 0
    assert after["success"], after["failure"]


@pytest.mark.slow
def test_a_validation_out_of_memory_is_a_refused_row_and_the_validator_goes_on(tmp_path):
    # 1e6 waypoints that do not move: counted as 1e6 states (allowed here), but checking them
    # allocates several 53 MB arrays, past 150 MiB; a short path needs far less
    planners = f"""
[[planners]]
label = "a-warm"
planner = "straight-line"
[[planners]]
label = "b-still"
planner = "{B}:HugePathPlanner"
settings = {{ shape = "still" }}
[[planners]]
label = "c-after"
planner = "straight-line"
"""
    extra = "[validation]\nvalidation_memory_limit = 150\nmax_validation_states = 2_000_000\n"
    run_benchmark(parse_suite(suite(planners, extra), "oom.toml"), tmp_path / "r.db", jobs=1)
    rows = rows_of(tmp_path / "r.db")
    still = rows["b-still"]
    assert still["status"] == "success" and not still["success"]
    assert "not validated: validation ran out of memory" in still["failure"], still["failure"]
    assert "+ 150 MiB (ValidationSettings.validation_memory_limit)" in still["failure"]
    assert rows["a-warm"]["success"] and rows["c-after"]["success"], rows["c-after"]["failure"]
