"""The conformance checker plugin authors run on their planner: ``check_planner(MyPlanner)``.

It returns a list of problems found (empty: conformant). It checks the interface (a kebab-case
name, a dataclass ``Config`` constructible from its defaults, ``setup``/``plan``) and behaviour on
small problems: a ``PlanResult`` with a well-formed path that starts at the start, a claim of
success that the harness's validation confirms, a trivial free-space problem solved, the same path
for the same seed, and the time limit respected.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.harness import plan
from planbench.planner import PlanResult, PlanStatus
from planbench.problem import Problem
from planbench.registry import NAME_PATTERN, REGISTRY
from planbench.robot import load_robot
from planbench.scene import Obstacle, Scene
from planbench.validate import evaluate

__all__ = ["check_planner", "trivial_problem", "blocked_problem"]


def trivial_problem(robot_name: str = "panda") -> Problem:
    """Free space, goal 0.3 rad from home on every joint (kept inside the limits)."""
    robot = load_robot(robot_name)
    goal = np.clip(robot.home + 0.3, robot.lower + 0.05, robot.upper - 0.05)
    return Problem.create(robot, Scene(name="empty"), robot.home, goal, id="conformance:trivial")


def blocked_problem(robot_name: str = "panda") -> Problem:
    """The trivial problem with a thin wall across the straight line's end-effector sweep."""
    base = trivial_problem(robot_name)
    robot = base.robot
    a = robot.frame_pose(base.start).translation
    b = robot.frame_pose(base.goal.q).translation  # type: ignore[arg-type]
    mid = 0.5 * (a + b)
    wall = Obstacle("wall", "box", position=tuple(mid), size=(0.02, 0.02, 0.02))
    return Problem.create(robot, Scene((wall,), name="blocked"), base.start, base.goal.q, id="conformance:blocked")


def check_planner(
    planner: Any, config: Any = None, problems: list[Problem] | None = None, time_limit: float = 2.0, seed: int = 0
) -> list[str]:
    """Problems found with ``planner`` (a class, or a registered name); empty when conformant.

    ``config`` is a ``Config`` instance to check it with (default: its defaults, built as every
    planner is, by :meth:`~planbench.registry.Registry.configure`). ``problems`` default: a trivial
    free-space problem (must be solved) and a problem with a small obstacle on the straight line's
    way (any status is fine, but a success must validate).
    """
    found: list[str] = []
    _, cls, implied = REGISTRY.resolve(planner)
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        found.append(f"'name' must be a kebab-case string like 'my-planner', got {name!r}")
    Config: Any = getattr(cls, "Config", None)
    if Config is None or not dataclasses.is_dataclass(Config):
        found.append("'Config' must be a dataclass of the planner's settings (units in its docstrings)")
    elif config is None:
        try:
            config = REGISTRY.configure(planner).config
        except InvalidConfigError as exc:
            what = "Config() must work with defaults only" if not implied else f"{planner}'s settings {implied}"
            found.append(f"{what}: {exc}")
            return found
    for method in ("setup", "plan"):
        if not callable(getattr(cls, method, None)):
            found.append(f"missing method {method}()")
    if found:
        return found

    def make() -> Any:
        return cls(config) if config is not None else REGISTRY.make(planner)

    trivial = trivial_problem()
    cases = problems or [trivial, blocked_problem()]
    for problem in cases:
        label = f"on {problem.id}"
        try:
            result = plan(problem, make(), seed=seed, time_limit=time_limit)
        except Exception as exc:  # the harness itself should never raise for a planner bug
            found.append(f"{label}: the harness raised {type(exc).__name__}: {exc}")
            continue
        if result.status is PlanStatus.ERROR:
            found.append(f"{label}: plan raised: {result.message}")
            continue
        found += [f"{label}: {p}" for p in _result_problems(problem, result)]
        if result.planning_time > 1.5 * time_limit + 0.5:
            found.append(f"{label}: took {result.planning_time:.2f} s with a time limit of {time_limit:.2f} s")
        ev = evaluate(problem, result)
        if result.status is PlanStatus.SUCCESS and not ev.success:
            found.append(f"{label}: claims success but validation fails: {ev.failure}")
        if problem is trivial and problems is None and not ev.success:
            found.append(f"{label}: does not solve a trivial free-space problem ({ev.failure})")
        again = plan(problem, make(), seed=seed, time_limit=time_limit)
        if not _same_path(result, again):
            found.append(f"{label}: two runs with seed {seed} gave different paths (use only the rng handed in)")
    return found


def _result_problems(problem: Problem, result: Any) -> list[str]:
    if not isinstance(result, PlanResult):
        return [f"plan() must return a PlanResult, got {type(result).__name__}"]
    if result.status is PlanStatus.SUCCESS and result.path is None:
        return ["claims success without a path"]
    out = []
    if result.path is not None:
        path = result.path
        if path.ndim != 2 or path.shape[1] != problem.robot.nq:
            return [f"path must be (N, {problem.robot.nq}), got {path.shape}"]
        if len(path) == 0:
            out.append("path is empty; return path=None when there is none")
        elif not np.allclose(path[0], problem.start, atol=1e-6):
            out.append("path[0] must equal problem.start")
        if not np.all(np.isfinite(path)):
            out.append("path contains NaN or infinite values")
    return out


def _same_path(a: PlanResult, b: PlanResult) -> bool:
    if a.status is not b.status:
        return False
    if a.path is None or b.path is None:
        return a.path is None and b.path is None
    return a.path.shape == b.path.shape and bool(np.allclose(a.path, b.path, atol=1e-9, rtol=0))
