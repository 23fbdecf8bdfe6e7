"""Plots of a field planner's plan (matplotlib, headless; every function returns a Figure).

Any planner built on the shared IK loop (:class:`~planbench_plugins.ik_loop.loop.IKLoopPlanner`:
``matrix-field``, ``matrix-field-qp``, ``edt-field``, ``distance-field``) can be drawn.

- :func:`plot_arm_field`: the arm at one configuration, the points where the repulsion acts and
  the repulsive vectors there (the paper's "kernel on robot" figure).
- :func:`plot_ee_path`: the end-effector path among the obstacles.
- :func:`plot_diagnostics`: pose errors, repulsion, slow-down and manipulability over time.
- :func:`plot_result`: the three side by side (what ``planbench plan ... --plot out.png`` draws).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin
from matplotlib.figure import Figure

from planbench.planner import PlanResult
from planbench.problem import Problem

if TYPE_CHECKING:  # the loop imports this module on use (its plot_result): no import back at run time
    from planbench_plugins.ik_loop.loop import IKLoopPlanner

__all__ = ["plot_result", "plot_arm_field", "plot_ee_path", "plot_diagnostics"]

_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


def _obstacles(ax: Any, problem: Problem) -> None:
    for ob in problem.scene.obstacles:
        lo, hi = ob.aabb()
        c = lo + np.array(list(np.ndindex(2, 2, 2))) * (hi - lo)
        for a, b in _EDGES:
            ax.plot(*zip(c[a], c[b], strict=True), color="0.45", lw=0.7)


def _joint_chain(problem: Problem, q: np.ndarray) -> np.ndarray:

    model = problem.robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    pts = [data.oMi[j].translation.copy() for j in range(model.njoints)]
    pts.append(problem.robot.frame_pose(q).translation.copy())
    return np.array(pts)


def _equal(ax: Any, pts: np.ndarray) -> None:
    lo, hi = pts.min(0), pts.max(0)
    c, r = 0.5 * (lo + hi), 0.5 * float((hi - lo).max()) + 0.05
    ax.set(
        xlim=(c[0] - r, c[0] + r),
        ylim=(c[1] - r, c[1] + r),
        zlim=(c[2] - r, c[2] + r),
        xlabel="x [m]",
        ylabel="y [m]",
        zlabel="z [m]",
    )


def _prepared(problem: Problem, planner: IKLoopPlanner) -> IKLoopPlanner:
    if planner.problem is not problem:
        planner.setup(problem)
    return planner


def plot_arm_field(
    problem: Problem,
    q: np.ndarray,
    planner: IKLoopPlanner,
    ax: Any = None,
    out: str | Path | None = None,
) -> Figure:
    """The arm at ``q`` (joint chain), the points where the repulsion acts, the repulsive
    velocities ``f_i`` [m/s] there (drawn as 0.2 s of motion) and the obstacles' boxes.
    ``planner``: the loop planner whose repulsion is drawn (set up for ``problem`` if needed)."""
    planner = _prepared(problem, planner)
    fig = ax.figure if ax is not None else Figure(figsize=(6, 6), layout="constrained")
    ax = ax if ax is not None else fig.add_subplot(projection="3d")
    q = np.asarray(q, dtype=float)
    chain = _joint_chain(problem, q)
    pts, f = planner.repulsion_at(q)
    _obstacles(ax, problem)
    ax.plot(*chain.T, "-o", color="tab:blue", ms=3, lw=2, label="arm (joint origins)")
    ax.scatter(*pts.T, color="tab:orange", s=14, label=f"{len(pts)} repulsion points")
    mag = np.linalg.norm(f, axis=1) if len(f) else np.zeros(1)
    if mag.max() > 0:
        ax.quiver(*pts.T, *(0.2 * f).T, color="tab:red", lw=1.2, label="repulsion (0.2 s of motion)")
    ax.set_title(f"arm, control points, repulsion (max {mag.max():.2f} m/s)")
    ax.legend(loc="upper left", fontsize=7)
    _equal(ax, np.vstack([chain, pts]))
    return _save(fig, out)


def plot_ee_path(problem: Problem, result: PlanResult, ax: Any = None, out: str | Path | None = None) -> Figure:
    """End-effector positions along the path, start and goal, among the obstacles' boxes."""
    fig = ax.figure if ax is not None else Figure(figsize=(6, 6), layout="constrained")
    ax = ax if ax is not None else fig.add_subplot(projection="3d")
    robot = problem.robot
    ee = np.zeros((0, 3))
    if result.path is not None:
        ee = np.array([robot.frame_pose(q).translation for q in result.path])
    _obstacles(ax, problem)
    if len(ee):
        ax.plot(*ee.T, color="tab:green", lw=2, label="end effector")
        ax.scatter(*ee[0], color="k", s=20, label="start")
    ax.scatter(*problem.goal.pose.position, color="tab:red", marker="*", s=80, label="goal")
    ax.set_title(f"end-effector path ({result.status.value})")
    ax.legend(loc="upper left", fontsize=7)
    _equal(ax, np.vstack([ee, problem.goal.pose.position[None]]) if len(ee) else problem.goal.pose.position[None])
    return _save(fig, out)


def plot_diagnostics(result: PlanResult, ax: Any = None, out: str | Path | None = None) -> Figure:
    """Position error [m], orientation error [rad], repulsion [m/s] and slow-down over time [s]."""
    fig = ax.figure if ax is not None else Figure(figsize=(6, 4), layout="constrained")
    ax = ax if ax is not None else fig.add_subplot()
    info, t = result.info, result.times
    if t is None or "position_error" not in info:
        ax.text(0.5, 0.5, "no diagnostics", ha="center")
        return _save(fig, out)
    ax.plot(t, info["position_error"], label="position error [m]")
    ax.plot(t, info["orientation_error"], label="orientation error [rad]")
    ax.plot(t, info["repulsion"], label="repulsion max |f_i| [m/s]")
    ax.plot(t, info["slowdown"], "--", label="slow-down s [-]")
    ax.set(xlabel="t [s]", title="errors and repulsion over time", yscale="symlog", ylim=(0, None))
    ax.set_yscale("symlog", linthresh=1e-2)
    ax.legend(fontsize=7)
    return _save(fig, out)


def plot_result(
    problem: Problem,
    result: PlanResult,
    path_png: str | Path | None = None,
    *,
    planner: IKLoopPlanner,
    step: int | None = None,
) -> Figure:
    """Arm with control points and repulsion at ``step`` (default: the step of strongest
    repulsion), the end-effector path, and the diagnostics; written to ``path_png`` when given."""
    fig = Figure(figsize=(17, 5.5), layout="constrained")
    ax1 = fig.add_subplot(1, 3, 1, projection="3d")
    ax2 = fig.add_subplot(1, 3, 2, projection="3d")
    ax3 = fig.add_subplot(1, 3, 3)
    path = result.path if result.path is not None else np.asarray(problem.start)[None]
    if step is None:
        rep = np.asarray(result.info.get("repulsion", np.zeros(len(path))), dtype=float)
        step = int(np.nanargmax(rep)) if np.any(np.nan_to_num(rep) > 0) else 0
    plot_arm_field(problem, path[min(step, len(path) - 1)], planner, ax=ax1)
    ax1.set_title(f"step {step}: " + ax1.get_title())
    plot_ee_path(problem, result, ax=ax2)
    plot_diagnostics(result, ax=ax3)
    return _save(fig, path_png)


def _save(fig: Figure, out: str | Path | None) -> Figure:
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110)
    return fig
