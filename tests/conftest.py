"""Shared fixtures and helpers of the tests.

Tests that take seconds each (benchmark runs in worker processes, planners that use their whole
time limit, all 700 MotionBenchMaker problems) carry the ``slow`` marker (registered in
pyproject.toml). ``.venv/bin/pytest`` runs everything, as CI does; the quick set, under a minute
on two cores, is::

    .venv/bin/pytest -m "not slow"

Most are marked with ``@pytest.mark.slow`` in their file; the few below are marked here
(``SLOW_CASES``): single cases of a parametrized test, and a module without a pytest import.
"""

import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import planbench
from planbench.problem import Problem
from planbench.scene import Obstacle, Scene

# planbench commands run here compute with numba whatever its cache holds, and start no background
# compilation (tests/test_compile_cache.py turns it on where it tests it)
os.environ["PLANBENCH_BACKGROUND_COMPILE"] = "0"

# "file::test[case]" of the slow tests that cannot carry a decorator of their own
SLOW_CASES = {
    "test_conformance.py::test_every_registered_planner_conforms[ompl-rrtstar]",  # RRT* plans to its time limit
    "test_ompl_planners.py::test_conformance[ompl-rrtstar]",
    "test_bench_processes.py::test_a_planner_flooding_stdout_reaches_neither_the_terminal_nor_the_disk_unbounded",
    "test_bench_processes.py::test_a_run_killed_on_timeout_takes_its_child_processes_with_it",
    "test_bench_processes.py::test_workers_and_their_children_die_when_the_main_process_is_killed",
}


def pytest_collection_modifyitems(items):
    for item in items:
        if f"{item.path.name}::{item.name}" in SLOW_CASES:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def panda():
    return planbench.load_robot("panda")


@pytest.fixture
def free_problem(panda):
    """Empty scene, goal 0.3 rad from home on every joint."""
    goal = panda.home + 0.3
    return Problem.create(panda, Scene(name="empty"), panda.home, goal, id="test:free")


def box(name, position, size, **kw):
    return Obstacle(name, "box", position=tuple(position), size=tuple(size), **kw)


def midpoint_wall(robot, start, goal, thickness=0.005, size=0.06):
    """A thin plate across the end effector's straight-line path, halfway between start and goal."""
    a = robot.frame_pose(start).translation
    b = robot.frame_pose(goal).translation
    mid = robot.frame_pose(0.5 * (start + goal)).translation
    normal = (b - a) / np.linalg.norm(b - a)
    # plate spanning the two directions orthogonal to the motion, thin along it
    rot, _ = Rotation.align_vectors([normal], [[1.0, 0.0, 0.0]])
    return Obstacle(
        "plate", "box", position=tuple(mid), size=(thickness, size, size), orientation_xyzw=tuple(rot.as_quat())
    )
