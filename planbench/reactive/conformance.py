"""The conformance checker controller authors run on their controller: ``check_controller(MyController)``.

What :func:`planbench.conformance.check_planner` is for planners: it builds the controller as the
benchmark does (through :data:`~planbench.registry.CONTROLLERS`), drives it on a small task the way
the closed-loop runner does (``setup``, ``reset``, ``step`` before the first frame, ``update`` at
about the sensor rate, ``step`` every tick, the velocity clipped to the limits and integrated) and
returns what it finds, each :class:`Finding` under one of the names of :data:`CHECKS` (an empty list:
conformant); :func:`controller_report` gives the verdict of every check (passed, failed, not run), in
the shape of the planners' (:class:`~planbench.conformance.ConformanceReport`). The task: the Panda
of MotionBenchMaker ``box/0001``, its start and goal, a control period of 10 ms; observed with truth
sensing (its scene voxelized at 2 cm, the scene attached) and, for the goal check, an empty grid of
the same origin and shape without a scene (as a depth sensor sees free space).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.conformance import CheckRecord, ConformanceReport, Finding
from planbench.errors import InvalidConfigError, PlanbenchError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.problem import Goal, pose_error
from planbench.reactive.controller import ControlTask, Observation
from planbench.registry import CONTROLLERS, NAME_PATTERN, Registry

__all__ = ["CHECKS", "ConformanceTask", "Finding", "check_controller", "conformance_task", "controller_report"]

CHECKS = {
    "interface": "a kebab-case name, a dataclass Config, callable setup/reset/update/step",
    "settings": "Config() built from its defaults (or the preset's settings) through the registry",
    "raises": "a call raised (construction, setup, reset, update, step or info)",
    "wrong-shape": "step returned something that is not an (nq,) array of numbers",
    "nan": "step returned NaN",
    "non-finite": "step returned an infinite velocity",
    "non-deterministic": "the same task, frames and rng seed gave another trajectory",
    "ignores-goal": "in free space, the integrated steps did not bring the end effector nearer the goal",
    "info": "info() is not a mapping of JSON-friendly values",
}
"""The name of each check, and what failing it means."""

TICK_CHECKS = ("raises", "wrong-shape", "nan", "non-finite")
"""The checks of every call in every run: passed only when all runs got to their end."""

TASK_PROBLEM = "mbm:box/0001"
ROTATION_WEIGHT = 0.1
"""[m/rad] Goal error ``|p - p_goal| + ROTATION_WEIGHT * angle`` of the goal check (the IK loop's)."""


class _Fault(Exception):
    def __init__(self, check: str, message: str) -> None:
        super().__init__(message)
        self.finding = Finding(check, message)


@dataclass(frozen=True, eq=False)
class ConformanceTask:
    """The task of the checks and its two observations (module docstring)."""

    task: ControlTask
    obstacles: Observation
    """The scene voxelized (rule ``"any"``), with the scene (truth sensing)."""
    free: Observation
    """An empty grid of the same origin and shape, no scene."""


def conformance_task(period: float = 0.01, resolution: float = 0.02, padding: float = 0.2) -> ConformanceTask:
    """The task of MotionBenchMaker ``box/0001`` with a control period [s] and its observations
    (grid cells of ``resolution`` [m] over the scene grown by ``padding`` [m])."""
    from planbench.problems.datasets import load_problems

    problem = load_problems(TASK_PROBLEM)[0]
    robot, label = problem.robot, f"conformance:{problem.id}"
    task = ControlTask(robot, problem.start, problem.goal, problem.tolerances, period, label)
    grid = OccupancyGrid.from_scene(problem.scene, resolution, padding=padding)
    empty = OccupancyGrid(np.zeros(grid.shape), grid.origin.copy(), grid.resolution)
    return ConformanceTask(task, Observation(0.0, grid, scene=problem.scene), Observation(0.0, empty))


def check_controller(
    controller: Any,
    config: Any = None,
    *,
    steps: int = 300,
    seed: int = 0,
    goal_progress: float = 0.25,
    frame_every: int = 3,
    registry: Registry | None = None,
) -> list[Finding]:
    """Problems found with ``controller`` (a class, a registered name, ``name:preset``); empty when
    conformant.

    ``config``: a ``Config`` instance to check it with, or a mapping of settings (checked and built
    through the registry, as a suite's are; a refused one is a ``settings`` finding); default: built
    from its defaults through the registry, as the benchmark builds it. ``steps``: control ticks
    per run; ``frame_every``: a new frame every this many ticks (30 Hz at the default 10 ms
    period); ``goal_progress``: the fraction of the goal error the free-space run must remove at
    least.
    """
    report = controller_report(
        controller,
        config,
        steps=steps,
        seed=seed,
        goal_progress=goal_progress,
        frame_every=frame_every,
        registry=registry,
    )
    return list(report.findings)


def controller_report(
    controller: Any,
    config: Any = None,
    *,
    steps: int = 300,
    seed: int = 0,
    goal_progress: float = 0.25,
    frame_every: int = 3,
    registry: Registry | None = None,
) -> ConformanceReport:
    """The verdict of each of :data:`CHECKS` on ``controller`` (arguments: :func:`check_controller`)."""
    if steps < 1 or frame_every < 1 or not 0.0 < goal_progress < 1.0:
        raise ValueError(
            "steps and frame_every must be >= 1 and goal_progress in (0, 1), "
            f"got {steps}, {frame_every} and {goal_progress}"
        )
    registry = registry or CONTROLLERS
    record = CheckRecord(CHECKS)
    settings = dict(config) if isinstance(config, Mapping) else None
    config = None if settings is not None else config
    _interface(controller, config, registry, record, settings)
    if record.findings:
        record.skip(c for c in CHECKS if c not in ("interface", "settings"))
        return record.report()
    _, cls, _ = registry.resolve(controller)

    def make() -> Any:
        return cls(config) if config is not None else registry.configure(controller, settings).build()

    where = conformance_task()
    nq = where.task.robot.nq
    runs: list[np.ndarray] = []
    try:
        first = _construct(make)
        runs.append(_run(first, where.task, where.obstacles, steps, seed, frame_every, nq))
        runs.append(_run(first, where.task, where.obstacles, steps, seed, frame_every, nq, setup=False))
        _check_info(first)
        runs.append(_run(_construct(make), where.task, where.obstacles, steps, seed, frame_every, nq))
    except _Fault as fault:
        record.fail(fault.finding.check, fault.finding.message)
        record.skip(["info", *TICK_CHECKS] if len(runs) < 2 else TICK_CHECKS)
    if len(runs) == 3:
        for other, how in ((runs[1], "after reset with the same seed"), (runs[2], "on a new instance")):
            if not (other.shape == runs[0].shape and np.allclose(other, runs[0], atol=1e-9, rtol=0)):
                at = _first_difference(runs[0], other)
                record.fail(
                    "non-deterministic",
                    f"a second run {how} took another trajectory (from tick {at} on); "
                    "use only the rng handed to reset, and reset every state a run leaves behind",
                )
                break
    else:
        record.skip(["non-deterministic"])
    if any(f.check != "non-deterministic" for f in record.findings):
        record.skip(["ignores-goal"])
        return record.report()
    try:
        free = _construct(make)
        path = _run(free, where.task, where.free, steps, seed, frame_every, nq)
    except _Fault as fault:
        record.fail(fault.finding.check, fault.finding.message)
        record.skip(["ignores-goal", *TICK_CHECKS])
        return record.report()
    before, after = _goal_error(where.task, path[0]), _goal_error(where.task, path[-1])
    if not after <= (1.0 - goal_progress) * before:
        record.fail(
            "ignores-goal",
            f"in free space, {steps} ticks of {where.task.period * 1000:g} ms took the goal error from "
            f"{before:.3f} to {after:.3f} (|p - p_goal| + {ROTATION_WEIGHT} m/rad x angle); "
            f"at least {goal_progress:.0%} of it must go",
        )
    return record.report()


def _interface(
    controller: Any, config: Any, registry: Registry, record: CheckRecord, settings: Mapping[str, Any] | None = None
) -> None:
    """The checks that need no call of the controller's code besides its ``Config``."""
    try:
        _, cls, implied = registry.resolve(controller)
    except PlanbenchError as exc:
        record.fail("interface", f"cannot find controller {controller!r}: {exc}")
        record.skip(["settings"])
        return
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        record.fail("interface", f"'name' must be a kebab-case string like 'my-controller', got {name!r}")
    Config = getattr(cls, "Config", None)
    if Config is None or not dataclasses.is_dataclass(Config):
        record.fail("interface", "'Config' must be a dataclass of the controller's settings (units in its docstrings)")
        record.skip(["settings"])
    elif config is None:
        try:
            registry.configure(controller, settings)
        except InvalidConfigError as exc:
            what = "Config() must work with its defaults only" if not implied else f"the settings {implied}"
            what = f"the settings {settings}" if settings else what
            record.fail("settings", f"{what}: {exc}")
    else:
        record.skip(["settings"])  # a Config given: its defaults are not built
    for method in ("setup", "reset", "update", "step"):
        if not callable(getattr(cls, method, None)):
            record.fail("interface", f"missing method {method}()")


def _construct(make: Callable[[], Any]) -> Any:
    try:
        return make()
    except Exception as exc:
        raise _Fault("raises", f"building the controller raised {type(exc).__name__}: {exc}") from exc


def _call(what: str, fn: Callable[..., Any], *args: Any) -> Any:
    try:
        return fn(*args)
    except Exception as exc:
        raise _Fault("raises", f"{what} raised {type(exc).__name__}: {exc}") from exc


def _run(
    controller: Any,
    task: ControlTask,
    observation: Observation,
    steps: int,
    seed: int,
    frame_every: int,
    nq: int,
    setup: bool = True,
) -> np.ndarray:
    """The trajectory (steps + 1, nq) of one run as the runner drives it: frames delivered from
    tick 1 on, every ``frame_every`` ticks (tick 0 has none), the velocity clipped and integrated."""
    robot = task.robot
    lower, upper = np.asarray(robot.lower, dtype=float), np.asarray(robot.upper, dtype=float)
    vmax = np.asarray(robot.velocity_limit, dtype=float)
    goal: Goal = task.goal
    if setup:
        _call("setup(task)", controller.setup, task)
    q = np.array(task.start, dtype=float)
    _call("reset(q, rng)", controller.reset, q.copy(), np.random.default_rng(seed))
    path = np.empty((steps + 1, nq))
    path[0] = q
    latest: Observation | None = None
    for k in range(steps):
        t = k * task.period
        if k >= 1 and (k - 1) % frame_every == 0:
            frame = (k - 1) // frame_every
            latest = dataclasses.replace(observation, time=t, frame=frame)
            _call(f"update(observation) at tick {k}", controller.update, latest)
        qd = _velocity(_call(f"step at tick {k} (t = {t:.2f} s)", controller.step, t, q.copy(), latest, goal), nq, k)
        q = np.clip(q + task.period * np.clip(qd, -vmax, vmax), lower, upper)
        path[k + 1] = q
    return path


def _velocity(qd: Any, nq: int, k: int) -> np.ndarray:
    """``qd`` as joint velocities, or the check it fails."""
    try:
        out = np.array(qd, dtype=float)
    except (TypeError, ValueError):
        what = f"step at tick {k} returned {type(qd).__name__}, not ({nq},) joint velocities"
        raise _Fault("wrong-shape", what) from None
    if out.shape != (nq,):
        raise _Fault("wrong-shape", f"step at tick {k} returned shape {out.shape}, expected ({nq},) joint velocities")
    if np.isnan(out).any():
        raise _Fault("nan", f"step at tick {k} returned NaN: {out.tolist()}")
    if not np.isfinite(out).all():
        raise _Fault("non-finite", f"step at tick {k} returned an infinite velocity: {out.tolist()}")
    return out


def _check_info(controller: Any) -> None:
    info = _call("info()", controller.info)
    if not isinstance(info, Mapping):
        raise _Fault("info", f"info() must return a mapping (a dict), got {type(info).__name__}")
    try:
        json.dumps(dict(info), default=_plain, allow_nan=True)
    except (TypeError, ValueError) as exc:
        raise _Fault("info", f"info() must hold JSON-friendly values (numbers, text, lists, arrays): {exc}") from exc


def _plain(value: Any) -> Any:
    """numpy values as Python ones (what the results file stores); anything else is refused."""
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-friendly")


def _goal_error(task: ControlTask, q: np.ndarray) -> float:
    err_p, err_r = pose_error(task.robot, q, task.goal.pose)
    return float(err_p + ROTATION_WEIGHT * err_r)


def _first_difference(a: np.ndarray, b: np.ndarray) -> int:
    n = min(len(a), len(b))
    far = np.flatnonzero(~np.isclose(a[:n], b[:n], atol=1e-9, rtol=0).all(axis=1))
    return int(far[0]) - 1 if len(far) else n - 1
