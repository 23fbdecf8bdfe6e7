"""planbench: plan paths for robot arms and compare planners fairly.

Library use::

    import planbench
    problem = planbench.load_problems("mbm:box/0001")[0]
    result = planbench.plan(problem, planner="straight-line", seed=0, time_limit=5.0)
    print(planbench.evaluate(problem, result))
"""

from typing import TYPE_CHECKING

from planbench.datasets import load_problems
from planbench.errors import PlanbenchError
from planbench.harness import plan
from planbench.occupancy import OccupancyGrid
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Goal, Pose, Problem, Tolerances
from planbench.registry import CONTROLLERS, REGISTRY, Registry, make_controller, make_planner, register_planner
from planbench.robot import Robot, RobotSettings, load_robot
from planbench.scene import Obstacle, Scene
from planbench.validate import Evaluation, ValidationSettings, evaluate

if TYPE_CHECKING:  # imported on use (__getattr__ below): its type for type checkers
    from planbench.reactive.sets import load_scenarios

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    if name == "load_scenarios":  # imported on use, like the benchmark
        from planbench.reactive.sets import load_scenarios

        return load_scenarios
    if name == "benchmark":  # imported on use: the benchmark pulls in sqlite, plotting, workers
        from planbench.bench import benchmark

        return benchmark
    raise AttributeError(f"module 'planbench' has no attribute {name!r}")


__all__ = [
    "benchmark",
    "CONTROLLERS",
    "Evaluation",
    "Goal",
    "Obstacle",
    "OccupancyGrid",
    "PlanResult",
    "PlanStatus",
    "Planner",
    "PlanbenchError",
    "Pose",
    "Problem",
    "REGISTRY",
    "Registry",
    "Robot",
    "RobotSettings",
    "Scene",
    "Tolerances",
    "ValidationSettings",
    "evaluate",
    "load_problems",
    "load_scenarios",
    "load_robot",
    "make_controller",
    "make_planner",
    "plan",
    "register_planner",
]
