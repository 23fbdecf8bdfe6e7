"""Solving a step's QP with qpsolvers: backend choice, options, timing, and refusal of bad answers.

A step is either a velocity that satisfies the joint limits exactly, or a :class:`QPFailure` that
names the solver and its status; never an exception from the backend, never a silently wrong
step. The solver's answer is checked (finite, constraint violation under ``residual_tolerance``)
and then projected onto the velocity and position bounds, which removes the remaining round-off
violation of the limits (the projection moves ``qd`` by at most that violation).
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import numpy as np
import qpsolvers
from scipy.sparse import csc_matrix

from planbench.planner import PlanStatus
from planbench_plugins.ik_loop import StepFailure
from planbench_plugins.matrix_field_qp.formulation import StepQP, infeasible_joints

__all__ = ["QPFailure", "QPSolver", "SOLVER_DEFAULTS", "RETRY_OPTIONS"]

SOLVER_DEFAULTS: dict[str, dict[str, Any]] = {
    "osqp": {"eps_abs": 1e-8, "eps_rel": 1e-8, "polishing": False, "max_iter": 20000, "raise_error": False},
}
"""Options given to a backend unless ``solver_options`` overrides them. OSQP's own tolerances
(1e-3) leave steps up to 0.3 rad/s from the optimum on planning QPs; at 1e-8 they agree with an
active-set solver (daqp) to 1e-5 rad/s (median 2e-8). Polishing is off: OSQP 1.1 prints a line on
every solve that polishes nothing, even with ``verbose=False`` (osqp/osqp#785)."""

RETRY_OPTIONS: dict[str, dict[str, Any]] = {"osqp": {"adaptive_rho": False}}
"""Options of one second attempt when a backend finds no solution, over the first attempt's (a
``solver_options`` key wins). OSQP's adaptive step size stalls on a few steps with collision
constraints, where several rows are nearly parallel (one face of a link held against two bars)
and a joint sits at its limit: on the 93 steps of ``mbm:cage/0001-0020`` that took OSQP over 3000
iterations, 3 failed after 200,000 (70 ms each), while a fixed ``rho`` solved all 93 within 1,375
iterations (2.7e-6 rad/s from daqp's answer). On ordinary steps a fixed ``rho`` needs more
iterations (median 500 against 75), so it is the second attempt only."""


class QPFailure(StepFailure):
    """No valid step: the QP is infeasible or the solver failed. ``status`` is the plan status
    (``INFEASIBLE``), ``solver_status`` the backend's own word for it, ``info`` a JSON-friendly
    summary for the result."""

    def __init__(self, message: str, solver: str, solver_status: str) -> None:
        super().__init__(
            PlanStatus.INFEASIBLE,
            message,
            {"qp_failure": {"solver": solver, "solver_status": solver_status, "message": message}},
        )
        self.solver = solver
        self.solver_status = solver_status


class QPSolver:
    """One qpsolvers backend with its options; :meth:`solve` returns ``(qd, residual, seconds)``."""

    def __init__(self, name: str, options: dict[str, Any] | None = None, residual_tolerance: float = 1e-5) -> None:

        self._qpsolvers = qpsolvers
        self.name = name
        self.options = {**SOLVER_DEFAULTS.get(name, {}), **(options or {})}
        retry = RETRY_OPTIONS.get(name)
        self.retry_options = None if retry is None else {**self.options, **retry, **(options or {})}
        """The second attempt's options (:data:`RETRY_OPTIONS`), None for a backend without one."""
        self.residual_tolerance = residual_tolerance
        self._sparse = name in qpsolvers.sparse_solvers and name not in qpsolvers.dense_solvers
        if self._sparse:
            self._csc = csc_matrix

    def solve(self, qp: StepQP, joint_names: Any = None) -> tuple[np.ndarray, float, float]:
        """``(qd, violation before the projection, solver wall time [s])``; raises :class:`QPFailure`."""
        bad = infeasible_joints(qp.lb, qp.ub)
        if len(bad):
            j = int(bad[0])
            name = joint_names[j] if joint_names is not None else f"joint {j}"
            raise QPFailure(
                f"infeasible QP: no velocity of {name} keeps it within its velocity limit and inside its "
                f"position limits after one step (needs {qp.lb[j]:.4g} <= qd <= {qp.ub[j]:.4g} rad/s); "
                "the configuration is outside the joint limits by more than one step at full speed: "
                "start inside the limits",
                self.name,
                "infeasible (inconsistent bounds, found before the solver)",
            )
        P: np.ndarray | csc_matrix = qp.P
        G: np.ndarray | csc_matrix | None = qp.G
        if self._sparse:  # a sparse-only backend: convert here, silently, instead of in qpsolvers
            P = self._csc(P)
            G = None if G is None else self._csc(G)
        problem = self._qpsolvers.Problem(P, qp.c, G, qp.h, None, None, qp.lb, qp.ub)
        t0 = time.perf_counter()
        solution = self._call(problem, self.options)
        if not solution.found and self.retry_options is not None:
            solution = self._call(problem, self.retry_options)
        seconds = time.perf_counter() - t0
        x = solution.x
        if not solution.found or x is None or not np.all(np.isfinite(x)):
            status = _status(solution)
            raise QPFailure(f"QP solver {self.name!r} found no solution (status: {status})", self.name, status)
        violation = qp.violation(x)
        if violation > self.residual_tolerance:
            raise QPFailure(
                f"QP solver {self.name!r} returned a step that breaks the constraints by {violation:.3g} "
                f"(tolerance {self.residual_tolerance:g}); tighten its tolerances through solver_options",
                self.name,
                f"{_status(solution)}, violation {violation:.3g}",
            )
        return np.clip(x, qp.lb, qp.ub), violation, seconds

    def _call(self, problem: Any, options: dict[str, Any]) -> Any:
        """One backend call. qpsolvers' warning of a failed solve is silenced: the answer is
        checked here, and a failure becomes a :class:`QPFailure` with the backend's status."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                return self._qpsolvers.solve_problem(problem, solver=self.name, **options)
        except Exception as exc:  # any backend error is a named failure, not an escaping exception
            raise QPFailure(
                f"QP solver {self.name!r} raised {type(exc).__name__}: {exc}", self.name, f"error: {exc}"
            ) from exc


def _status(solution: Any) -> str:
    """The backend's status, as far as qpsolvers passes it on."""
    extras = getattr(solution, "extras", None) or {}
    info = extras.get("info") if isinstance(extras, dict) else None
    for source in (info, extras):
        for key in ("status", "exitflag", "status_val"):
            value = source.get(key) if isinstance(source, dict) else getattr(source, key, None)
            if value is not None:
                return str(value)
    return "no solution found" if not getattr(solution, "found", False) else "solved"
