"""One step of the IK loop from any configuration, on buffers prepared once.

:meth:`IKLoopPlanner.prepare <planbench_plugins.ik_loop.loop.IKLoopPlanner.prepare>` builds a
:class:`LoopStepper` for a robot, a goal pose and a repulsion: the kinematics, the step inputs, the
buffers and the planner's step bound to them (with numba, the compiled step bound to the types of
these very arrays, :func:`.fast.bind`). The planner's ``plan`` integrates it; a controller
(:mod:`planbench_plugins.controllers`) calls it once per control tick from the measured ``q``.

:class:`ArmRepulsion` is its first half, the arm's kinematics and the repulsion asked at ``q``:
all that a planner needs that only adds the push to its own loop (``matrix-field-guided``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from planbench_plugins.ik_loop.kinematics import ArmKinematics

if TYPE_CHECKING:
    from planbench.problem import Pose
    from planbench_plugins.ik_loop.control_points import ControlPoints
    from planbench_plugins.ik_loop.loop import Repulsion, StepInputs

__all__ = ["ArmRepulsion", "LoopStepper"]

Forces = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""``(points, F, support, joint)``, as :meth:`Repulsion.forces <.loop.Repulsion.forces>` returns them."""


@dataclass(eq=False)
class ArmRepulsion:
    """A robot's kinematics for one goal frame and its control points (``kin``), and the
    repulsion acting on the arm. ``kin`` is updated in place by :meth:`at`: one object per loop."""

    robot: Any
    kin: ArmKinematics
    repulsion: Repulsion

    @property
    def control_points(self) -> ControlPoints:
        return self.kin.cp

    def at(self, q: np.ndarray) -> Forces:
        """The kinematics updated to ``q`` [rad], then the repulsion's ``(points, F, support,
        joint)`` there (arrays the repulsion may reuse: read them before the next call)."""
        self.kin.update(q)
        return self.repulsion.forces(self.kin)

    def kinematics_at(self, q: np.ndarray) -> ArmKinematics:
        """New kinematics of the same arm, frame and points at ``q``, leaving ``kin`` (the one the
        step is bound to) as it is: for inspection and plots."""
        kin = ArmKinematics(self.robot, self.kin.frame_id, self.kin.cp)
        kin.update(np.asarray(q, dtype=float))
        return kin

    def forces_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(points, F)`` at ``q``, copies: the points where the repulsion acts [m] and the
        repulsive velocities there [m/s] (:meth:`kinematics_at`; for plots and inspection)."""
        points, F, _, _ = self.repulsion.forces(self.kinematics_at(q))
        return points.copy(), F.copy()


@dataclass(eq=False)
class LoopStepper(ArmRepulsion):
    """One step of the loop, from any configuration (made by ``IKLoopPlanner.prepare``).

    The buffers the step is bound to: ``q`` (n,) the configuration it reads [rad], ``qd`` (n,) the
    joint velocity it writes [rad/s], ``diag`` its diagnostics (:data:`.loop.DIAGNOSTICS`, then the
    planner's ``extra_diagnostics``); write into them, never rebind them. ``inputs`` the goal, the
    limits and the step's parameters (:meth:`aim` moves the goal). ``solve(points, F, support,
    tool)`` is the planner's ``solve_step`` on these buffers for what the repulsion returned;
    ``joint`` and ``tool`` the joints of the repulsion's last points and the indices of the tool's
    among them (recomputed when the repulsion returns another ``joint`` array). ``hierarchy`` the
    mode in use on this arm, ``warnings`` what the settings cannot do on it.
    """

    inputs: StepInputs
    q: np.ndarray
    qd: np.ndarray
    diag: np.ndarray
    solve: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], None]
    joint: np.ndarray
    tool: np.ndarray
    hierarchy: str
    warnings: tuple[str, ...] = ()
    _start: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._start = self.joint, self.tool  # the arrays the compiled step was bound to

    def tool_points(self, joint: np.ndarray) -> np.ndarray:
        """Indices of the points carried by the goal frame's joint, for a repulsion's ``joint``."""
        return np.flatnonzero(joint == self.inputs.tool_joint)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """One step from ``q`` [rad]: the kinematics, the repulsion, the step. Returns ``qd`` (the
        buffer: copy it to keep it); ``diag`` holds the step's diagnostics. Raises
        :class:`~.loop.StepFailure` when the step has no valid answer."""
        x = self.q
        x[:] = q
        kin = self.kin
        kin.update(x)
        points, F, support, joint = self.repulsion.forces(kin)
        if joint is not self.joint:  # sources on the control points return the same array
            self.joint, self.tool = joint, self.tool_points(joint)
        self.solve(points, F, support, self.tool)
        return self.qd

    def restart(self) -> None:
        """Start a new query or run: the same answers however the last one ended (the
        self-collision push asks its distances afresh; the tool's points are the prepared ones)."""
        self.joint, self.tool = self._start
        restart = getattr(self.repulsion, "restart", None)
        if callable(restart):
            restart()

    def aim(self, goal: Pose) -> None:
        """Steer to ``goal`` from the next step on (written into the arrays the step is bound to).
        Its frame must be the one the loop was prepared for."""
        if self.robot.frame_id(goal.frame) != self.kin.frame_id:
            steered = self.robot.model.frames[self.kin.frame_id].name
            raise ValueError(f"the loop steers frame {steered!r}, not {goal.frame!r}: prepare another for it")
        self.inputs.p_goal[:] = np.asarray(goal.position, dtype=float)
        self.inputs.R_goal[:] = np.asarray(goal.rotation, dtype=float)
