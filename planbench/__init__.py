"""planbench: plan paths for robot arms and compare planners fairly.

Library use::

    import planbench
    problem = planbench.load_problems("mbm:box/0001")[0]
    result = planbench.plan(problem, planner="straight-line", seed=0, time_limit=5.0)
    print(planbench.evaluate(problem, result))

The layers of the package, and which may import which: docs/architecture.md.
"""

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType
from typing import TYPE_CHECKING

from planbench.errors import PlanbenchError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.harness import plan
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Goal, Pose, Problem, Tolerances
from planbench.problems.datasets import load_problems
from planbench.registry import CONTROLLERS, REGISTRY, Registry, make_controller, make_planner, register_planner
from planbench.robot import Robot, RobotSettings, load_robot
from planbench.scene import Obstacle, Scene
from planbench.validate import Evaluation, ValidationSettings, evaluate

if TYPE_CHECKING:  # imported on use (__getattr__ below): its type for type checkers
    from planbench.bench.results import load as load_results
    from planbench.reactive.sets import load_scenarios

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    if name == "load_scenarios":  # imported on use, like the benchmark
        from planbench.reactive.sets import load_scenarios

        return load_scenarios
    if name == "load_results":  # imported on use: pandas
        from planbench.bench.results import load

        return load
    if name == "benchmark":  # imported on use: the benchmark pulls in sqlite, plotting, workers
        from planbench.bench import benchmark

        return benchmark
    raise AttributeError(f"module 'planbench' has no attribute {name!r}")


MOVED = {
    "planbench.certified": "planbench.checking.certified",
    "planbench.collision": "planbench.checking.collision",
    "planbench.datasets": "planbench.problems.datasets",
    "planbench.occupancy": "planbench.geometry.occupancy",
    "planbench.outputs": "planbench.files.outputs",
    "planbench.pointcloud": "planbench.geometry.pointcloud",
    "planbench.results": "planbench.bench.results",
}
"""Modules of release 0.1 that moved into subpackages in 0.2: importable under their old names,
with a ``DeprecationWarning``, until 0.3 (CHANGELOG.md)."""


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds a moved module under its old name and hands out the module at its new place (the
    same module object: one import, one set of globals)."""

    def find_spec(
        self, fullname: str, path: object = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        return importlib.machinery.ModuleSpec(fullname, self) if fullname in MOVED else None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        new = MOVED[spec.name]
        warnings.warn(f"{spec.name} moved to {new}; import it from there", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module: ModuleType) -> None:
        pass  # imported at its new place already


if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
    sys.meta_path.append(_MovedModules())


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
    "load_results",
    "load_scenarios",
    "load_robot",
    "make_controller",
    "make_planner",
    "plan",
    "register_planner",
]
