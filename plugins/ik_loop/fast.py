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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from planbench_plugins.ik_loop import tasks as T

__all__ = [
    "StepParams",
    "step_params",
    "Priority",
    "step_priority",
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
    ``adaptive``. numba types a NamedTuple of floats, so the compiled step reads the same names."""

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


def step_params(cfg: Any) -> StepParams:
    """The :class:`StepParams` of a config (:class:`~planbench_plugins.ik_loop.config.IKLoopConfig`)."""
    settings = {name: float(getattr(cfg, name)) for name in StepParams._fields if name != "adaptive"}
    return StepParams(adaptive=float(cfg.damping == "adaptive"), **settings)


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
    qd, _ = T.scale_to_velocity_limits(T.merge(qd1, s, nx), qd_max)
    qd_out[:] = T.clamp_to_position_limits(q, qd, lower, upper, prm.dt)
    diag[:] = (err_p, err_r, float(mag.max()) if len(mag) else 0.0, m, s, lam)


def _terms(S, p, R, p_goal, R_goal, q, lower, upper, points, F, support, descendants, tool, prm):  # type: ignore[no-untyped-def]
    """The task terms every numpy step shares: ``(err_p, err_r, v, x, m, lam, s, |f_i|)`` with ``v``
    the attraction (plus the tool's push), ``x`` the secondary velocity (mid-joint, manipulability,
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


_PRIORITY_FLOOR2 = 1e-6  # (1 mm)^2: the stacked task's least squares stays defined at any rank


class Priority(NamedTuple):
    """The ``"priority"`` hierarchy's settings (:class:`~.config.IKLoopConfig`), resolved for one arm."""

    onset: float
    full: float
    weight: float
    orientation: float
    """Weight of the orientation rows (``orientation_priority`` without redundancy, else 1)."""
    fade: float
    """[m] the rows' weights fade linearly to 0 within this position error of the goal."""


def step_priority(
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
    descendants,
    tool,
    prm,
    qd_out,
    diag,
    priority: Priority,
) -> None:  # type: ignore[no-untyped-def]
    """:func:`step_numpy` with the repulsion also as weighted task rows beside the pose task
    (``hierarchy="priority"``): row ``i`` asks point ``i`` to move along its push at ``|f_i|``, with
    weight ``weight * smoothstep((|f_i| / speed_max - onset) / (full - onset))``, faded to 0 within
    ``fade`` of the goal (a grasp next to an object stays reachable); the orientation
    rows are weighted by ``orientation``. The rows, the pose task and the damping form one damped
    least squares; the secondary tasks (repulsion, manipulability, mid-joint) stay in the null
    space of the stack. Numpy only (the compiled step has the null-space hierarchy)."""
    err_p, err_r, v, x, m, lam, s, mag = _terms(
        S, p, R, p_goal, R_goal, q, lower, upper, points, F, support, descendants, tool, prm
    )
    rep = float(mag.max()) if len(mag) else 0.0
    row_w = np.sqrt(np.diag([1.0, 1.0, 1.0] + [priority.orientation] * 3))
    A, b = row_w @ J, row_w @ (s * v)
    span = priority.full - priority.onset
    near = min(1.0, err_p / priority.fade)  # goals next to obstacles stay reachable
    weights = np.array(
        [near * priority.weight * T.smoothstep((f / prm.speed_max - priority.onset) / span) for f in mag]
    )
    active = np.flatnonzero(weights > 0)
    if len(active):
        rows = T.repulsion_rows(S, points[active], F[active], support[active])
        root = np.sqrt(weights[active])
        A = np.vstack((A, root[:, None] * rows))
        b = np.concatenate((b, root * mag[active]))
    # joint-space normal equations: the stack may have more rows than joints (rank-deficient A A^T)
    H = A.T @ A
    H.flat[:: H.shape[0] + 1] += lam * lam + _PRIORITY_FLOOR2
    sol = np.linalg.solve(H, np.stack((A.T @ b, H @ x - (lam * lam + _PRIORITY_FLOOR2) * x), axis=1))
    qd1, nx = sol[:, 0], x - sol[:, 1]
    qd, _ = T.scale_to_velocity_limits(qd1 + nx, qd_max)
    qd_out[:] = T.clamp_to_position_limits(q, qd, lower, upper, prm.dt)
    diag[:] = (err_p, err_r, rep, m, s, lam)


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
