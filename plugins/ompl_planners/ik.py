"""Goal configurations for a pose-only goal: a small IK sampler.

OMPL plans between configurations, so a goal given only as an end-effector pose is turned into a
set of goal configurations first. The sampler: damped least squares on the 6D pose error (the SE3
log of ``M_goal^-1 M(q)``, in the local frame), from the given ``seeds`` first (e.g. a goal
configuration outside the joint limits, clipped to them), then from random joint configurations
drawn uniformly within the limits with the planner's ``rng``, at most ``iterations`` steps per attempt, joints
clipped to their limits after each step. An attempt counts when the pose is within the problem's
position and orientation tolerances (at a tenth of them, so that round-off on the way does not
matter) and the configuration is collision-free. Sampling stops at ``n_goals`` configurations or when
its time budget is spent. Not complete: a reachable pose may yield no goal within the budget.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

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
) -> list[np.ndarray]:
    """Collision-free configurations reaching ``problem.goal.pose`` (see the module docstring).

    ``time_budget`` [s]; ``damping`` [-] of the least-squares step; ``seeds``: initial guesses tried
    first, one attempt each (within the limits).
    """
    import pinocchio as pin

    robot = problem.robot
    model = robot.model
    data = model.createData()
    pose = problem.goal.pose
    fid = robot.frame_id(pose.frame)
    target = pose.se3()
    tol = problem.tolerances
    pos_tol, rot_tol = 0.1 * tol.position, 0.1 * tol.orientation
    deadline = time.perf_counter() + time_budget
    found: list[np.ndarray] = []
    eye = np.eye(6)
    guesses = [np.clip(np.asarray(x, dtype=float), robot.lower, robot.upper) for x in seeds]
    while len(found) < n_goals and time.perf_counter() < deadline:
        q = guesses.pop(0) if guesses else rng.uniform(robot.lower, robot.upper)
        for _ in range(iterations):
            pin.framesForwardKinematics(model, data, q)
            err = pin.log6(target.actInv(data.oMf[fid])).vector
            if np.linalg.norm(err[:3]) < pos_tol and np.linalg.norm(err[3:]) < rot_tol:
                break
            J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
            J = pin.Jlog6(target.actInv(data.oMf[fid])) @ J
            dq = -J.T @ np.linalg.solve(J @ J.T + damping * eye, err)
            q = np.clip(q + dq, robot.lower, robot.upper)
        pos_err, rot_err = pose_error(robot, q, pose)
        if pos_err <= pos_tol and rot_err <= rot_tol and not in_collision(q):
            found.append(q)
    return found
