"""An IK-loop planner's step, run as a closed-loop controller.

The field planners (``matrix-field``, ``matrix-field-qp``, ``edt-field``, ``distance-field``) are
one step function integrated by the IK loop (:mod:`planbench_plugins.ik_loop`). A controller is
that step without the integration: the runner gives ``q`` every tick and integrates the velocity
itself. :class:`IKLoopController` runs one planner class's step that way:

- ``setup(task)`` builds the planner from the controller's config (its ``Config`` *is* the
  planner's, so every planner setting is a controller setting) and prepares its loop for the
  task's robot and goal (:meth:`~planbench_plugins.ik_loop.IKLoopPlanner.prepare`): no scene, the
  controller knows obstacles only from observations. The loop's repulsion is a
  :class:`~.live.LiveRepulsion`, whose source each ``update(observation)`` replaces
  (:meth:`IKLoopController.make_source`, the one method a subclass writes). The self-collision
  push (``self_collision``, on by default) wraps it as in the planner: it needs the robot only.
- ``step`` runs the prepared :class:`~planbench_plugins.ik_loop.LoopStepper` from ``q``: the
  kinematics, the repulsion and the planner's step (compiled, or the QP); the joint velocity
  [rad/s], a copy.

What the loop's ``plan`` adds around its steps is planning, not control, and is switched off:
the integration (the runner integrates), endings and the local-minimum test, escapes
(``escape_attempts``: an escape teleports along a collision-checked detour of the true scene,
which a controller does not have), the periodic and final collision checks against the true
scene (``collision_check_every``, ``verify_path``). ``dt`` is replaced by the task's control
period: the step uses it only to keep ``q + qd dt`` within the joint limits, which must be the
runner's tick. A step that has no valid answer (:class:`~planbench_plugins.ik_loop.StepFailure`,
e.g. an infeasible QP) gives zero velocity and is counted in :meth:`~IKLoopController.info`.

Unknown cells (``unknown``, :class:`~.unknown.UnknownSettings`): with ``"occupied"``, ``update``
hands :meth:`~IKLoopController.make_source` the frame with the unknown cells near the arm (at the
last step's configuration, :mod:`.unknown`) occupied and no ``points`` (the grid is no longer a
sensor's surfaces only, so the matrix field's surface pass runs on it).
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import numpy as np

from planbench.problem import Goal
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench_plugins.controllers.live import LiveRepulsion
from planbench_plugins.controllers.unknown import near_unknown, unknown_as_occupied
from planbench_plugins.ik_loop import IKLoopConfig, IKLoopPlanner, LoopStepper, Repulsion, StepFailure

__all__ = ["IKLoopController", "PLANNING_ONLY"]

PLANNING_ONLY = {"escape_attempts": 0, "collision_check_every": 0, "verify_path": False}
"""Loop settings that belong to planning (module docstring), set so for the controller's planner."""


class IKLoopController(Controller):
    """The step of :attr:`planner_class` as a controller (module docstring).

    Subclasses set ``name``, ``Config`` (the planner's config class, or a subclass of it with
    controller defaults), :attr:`planner_class`, and write :meth:`make_source`.
    """

    Config: ClassVar[type] = IKLoopConfig
    planner_class: ClassVar[type[IKLoopPlanner]] = IKLoopPlanner
    """The IK-loop planner whose step this controller runs."""

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self.repulsion = LiveRepulsion()
        """The loop's repulsion; its source is replaced on every frame."""
        self.planner: IKLoopPlanner | None = None
        """The planner whose step runs (after :meth:`setup`)."""
        self.stepper: LoopStepper | None = None
        """The planner's loop, prepared for the task (after :meth:`setup`)."""
        self.task: ControlTask | None = None
        self._goal: Goal | None = None
        self._counts = {"steps": 0, "frames": 0, "step_failures": 0}
        self._last_failure = ""
        self._largest_push = 0.0
        self._unknown_cells = 0  # unknown cells read as occupied in the last frame
        self._counted: np.ndarray | None = None  # which they were (near_unknown's ``before``)

    # --- for subclasses ---------------------------------------------------------------------------
    def make_source(self, observation: Observation) -> Repulsion | None:
        """The repulsion of one sensor frame (None: nothing pushes). Timed as the field update."""
        raise NotImplementedError

    def planner_config(self, task: ControlTask) -> Any:
        """The planner's config: the controller's, with the task's period as ``dt`` and the
        planning-only features off (:data:`PLANNING_ONLY`)."""
        return dataclasses.replace(self.config, dt=float(task.period), **PLANNING_ONLY)

    def make_planner(self, task: ControlTask) -> IKLoopPlanner:
        """The planner whose step runs, before its loop is prepared (a subclass gives it what it
        measures besides the repulsion, as ``matrix-field-qp``'s collision constraints)."""
        return self.planner_class(self.planner_config(task))

    def extra_info(self) -> dict[str, Any]:
        """What a subclass adds to :meth:`info`."""
        return {}

    # --- the controller interface -------------------------------------------------------------------
    def setup(self, task: ControlTask) -> None:
        """Build the planner and prepare its loop for ``task`` (module docstring)."""
        self.task = task
        planner = self.make_planner(task)
        self.repulsion.replace(None)
        self.stepper = planner.prepare(task.robot, task.goal.pose, self.repulsion, start=task.start)
        self.planner = planner
        self._goal = task.goal

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        """A new run: no obstacle known until the first frame, counters at zero."""
        self.repulsion.replace(None)
        stepper = self._require()
        stepper.restart()
        stepper.kin.update(np.asarray(q, dtype=float))  # where the arm is until the first step
        self._counts = dict.fromkeys(self._counts, 0)
        self._last_failure = ""
        self._largest_push = 0.0
        self._unknown_cells = 0
        self._counted = None

    def update(self, observation: Observation) -> None:
        """The repulsion of the new frame replaces the last one's (its unknown cells near the arm
        occupied first, with ``unknown = "occupied"``)."""
        self.repulsion.replace(self.make_source(self.unknown_read(observation)))
        self._counts["frames"] += 1

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        """One step of the planner from ``q`` [rad]: joint velocities [rad/s] (zeros when the step
        has no valid answer)."""
        stepper = self._require()
        if goal is not self._goal:
            self._aim(stepper, goal)
        try:
            qd = stepper(q)
        except StepFailure as exc:
            self._counts["step_failures"] += 1
            self._last_failure = f"t = {t:.3f} s: {exc.message}"
            return np.zeros_like(stepper.qd)
        self._counts["steps"] += 1
        self._largest_push = max(self._largest_push, float(stepper.diag[2]))
        return qd.copy()

    def info(self) -> dict[str, Any]:
        """Steps, frames and failed steps of the run, the largest push [m/s], the gain in use."""
        out: dict[str, Any] = dict(self._counts)
        out["last_step_failure"] = self._last_failure
        out["largest_push"] = self._largest_push
        out["field_gain"] = self.repulsion.gain
        out["unknown_cells"] = self._unknown_cells
        if self.stepper is not None:
            out["hierarchy"] = self.stepper.hierarchy
            out["n_control_points"] = len(self.stepper.control_points)
        out.update(self.extra_info())
        return out

    def unknown_read(self, observation: Observation) -> Observation:
        """``observation`` as the ``unknown`` setting reads it: itself with ``"free"`` (or when
        every cell is known), else with the unknown cells near the arm where the last step left it
        occupied (:func:`.unknown.near_unknown`) and no ``points``."""
        stepper = self._require()
        c = self.config
        if getattr(c, "unknown", "free") == "free" or observation.grid.known is None:
            return observation
        arm = (stepper.kin.points, np.asarray(stepper.control_points.radius, dtype=float))
        cells = near_unknown(observation.grid, [arm], c.unknown_reach, c.unknown_self_margin, self._counted)
        self._counted = cells
        self._unknown_cells = 0 if cells is None else int(np.count_nonzero(cells))
        return dataclasses.replace(observation, grid=unknown_as_occupied(observation.grid, cells), points=None)

    # --- internals --------------------------------------------------------------------------------
    def _require(self) -> LoopStepper:
        if self.stepper is None:
            raise RuntimeError(f"{self.name}: call setup(task) before reset, update or step")
        return self.stepper

    def _aim(self, stepper: LoopStepper, goal: Goal) -> None:
        """Steer to ``goal`` from now on (:meth:`~planbench_plugins.ik_loop.LoopStepper.aim`)."""
        frame = self.task.goal.pose.frame if self.task is not None else goal.pose.frame
        if goal.pose.frame != frame:
            raise ValueError(
                f"{self.name}: the goal's frame changed from {frame!r} to {goal.pose.frame!r}; "
                "a controller steers one frame, set up a new task for another"
            )
        stepper.aim(goal.pose)
        self._goal = goal
