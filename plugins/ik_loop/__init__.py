"""The IK loop that every field planner shares: the loop, its task terms, control points,
kinematics and the compiled step (docs/method.md, "The IK loop").

A field planner is one module: a config (subclass :class:`IKLoopConfig`, add the repulsion's
settings) and a planner (subclass :class:`IKLoopPlanner`, give ``make_repulsion``)::

    @dataclass(frozen=True)
    class MyConfig(IKLoopConfig):
        reach: float = 0.2

    class MyPlanner(IKLoopPlanner):
        name = "my-field"
        Config = MyConfig

        def make_repulsion(self, problem, points):
            return MyRepulsion(problem.scene, self.config.reach)  # forces(kin) -> points, F, support, joint

The two seams are :class:`Repulsion` (where the push comes from) and
:meth:`IKLoopPlanner.solve_step` (how one step's joint velocity is solved; ``matrix-field-qp``
replaces it with a quadratic program). :meth:`IKLoopPlanner.prepare` gives the step for a robot, a
goal and a repulsion as a :class:`LoopStepper`, to call from any configuration (the controllers
do, once per tick). Modules: ``config``, ``loop``, ``stepper``, ``tasks`` (one function per
task term), ``control_points``, ``kinematics``, ``fast`` and ``_compiled`` (the step in one
compiled call), ``escape`` (leaving local minima), ``distances`` (coal's exact distances, robot to
obstacles and robot to itself), ``self_collision`` (the push between the robot's own links),
``plots``.
"""

from typing import Any

from planbench_plugins.ik_loop import tasks
from planbench_plugins.ik_loop.config import DAMPING_MODES, IKLoopConfig, check_number
from planbench_plugins.ik_loop.control_points import ControlPoints, place_control_points
from planbench_plugins.ik_loop.distances import DistanceModel, PairDistances
from planbench_plugins.ik_loop.khatib import khatib_gain, khatib_magnitude
from planbench_plugins.ik_loop.kinematics import ArmKinematics
from planbench_plugins.ik_loop.loop import (
    DIAGNOSTICS,
    IKLoopPlanner,
    Repulsion,
    ScaledRepulsion,
    StepFailure,
    StepInputs,
    ZeroRepulsion,
    stalled,
)
from planbench_plugins.ik_loop.stepper import ArmRepulsion, LoopStepper

__all__ = [
    "DAMPING_MODES",
    "DIAGNOSTICS",
    "ArmKinematics",
    "ArmRepulsion",
    "ControlPoints",
    "DistanceModel",
    "PairDistances",
    "IKLoopConfig",
    "IKLoopPlanner",
    "LoopStepper",
    "Repulsion",
    "ScaledRepulsion",
    "StepFailure",
    "StepInputs",
    "ZeroRepulsion",
    "check_number",
    "khatib_gain",
    "khatib_magnitude",
    "place_control_points",
    "plot_result",
    "stalled",
    "tasks",
]


def plot_result(problem: Any, result: Any, path_png: Any = None, **kwargs: Any) -> Any:
    """Three panels: the arm with control points and repulsive vectors, the end-effector path
    among the obstacles, errors and repulsion over time (:func:`.plots.plot_result`). Imported on
    use: matplotlib costs a planner's start-up half a second it does not need to plan."""
    from planbench_plugins.ik_loop.plots import plot_result as _plot

    return _plot(problem, result, path_png, **kwargs)
