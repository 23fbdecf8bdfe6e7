import numpy as np
import pytest

import planbench
from planbench.problem import Problem
from planbench.scene import Obstacle, Scene


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
    from scipy.spatial.transform import Rotation

    rot, _ = Rotation.align_vectors([normal], [[1.0, 0.0, 0.0]])
    return Obstacle(
        "plate", "box", position=tuple(mid), size=(thickness, size, size), orientation_xyzw=tuple(rot.as_quat())
    )
