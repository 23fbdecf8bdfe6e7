"""VAMP's RRT-Connect as a planbench baseline (``vamp-rrtc``).

VAMP: W. Thomason, Z. Kingston, L. E. Kavraki, "Motions in Microseconds via Vectorized
Sampling-Based Planning", ICRA 2024 (arXiv:2309.14545); its collision checks test a sphere model of
the robot against the obstacles, several configurations at once in SIMD lanes.

Only RRT-Connect is offered: VAMP's FCIT* (tried the same way, stopped at its first solution) took a
median 755 ms of VAMP's own time on MotionBenchMaker ``cage/0001-0010`` against RRT-Connect's
0.2 ms, and 7 of its 10 paths failed planbench's certified check.

How a query runs:

- ``setup`` (untimed, like every planner's collision checker): VAMP's model of the robot
  (:func:`.convert.vamp_robot`: only the Panda and the UR5; any other robot raises
  :class:`.convert.UnsupportedRobotError`) and the scene as VAMP primitives
  (:func:`.convert.environment`).
- ``plan`` (timed): the goal configuration (a pose-only goal, or a goal configuration outside
  planbench's joint limits, is ``INVALID_GOAL``: VAMP plans to configurations); the start and the
  goal checked in VAMP's own model (``INVALID_START`` / ``INVALID_GOAL`` when its spheres touch an
  obstacle); VAMP's sampler (``halton`` or ``xorshift``) advanced by an offset drawn from the
  ``rng`` (VAMP exposes no seed: the offset, below ``seed_offsets``, is what makes seeds differ);
  the search; VAMP's simplification (``simplify``); then VAMP's own verdict on the path it returns
  (its motion check of every segment, ``info["vamp_verdict"]``: ``"free"`` or ``"collision"``).
  The path is VAMP's, in float64 with its first and last rows set to the exact start and goal
  (VAMP works in float32). It is *not* repaired or certified by the plugin: the harness certifies
  it like every planner's path, so a VAMP path that touches the true geometry (or leaves
  planbench's joint limits: VAMP samples within its own, the Panda's wider robowflex limits) is
  counted as planbench refusing it.

VAMP has no wall-clock limit: a query ends when it finds a path or after ``max_iterations``
(``STEP_LIMIT``); an answer after the time limit is the harness's ``TIMEOUT``, as for any planner.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import vamp

from planbench.errors import InvalidConfigError
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem

from .convert import CYLINDER_MODES, SUPPORTED_ROBOTS, VampRobot, environment, vamp_robot

__all__ = ["VampConfig", "VampPlanner", "VampRRTCPlanner", "own_verdict"]

SAMPLERS = ("halton", "xorshift")
GOAL_SNAP = 1e-5  # [rad] VAMP's float32 end points within this of the goal are set to it exactly


@dataclass(frozen=True)
class VampConfig:
    """Settings of the VAMP planners."""

    simplify: bool = True
    """Shorten the path with VAMP's simplification (its default routine: shortcuts, then B-spline
    smoothing, 5 rounds) before returning it."""
    range: float = 0.0
    """RRT-Connect's longest extension [rad]; 0: VAMP's choice for the robot (Panda 1.0, UR5 1.5).
    ``vamp-rrtc`` only."""
    max_iterations: int = 100_000
    """Iterations (and samples) the search may spend before it gives up (``STEP_LIMIT``)."""
    sampler: str = "halton"
    """VAMP's sampler: ``"halton"`` (its default, a Halton sequence) or ``"xorshift"`` (SIMD
    pseudo-random numbers)."""
    seed_offsets: int = 1024
    """The ``rng`` picks how many of the sampler's first values to skip, below this number: what
    makes two seeds differ (VAMP's samplers take no seed). 1: every seed plans the same."""
    cylinders: str = "box"
    """How a cylinder becomes a VAMP primitive: ``"box"`` (its bounding box) or ``"capsule"``
    (VAMP's own; longer by the radius at both ends). Both hold the cylinder. ``"box"`` by default:
    with capsules 13 of MotionBenchMaker's ``box/0001-0020`` goals touch the can's caps in VAMP's
    model (``INVALID_GOAL``), with boxes none (VAMP's own MotionBenchMaker script boxes the
    cylinders of that family for the same reason)."""
    mesh_spacing: float = 0.01
    """A mesh obstacle becomes points on its surface this far apart at most [m], each of radius
    0.6 x the spacing (see :mod:`.convert`)."""

    def __post_init__(self) -> None:
        if self.sampler not in SAMPLERS:
            raise InvalidConfigError(f"sampler must be one of {SAMPLERS}, got {self.sampler!r}")
        if self.cylinders not in CYLINDER_MODES:
            raise InvalidConfigError(f"cylinders must be one of {CYLINDER_MODES}, got {self.cylinders!r}")
        if not (isinstance(self.range, (int, float)) and math.isfinite(self.range) and self.range >= 0):
            raise InvalidConfigError(f"range must be >= 0 [rad] (0: VAMP's choice), got {self.range!r}")
        for name in ("max_iterations", "seed_offsets"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise InvalidConfigError(f"{name} must be an integer >= 1, got {v!r}")
        v = self.mesh_spacing
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InvalidConfigError(f"mesh_spacing must be > 0 [m], got {v!r}")


def own_verdict(module: Any, path: np.ndarray, env: Any) -> bool:
    """VAMP's own collision verdict on ``path`` (N, nq): every segment passes its motion check."""
    q = np.asarray(path, dtype=np.float32)
    return all(module.validate_motion(q[k], q[k + 1], env, False) for k in range(len(q) - 1))


class VampPlanner(Planner):
    """A VAMP planner on a planbench problem (module docstring); subclasses name the planner."""

    Config: ClassVar[Any] = VampConfig
    vamp_planner: ClassVar[str] = ""
    robots: ClassVar[tuple[str, ...]] = SUPPORTED_ROBOTS
    """The planbench robots these planners plan for (others: :class:`.convert.UnsupportedRobotError`)."""

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self._problem: Problem | None = None
        self._robot: VampRobot | None = None
        self._env: Any = None
        self._counts: dict[str, int] = {}

    def setup(self, problem: Problem) -> None:
        """VAMP's model of the robot and the scene as VAMP primitives (untimed)."""
        self._prepare(problem)

    def _prepare(self, problem: Problem) -> tuple[VampRobot, Any]:
        if self._problem is not problem or self._robot is None:
            robot = vamp_robot(problem.robot)
            c = self.config
            self._env, self._counts = environment(
                problem.scene, robot, cylinders=c.cylinders, mesh_spacing=c.mesh_spacing
            )
            self._robot, self._problem = robot, problem
        return self._robot, self._env

    def settings(self, robot: VampRobot) -> Any:
        """The VAMP settings object of the planner (its search limits set)."""
        raise NotImplementedError

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        robot, env = self._prepare(problem)
        module, c = robot.module, self.config
        info: dict[str, Any] = {"vamp_planner": self.vamp_planner, "vamp_robot": robot.name, **self._counts}

        def result(status: PlanStatus, path: np.ndarray | None = None, message: str = "") -> PlanResult:
            return PlanResult(status, path, None, "configuration", message, info)

        if problem.goal.q is None:
            return result(PlanStatus.INVALID_GOAL, message="VAMP plans to a goal configuration; this goal is a pose")
        goal = np.array(problem.goal.q, dtype=float)
        bad = problem.robot.limit_violations(goal)
        if bad:
            return result(
                PlanStatus.INVALID_GOAL, message="goal configuration outside the joint limits: " + "; ".join(bad)
            )
        start32, goal32 = problem.start.astype(np.float32), goal.astype(np.float32)
        if not module.validate(start32, env):
            return result(PlanStatus.INVALID_START, message="start in collision in VAMP's sphere model")
        if not module.validate(goal32, env):
            return result(PlanStatus.INVALID_GOAL, message="goal in collision in VAMP's sphere model")
        sampler = getattr(module, c.sampler)()
        offset = int(rng.integers(c.seed_offsets))
        sampler.skip(offset)
        info["sampler_offset"] = offset
        found = getattr(module, self.vamp_planner)(start32, goal32, env, self.settings(robot), sampler)
        info["vamp_search_time"] = found.nanoseconds * 1e-9
        info["iterations"] = int(found.iterations)
        if not found.solved:
            return result(
                PlanStatus.STEP_LIMIT,
                message=f"VAMP {self.vamp_planner} found no path in {c.max_iterations} iterations",
            )
        path = found.path
        if c.simplify:
            simple = module.simplify(path, env, vamp.SimplifySettings(), sampler)
            info["vamp_simplify_time"] = simple.nanoseconds * 1e-9
            path = simple.path
        q = np.asarray(path.numpy(), dtype=float)
        t0 = time.perf_counter()
        info["vamp_verdict"] = "free" if own_verdict(module, q, env) else "collision"
        info["vamp_verdict_time"] = time.perf_counter() - t0
        q[0] = problem.start
        if np.abs(q[-1] - goal).max() < GOAL_SNAP:
            q[-1] = goal
        return result(PlanStatus.SUCCESS, q)


class VampRRTCPlanner(VampPlanner):
    """VAMP's RRT-Connect (with its dynamic-domain sampling, VAMP's default)."""

    name = "vamp-rrtc"
    vamp_planner = "rrtc"

    def settings(self, robot: VampRobot) -> Any:
        s = vamp.RRTCSettings()
        c = self.config
        s.range = float(c.range) if c.range > 0 else float(vamp.ROBOT_RRT_RANGES.get(robot.name, s.range))
        s.max_iterations = s.max_samples = c.max_iterations
        return s
