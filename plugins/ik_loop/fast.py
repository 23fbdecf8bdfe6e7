"""One planner step's arithmetic in one call: a numba-compiled version and its numpy reference.

Python call overhead, not arithmetic, dominates a step with small arrays (a 6x6 solve costs
microseconds in numpy for nanoseconds of work). :func:`step_numpy` composes the task functions of
:mod:`.tasks` (readable, unit-tested term by term); :func:`step_compiled` does the same arithmetic
in one numba function (products and Cholesky factorisations written out, no BLAS call). Tests
check that both agree to rounding. ``backend="auto"`` uses numba when it is installed. The loop
calls the compiled step through :func:`bind` (no per-call type dispatch) and integrates with
``compiled().advance`` or :func:`advance_numpy`.

Inputs: ``S`` (6, n) spatial Jacobian, ``J`` (6, n) goal-frame Jacobian, ``p``, ``R`` its pose,
``q``, ``F`` (N, 3) repulsive velocities ``k_rep F(p_i)`` [m/s] at ``points`` (N, 3), ``tool``
(indices of the tool's points), ``prm`` (:class:`StepParams`). Outputs: ``qd`` (n,) after limits
and ``diag`` = [position error, orientation error, repulsion, manipulability, slow-down, damping].
With ``prm.priority`` (``hierarchy="priority"``) the step adds the repulsion rows' correction
(:func:`.tasks.push_correction`) to the null-space step before the limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from planbench_plugins.ik_loop import tasks as T
from planbench_plugins.ik_loop.config import resolve_hierarchy

__all__ = [
    "StepParams",
    "step_params",
    "step_numpy",
    "step_compiled",
    "advance_numpy",
    "bind",
    "compiled",
    "have_numba",
]


class StepParams(NamedTuple):
    """The settings one step reads, by name, in both backends (``prm.speed_max``). Built from a
    config by :func:`step_params`; the fields are the config's settings of the same name, except
    ``adaptive`` and the hierarchy's (``priority``, ``priority_onset``, ``priority_full``,
    ``orientation_weight``: resolved for the arm). numba types a NamedTuple of floats, so the
    compiled step reads the same names."""

    speed_max: float
    sigmoid_gain: float
    position_gain: float
    orientation_gain: float
    angular_speed_max: float
    manipulability_gain: float
    mid_joint_gain: float
    slowdown_gain: float
    slowdown_min: float
    adaptive: float
    """1.0 for ``damping="adaptive"``, 0.0 for ``"fixed"``."""
    damping_factor: float
    manipulability_threshold: float
    dt: float
    tool_repulsion_gain: float
    tool_fade_distance: float
    priority: float
    """1.0 for the ``"priority"`` hierarchy (``hierarchy`` resolved for the arm), 0.0 for ``"nullspace"``."""
    priority_onset: float
    """Push ratio where the repulsion rows switch on (``priority_onset``, or 0 on an arm without
    redundancy)."""
    priority_full: float
    """Push ratio where they are fully on (``priority_full``, or 1 as for ``priority_onset``)."""
    priority_weight: float
    priority_fade_distance: float
    orientation_weight: float
    """Weight of the orientation rows in the ``"priority"`` stack: ``orientation_priority`` on an
    arm without redundancy (6 joints or fewer), else 1."""


_RESOLVED = ("adaptive", "priority", "priority_onset", "priority_full", "orientation_weight")


def step_params(cfg: Any, n_joints: int, redundant: str = "nullspace") -> StepParams:
    """The :class:`StepParams` of a config (:class:`~planbench_plugins.ik_loop.config.IKLoopConfig`)
    for an arm of ``n_joints`` joints: the hierarchy's fields resolved for the arm, ``redundant``
    what ``hierarchy="auto"`` is on a redundant one
    (:func:`~planbench_plugins.ik_loop.config.resolve_hierarchy`)."""
    h = resolve_hierarchy(cfg, n_joints, redundant)
    settings = {name: float(getattr(cfg, name)) for name in StepParams._fields if name not in _RESOLVED}
    return StepParams(
        adaptive=float(cfg.damping == "adaptive"),
        priority=float(h.mode == "priority"),
        priority_onset=h.onset,
        priority_full=h.full,
        orientation_weight=h.orientation_weight,
        **settings,
    )


def have_numba() -> bool:
    import importlib.util

    return importlib.util.find_spec("numba") is not None


_FLOOR2 = 1e-18  # (1e-9 m)^2 added to the DLS matrix: defined at an exact singularity


def step_numpy(
    S,
    J,
    p,
    R,
    p_goal,
    R_goal,
    q,
    lower,
    upper,
    qd_max,
    points,
    F,
    support,
    descendants,  # type: ignore[no-untyped-def]
    tool,
    prm,
    qd_out,
    diag,
) -> None:
    """The reference step, composed of the :mod:`.tasks` functions."""
    err_p, err_r, v, x, m, lam, s, mag = _terms(
        S, p, R, p_goal, R_goal, q, lower, upper, points, F, support, descendants, tool, prm
    )
    qd1, nx = T.dls_with_nullspace(J, v, x, lam)
    qd = T.merge(qd1, s, nx)
    if prm.priority:
        qd = qd + _push(S, J, qd, lam, points, F, support, mag, err_p, prm)
    qd, _ = T.scale_to_velocity_limits(qd, qd_max)
    qd_out[:] = T.clamp_to_position_limits(q, qd, lower, upper, prm.dt)
    diag[:] = (err_p, err_r, float(mag.max()) if len(mag) else 0.0, m, s, lam)


def _terms(S, p, R, p_goal, R_goal, q, lower, upper, points, F, support, descendants, tool, prm):  # type: ignore[no-untyped-def]
    """The task terms of every step: ``(err_p, err_r, v, x, m, lam, s, |f_i|)`` with ``v`` the
    attraction (plus the tool's push), ``x`` the secondary velocity (mid-joint, manipulability,
    repulsion), ``m`` the manipulability, ``lam`` the damping and ``s`` the slow-down."""
    e = p_goal - p
    err_p = math.sqrt(float(e @ e))
    err_r = float(np.linalg.norm(T.orientation_error(R, R_goal)))
    v = T.attraction(
        p,
        R,
        p_goal,
        R_goal,
        speed_max=prm.speed_max,
        sigmoid_gain=prm.sigmoid_gain,
        position_gain=prm.position_gain,
        orientation_gain=prm.orientation_gain,
        angular_speed_max=prm.angular_speed_max,
    )
    x = T.mid_joint_velocity(q, lower, upper, prm.mid_joint_gain)
    m, grad = T.manipulability_gradient(S, descendants)
    if prm.manipulability_gain > 0:
        x = x + prm.manipulability_gain * grad
    mag = np.sqrt(np.einsum("ij,ij->i", F, F)) if len(F) else np.zeros(0)
    rep = float(mag.max()) if len(mag) else 0.0
    if rep > 0:
        x = x + T.repulsion_joint_velocity(S, points, F, support)
        if prm.tool_repulsion_gain > 0:
            fade = min(1.0, err_p / prm.tool_fade_distance)
            v[:3] += (prm.tool_repulsion_gain * fade) * T.strongest(F, tool)
    lam_max = prm.damping_factor
    lam = T.adaptive_damping(m, lam_max, prm.manipulability_threshold) if prm.adaptive else lam_max
    s = T.slowdown_factor(rep, prm.slowdown_gain, prm.slowdown_min) if prm.slowdown_gain > 0 else 1.0
    return err_p, err_r, v, x, m, lam, s, mag


def _push(S, J, qd, lam, points, F, support, mag, err_p, prm):  # type: ignore[no-untyped-def]
    """The ``"priority"`` hierarchy's correction of the null-space step ``qd`` (before limits):
    the points with a non-zero activation (:func:`.tasks.priority_activation`) pushed away
    against the pose task (:func:`.tasks.push_correction`)."""
    a = T.priority_activation(
        mag,
        err_p,
        speed_max=prm.speed_max,
        onset=prm.priority_onset,
        full=prm.priority_full,
        fade=prm.priority_fade_distance,
    )
    active = np.flatnonzero(a > 0)
    if not len(active):
        return np.zeros_like(qd)
    rows = T.repulsion_rows(S, points[active], F[active], support[active])
    return T.push_correction(
        J,
        rows,
        mag[active],
        a[active],
        qd,
        weight=prm.priority_weight,
        orientation_weight=prm.orientation_weight,
        damping2=lam * lam,
    )


def advance_numpy(
    q: np.ndarray, qd: np.ndarray, dt: float, lower: np.ndarray, upper: np.ndarray, path: np.ndarray, k: int
) -> None:
    """The loop's integration, ``q <- clip(q + qd dt, lower, upper)`` in place, recorded as ``path[k]``."""
    np.clip(q + qd * dt, lower, upper, out=q)
    path[k] = q


def compiled() -> ModuleType:
    """The compiled functions (:mod:`._compiled`: ``step``, ``kinematics``, ``advance``). Imported
    on first use: numba is optional, and importing it costs start-up that the numpy path does not
    need. Each function compiles, or loads numba's on-disk cache, on its first call."""
    from planbench_plugins.ik_loop import _compiled

    return _compiled


def bind(dispatcher: Any, *args: Any) -> Callable[..., Any]:
    """The compiled code of the numba function ``dispatcher`` for exactly the types of ``args``,
    as a plain function that skips numba's per-call type dispatch.

    numba works out the type of every argument on every call (about 50 ns per array, about 1 us
    for a NamedTuple such as :class:`StepParams`): with the step's 18 arguments that costs more
    than the step's arithmetic. The returned function must be called with arguments of the same
    types as ``args`` (dtype, dimensions, layout; the same arrays, typically): it does not check.
    Compiles, or loads numba's cache, now."""
    import numba  # numba is optional: only the compiled path binds, and it has imported numba already

    return dispatcher.compile(tuple(numba.typeof(a) for a in args))  # type: ignore[no-any-return]


def step_compiled(*args: Any) -> None:
    """Same signature and results as :func:`step_numpy`, in one numba call (the loop calls
    ``compiled().step`` directly, without this wrapper)."""
    compiled().step(*args)
