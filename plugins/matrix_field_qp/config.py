"""Settings of the ``matrix-field-qp`` planner: the matrix-field planner's, plus the QP's.

Everything of the IK loop's settings (:class:`~planbench_plugins.ik_loop.IKLoopConfig`: time
step, attraction, secondary-task gains, endings) and of the field's
(:class:`~planbench.field.scene_field.FieldSettings`) keeps its meaning, as in ``matrix-field``;
what is added here are the weights of the QP's objective (see :mod:`.formulation`),
the collision constraints (exact distances, :mod:`.distances`), the field's velocity dampers, and
the solver.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import qpsolvers

from planbench.errors import InvalidConfigError
from planbench.field.scene_field import FieldSettings
from planbench_plugins.ik_loop import IKLoopConfig, check_number

__all__ = ["MatrixFieldQPConfig", "installed_solvers"]


def installed_solvers() -> list[str]:
    """The qpsolvers backends importable here (``qpsolvers.available_solvers``)."""

    return list(qpsolvers.available_solvers)


@dataclass(frozen=True)
class MatrixFieldQPConfig(FieldSettings, IKLoopConfig):
    """Settings of :class:`~planbench_plugins.matrix_field_qp.MatrixFieldQPPlanner`.

    Objective (one step, decision variable ``qd`` [rad/s]; :mod:`.formulation`)::

        1/2 w_task |W (J qd - s v_att)|^2 + 1/2 w_sec |qd - (qd_rep + qd_m + qd_c)|^2 + 1/2 mu |qd|^2

    with ``W = diag(1, 1, 1, r, r, r)``, ``r = orientation_weight``, and ``mu = w_task lambda^2 +
    damping_weight`` (``lambda`` the loop's damping, adaptive by default). Without active
    constraints the minimiser is the matrix-field step before its limits, with damped least
    squares at ``lambda_eff^2 = lambda^2 + (w_sec + damping_weight) / w_task``.
    """

    # --- objective -----------------------------------------------------------------------
    task_weight: float = 1.0
    """``w_task`` [s^2/m^2]: weight of the primary (end-effector) task. Only ratios matter."""
    orientation_weight: float = 1.0
    """``r`` [m^2/rad^2]: weight of the angular rows of the primary task relative to the linear
    ones (1 = the same balance as the matrix-field step's damped least squares)."""
    secondary_weight: float = 1e-3
    """``w_sec`` [s^2/rad^2]: weight of the secondary target ``qd_rep + qd_m + qd_c``. Small
    against ``w_task``, so the secondary tasks act (almost) only in the primary task's null space;
    it also damps the primary task like a fixed ``lambda^2 = w_sec / w_task`` (0.03 m)."""
    damping_weight: float = 1e-9
    """``mu_0`` [s^2/rad^2]: smallest weight of ``|qd|^2``, keeping the Hessian positive definite
    whatever the other weights."""

    # --- collision constraints (exact distances; docs/method.md section 5) ---------------------
    collision_constraints: bool = True
    """Collision avoidance as hard constraints of the QP: for every pair (robot collision geometry,
    obstacle) closer than ``collision_influence``, the velocity damper ``d_dot >= -collision_gain (d
    - collision_safety)`` with ``d`` coal's exact distance (robot meshes as their convex hulls),
    linear in ``qd`` through the witness point's Jacobian along the separating normal
    (:func:`.formulation.collision_constraints`). The distance then never falls below the safety
    distance (to first order in one step), so a step that cannot keep it ends the plan as a named
    ``INFEASIBLE`` step, never in a collision. Off: collision avoidance by the field alone (the
    objective), as ``matrix-field``."""
    collision_influence: float = 0.10
    """``d_i`` [m]: pairs closer than this get a constraint. Larger than a control point's travel
    in one step (the pair is seen before it can touch), and cheap: pairs farther apart are culled
    by bounding volumes before coal is asked."""
    collision_safety: float = 0.003
    """``d_s`` [m]: distance the constraints keep between every robot geometry's hull and every
    obstacle (below it they ask for a retreat). Small: goal poses of grasps often lie 1 cm from an
    obstacle, and the hand must reach them."""
    collision_gain: float = 5.0
    """``xi`` [1/s]: the approach speed allowed towards an obstacle is ``xi (d - d_s)``, so the gap
    above ``d_s`` shrinks at most by ``xi dt`` of itself per step (``xi dt <= 1`` is required: the
    step then cannot jump past ``d_s``)."""

    # --- velocity dampers from the field (obstacle avoidance as a constraint) ----------------
    velocity_dampers: bool = False
    """One linear constraint per control point inside the field: its velocity towards the
    obstacle (against ``f_i``) is at most ``a_i`` (:func:`.formulation.velocity_dampers`). Off by
    default: on MotionBenchMaker 0001-0020 it changed success from 30.7 % to 30.0 % (one problem)
    and cost 60 % more planning time (median 270 ms against 167 ms, daqp)."""
    damper_speed: float = 1.0
    """``xi`` [m/s]: approach speed allowed where the field starts (``|f_i|`` -> 0)."""
    damper_stop: float = 1.5
    """``k_stop`` [-]: the approach speed falls linearly with ``|f_i|`` and reaches 0 where
    ``|f_i| = k_stop * speed_max`` (1 = at the stand-off; larger = closer to the obstacle)."""
    damper_tool: bool = False
    """Also constrain the points carried by the goal frame's joint (hand, fingers). Off: the
    goal pose is collision-free but often within a few centimetres of a shelf, where a damper
    on the hand would stop it short."""

    # --- solver --------------------------------------------------------------------------
    solver: str = "daqp"
    """qpsolvers backend by name (any of ``qpsolvers.available_solvers``). daqp (dense, active-set,
    exact) by default: a step's QP has one variable per joint and tens of rows, where OSQP (the
    specification's backend, ``"osqp"``) is set up and factorised anew on every call; on
    MotionBenchMaker 0001-0020 at 5 s daqp solved 93 of 140 against OSQP's 78 (15 more, none fewer),
    every difference a time-out (docs/planners.md, "Solvers and failures")."""
    solver_options: Any = None
    """Extra keyword arguments for the backend (``{"eps_abs": 1e-8}``), over the defaults of
    :data:`.solve.SOLVER_DEFAULTS`."""
    residual_tolerance: float = 1e-5
    """Largest constraint violation [rad/s, m/s] accepted from the solver before the step is
    refused (``INFEASIBLE``). Smaller violations of the joint limits are then removed exactly by
    projecting onto the bounds, so the returned trajectory never breaks them."""

    def __post_init__(self) -> None:
        if self.solver_options is not None:
            object.__setattr__(self, "solver_options", _freeze_options(self.solver_options))
        super().__post_init__()

    def validate(self) -> None:
        IKLoopConfig.validate(self)
        self.validate_field()
        for name in (
            "task_weight",
            "orientation_weight",
            "damping_weight",
            "damper_speed",
            "damper_stop",
            "residual_tolerance",
            "collision_influence",
            "collision_gain",
        ):
            check_number(self, name, lambda v: v > 0, "finite and > 0")
        check_number(self, "secondary_weight", lambda v: v >= 0, "finite and >= 0")
        check_number(self, "collision_safety", lambda v: v >= 0, "finite and >= 0")
        if self.collision_safety >= self.collision_influence:
            raise InvalidConfigError(
                f"collision_safety ({self.collision_safety:g} m) must be below collision_influence "
                f"({self.collision_influence:g} m)"
            )
        if self.collision_gain * self.dt > 1.0:
            raise InvalidConfigError(
                f"collision_gain ({self.collision_gain:g} 1/s) times dt ({self.dt:g} s) must be at most 1: "
                "a larger gain lets one step jump past the safety distance"
            )
        for name in ("collision_constraints", "velocity_dampers", "damper_tool"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        installed = installed_solvers()
        if self.solver not in installed:
            raise InvalidConfigError(
                f"solver {self.solver!r} is not an installed qpsolvers backend; installed: {installed}. "
                f"Install it with e.g. `pip install qpsolvers[{self.solver}]`, or choose one of those."
            )

    @property
    def options(self) -> dict[str, Any]:
        """The solver options as a dict."""
        return dict(self.solver_options or ())


def _freeze_options(options: Any) -> tuple[tuple[str, Any], ...]:
    if not isinstance(options, Mapping | tuple | list):
        raise InvalidConfigError(f"solver_options must map option names to values, got {options!r}")
    try:
        items = dict(options).items()
    except (TypeError, ValueError):
        raise InvalidConfigError(f"solver_options must map option names to values, got {options!r}") from None
    return tuple(sorted((str(k), v) for k, v in items))
