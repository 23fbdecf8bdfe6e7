"""Goal configurations for a pose-only goal: a small IK sampler.

OMPL plans between configurations, so a goal given only as an end-effector pose is turned into a
set of goal configurations first. The sampler: damped least squares on the 6D pose error (the SE3
log of ``M_goal^-1 M(q)``, in the local frame), from the given ``seeds`` first (e.g. a goal
configuration just outside the joint limits, clipped to them), then from random configurations
drawn uniformly within the limits with the planner's ``rng``; at most ``iterations`` steps per
attempt, each at most ``max_step`` [rad] per joint (an attempt stays near its initial guess), joints
clipped to their limits after each step. A joint at a limit that the step would push further out is
locked for that step (its Jacobian column zeroed, the step solved again), so that the other joints
make up for it instead of the clipping undoing the step.

An attempt counts when its pose is within a tenth of the problem's position and orientation
tolerances, or, when it stalls (e.g. with a joint held at its limit), within half of them, and the
configuration is collision-free. The path ends exactly at that configuration, so its final pose is
the one checked here. Sampling stops at ``n_goals`` configurations or when its time budget is spent.
Not complete: a reachable pose may yield no goal within the budget.

With these rules, the 4 MotionBenchMaker goal configurations outside the Panda's joint-4 limits
(``table_pick/0031``, ``/0049``, ``table_under_pick/0003``, ``/0097``) all give goal configurations
within 1.1 s; with plain clipping and a tenth of the tolerances only, ``table_under_pick/0097`` gave
none (the attempt from its clipped configuration wandered 3 rad off, into the table).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import pinocchio as pin

from planbench.problem import Problem, pose_error

__all__ = ["sample_goal_configurations"]


def sample_goal_configurations(
    problem: Problem,
    in_collision: Callable[[np.ndarray], bool],
    rng: np.random.Generator,
    n_goals: int,
    time_budget: float,
    iterations: int = 200,
    damping: float = 1e-3,
    seeds: Sequence[np.ndarray] = (),
    max_step: float = 0.2,
    clock: Callable[[], float] = time.perf_counter,
) -> list[np.ndarray]:
    """Collision-free configurations reaching ``problem.goal.pose`` (see the module docstring).

    ``time_budget`` [s]; ``damping`` [-] of the least-squares step; ``seeds``: initial guesses tried
    first, one attempt each (within the limits); ``max_step`` [rad]: largest joint step per iteration
    (keeps an attempt near its initial guess); ``clock``: what ``time_budget`` counts (elapsed time,
    or the process's CPU time for a controller's plan).
    """

    robot = problem.robot
    model = robot.model
    data = model.createData()
    pose = problem.goal.pose
    fid = robot.frame_id(pose.frame)
    target = pose.se3()
    tol = problem.tolerances
    pos_tol, rot_tol = 0.1 * tol.position, 0.1 * tol.orientation
    deadline = clock() + time_budget
    found: list[np.ndarray] = []
    eye = np.eye(6)
    guesses = [np.clip(np.asarray(x, dtype=float), robot.lower, robot.upper) for x in seeds]
    while len(found) < n_goals and clock() < deadline:
        q = guesses.pop(0) if guesses else rng.uniform(robot.lower, robot.upper)
        for _ in range(iterations):
            pin.framesForwardKinematics(model, data, q)
            err = pin.log6(target.actInv(data.oMf[fid])).vector
            if np.linalg.norm(err[:3]) < pos_tol and np.linalg.norm(err[3:]) < rot_tol:
                break
            J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
            J = pin.Jlog6(target.actInv(data.oMf[fid])) @ J
            dq = -J.T @ np.linalg.solve(J @ J.T + damping * eye, err)
            locked = ((q <= robot.lower) & (dq < 0)) | ((q >= robot.upper) & (dq > 0))
            if locked.any():
                J[:, locked] = 0.0
                dq = -J.T @ np.linalg.solve(J @ J.T + damping * eye, err)
            dq *= min(1.0, max_step / max(float(np.abs(dq).max()), 1e-300))
            q = np.clip(q + dq, robot.lower, robot.upper)
        pos_err, rot_err = pose_error(robot, q, pose)
        # converged (a tenth of the tolerances), or stalled within half of them (a joint at its limit)
        if pos_err <= 5 * pos_tol and rot_err <= 5 * rot_tol and not in_collision(q):
            found.append(q)
    return found
