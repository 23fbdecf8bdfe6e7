"""Closed-loop runs in the benchmark: the worker's side (run a controller, send the trajectory as
data) and the validator's (verdict and metrics from the trajectory alone).

A closed-loop run crosses the benchmark's process boundaries as a static run does: the worker
sends the raw fields of :data:`planbench.bench.wire.RESULT_FIELDS` (status, message, the executed
trajectory as ``path`` and ``times``, the compute times in ``info``), the validator, where no
controller code ran, computes :func:`~planbench.reactive.runner.evaluate_run` and returns an
:class:`~planbench.validate.Evaluation` whose closed-loop fields are filled.
"""

from __future__ import annotations

import math
import os
import socket
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from planbench.problem import pose_error
from planbench.reactive.runner import RunRecord, RunSettings, evaluate_run, run_scenario
from planbench.reactive.scenario import Scenario
from planbench.validate import Evaluation

__all__ = ["control_one", "validate_run_fields"]

_STATUS = {"success": "success", "collision": "collision", "timeout": "timeout", "error": "error"}


def control_one(task: Any, notify: Callable[[str], None] = lambda phase: None) -> dict[str, Any]:
    """Run ``task`` (a closed-loop :class:`~planbench.bench.task.RunTask`) in this process and
    return its raw-result fields (unchecked: the worker checks them as it does a planner's)."""
    from planbench.reactive.sets import load_scenario
    from planbench.registry import CONTROLLERS

    t0 = time.perf_counter()
    base = {"pid": os.getpid(), "host": socket.gethostname(), "target": "pose", "traceback": ""}
    try:
        scenario = load_scenario(task.problem_ref)
        controller = CONTROLLERS.make(task.planner, **task.settings)
    except Exception as exc:
        return {
            **base,
            "status": "error",
            "message": f"could not prepare the run: {type(exc).__name__}: {exc}",
            "info": {},
            "planning_time": math.nan,
            "setup_time": math.nan,
            "wall_time": time.perf_counter() - t0,
            "traceback": traceback.format_exc(),
            "prepared": False,
            "path": None,
            "times": None,
        }
    if _warm(controller, scenario):
        controller = CONTROLLERS.make(task.planner, **task.settings)  # a fresh one: nothing of the warm-up kept
    notify("plan")
    record = run_scenario(scenario, controller, seed=task.seed, settings=RunSettings(timing=task.timing))
    loop_time = time.perf_counter() - t0 - (record.setup_time if math.isfinite(record.setup_time) else 0.0)
    return {
        **base,
        "status": _STATUS[record.status],
        "message": record.message,
        "info": _record_info(record),
        "planning_time": loop_time,
        "setup_time": record.setup_time,
        "wall_time": time.perf_counter() - t0,
        "prepared": True,
        "path": record.path,
        "times": record.times,
    }


_WARMED: set[type] = set()


def _warm(controller: Any, scenario: Scenario) -> bool:
    """Compile the controller's numba code (or load numba's on-disk cache) before its first run in
    this worker: one frame of the scenario through ``setup``, ``reset``, ``update`` and ``step``,
    untimed. Without it the first run of each worker charges the compilation to its first ticks
    as deadline misses. A failure here is left to the run to meet. True when ``controller`` was
    used for it."""
    cls = type(controller)
    if cls in _WARMED or not getattr(controller, "compiles", False):
        return False
    _WARMED.add(cls)
    try:
        from planbench.reactive.controller import ControlTask
        from planbench.reactive.sensing import Sensor

        p = scenario.problem
        rng = np.random.default_rng(0)
        frame = Sensor(scenario.sensing, p.robot).capture(scenario.scene_at(0.0), np.array(p.start), 0.0, 0, rng)
        controller.setup(ControlTask(p.robot, p.start, p.goal, p.tolerances, scenario.period, scenario.name))
        controller.reset(np.array(p.start), rng)
        controller.update(frame)
        controller.step(0.0, np.array(p.start), frame, p.goal)
    except Exception:  # the run will meet it again, as its own error
        pass
    return True


def _record_info(record: RunRecord) -> dict[str, Any]:
    """What the validator needs besides the trajectory, and the controller's own diagnostics."""
    return {
        "compute": _floats(record.compute),
        "measured": _floats(record.measured),
        "field_update_times": _floats(record.field_update_times),
        "frame_times": _floats(record.frame_times),
        "deadline_misses": int(record.deadline_misses),
        "velocity_clipped": int(record.velocity_clipped),
        "position_clamped": int(record.position_clamped),
        "collision": list(record.collision) if record.collision else None,
        "controller": dict(record.info),
    }


def _floats(values: Any) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, dtype=float).tolist()]


def validate_run_fields(scenario: Scenario, fields: dict[str, Any]) -> dict[str, Any]:
    """The :class:`Evaluation` (as a dict) of a closed-loop run's checked raw fields."""
    info = fields["info"]
    path, times = fields["path"], fields["times"]
    status = fields["status"]
    base = Evaluation(False, "", status, fields["planning_time"], fields["setup_time"])
    if path is None or times is None or len(path) == 0:
        failure = f"{status}: {fields['message']}" if fields["message"] else status
        return {**base.as_dict(), "failure": failure}
    record = RunRecord(
        scenario.name,
        "",
        status,
        fields["message"],
        np.asarray(times, dtype=float),
        np.asarray(path, dtype=float),
        np.zeros((0, path.shape[1])),
        _array(info.get("compute")),
        _array(info.get("measured")),
        field_update_times=_array(info.get("field_update_times")).tolist(),
        deadline_misses=int(info.get("deadline_misses") or 0),
    )
    m = evaluate_run(scenario, record)
    err_p, err_r = pose_error(scenario.problem.robot, record.path[-1], scenario.problem.goal.pose)
    pair = ""
    if m.failure.startswith("collision with "):  # "collision with <body> (<robot link>) at t = ..."
        body, _, link = m.failure.removeprefix("collision with ").partition(" at t")[0].rpartition(" (")
        pair = f"{link.rstrip(')')} / {body}"  # as a static run's: "<robot link> / <link or obstacle:name>"
    return {
        **base.as_dict(),
        "success": m.success,
        "failure": m.failure,
        "n_waypoints": len(record.path),
        "joint_path_length": m.path_length,
        "min_clearance": m.min_clearance,
        "trajectory_duration": float(record.times[-1]),
        "final_position_error": err_p,
        "final_orientation_error": err_r,
        "collision_pair": pair,
        "time_to_goal": m.time_to_goal,
        "tick_time_median": m.tick_time_median,
        "tick_time_p99": m.tick_time_p99,
        "deadline_misses": m.deadline_misses,
        "field_update_time": m.field_update_time,
        "stalled_time": m.stalled_time,
        "path_length": m.path_length,
    }


def _array(values: Any) -> np.ndarray:
    if not isinstance(values, list):
        return np.zeros(0)
    return np.array([math.nan if v is None else float(v) for v in values], dtype=float)
