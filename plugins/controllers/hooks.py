"""The one place where the controllers read an IK-loop planner's private state.

:class:`~planbench_plugins.ik_loop.IKLoopPlanner` prepares everything one step needs in ``setup``
(kinematics, step inputs, buffers, the compiled step bound to them) but keeps it in a private
dict, ``_prepared``, read only by its own ``plan``. A controller runs one step per control tick
and needs exactly that, so until the loop offers it publicly this module reads it, here and
nowhere else. The public hook that would replace it, proposed for the loop::

    class IKLoopPlanner:
        def stepper(self) -> LoopStepper:
            '''After setup: one step of the loop from any q, the repulsion asked at q.'''

    class LoopStepper:
        kin, inputs, q, qd, diag, repulsion          # the buffers the compiled step is bound to
        def __call__(self, q) -> np.ndarray: ...     # kin.update, forces, solve_step; qd (a view)
        def restart(self) -> None: ...               # what plan() resets at the start of a query

``matrix-field-qp`` keeps two more private fields: the distances checked ahead by the last step
(``_next``) and the witness points kept from earlier steps (``_kept``). Both belong to the scene the
distances were measured in, so a new scene must drop them (:func:`forget_checked_steps`); the hook
there would be ``MatrixFieldQPPlanner.use_distances(model)``, setting ``distances`` and dropping both.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench_plugins.ik_loop import ArmKinematics, IKLoopPlanner, Repulsion, StepInputs

__all__ = ["LoopState", "loop_state", "forget_checked_steps"]


@dataclass(frozen=True, eq=False)
class LoopState:
    """What one step of a set-up IK-loop planner reads and writes (arrays shared with the loop).

    ``q`` (n,) the configuration buffer the step reads [rad] (write into it, never rebind it);
    ``qd`` (n,) the joint velocity the step writes [rad/s]; ``diag`` the step's diagnostics
    (:data:`~planbench_plugins.ik_loop.DIAGNOSTICS` first); ``step(points, F, support, tool)`` the
    step bound to these buffers; ``repulsion`` the loop's repulsion (the controller's
    :class:`~.live.LiveRepulsion`, possibly inside the self-collision push); ``joint`` and
    ``tool`` the joints of the repulsion's points at setup and the indices of the tool's points."""

    kin: ArmKinematics
    inputs: StepInputs
    q: np.ndarray
    qd: np.ndarray
    diag: np.ndarray
    step: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], None]
    repulsion: Repulsion
    joint: np.ndarray
    tool: np.ndarray


def loop_state(planner: IKLoopPlanner) -> LoopState:
    """The step state of ``planner`` after its ``setup`` (raises if it was not set up)."""
    prep: dict[str, Any] | None = planner._prepared  # PRIVATE: IKLoopPlanner's setup state (module docstring)
    if prep is None:
        raise RuntimeError(f"{planner.name}: setup(problem) must run before its steps can be used")
    return LoopState(
        kin=prep["kin"],
        inputs=prep["inputs"],
        q=prep["q"],
        qd=prep["qd"],
        diag=prep["dg"],
        step=prep["step"],
        repulsion=prep["repulsion"],
        joint=prep["joint"],
        tool=prep["tool"],
    )


def forget_checked_steps(planner: Any) -> None:
    """Drop what ``matrix-field-qp`` remembers from earlier steps' distance checks (the pairs
    checked ahead, the witness points kept): they belong to the scene they were measured in."""
    planner._next = None  # PRIVATE: MatrixFieldQPPlanner's distances checked ahead (module docstring)
    planner._kept = {}  # PRIVATE: MatrixFieldQPPlanner's witness points kept per pair
