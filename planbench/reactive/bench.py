"""Closed-loop runs in the benchmark: the controller's side and the simulation's side of one run.

The benchmark (:mod:`planbench.bench.kinds`) gives each closed-loop run two processes joined by a
socket pair (:mod:`planbench.reactive.remote`):

- the **controller's process** (a fresh benchmark worker) calls :func:`serve_run`: it confines
  itself (:func:`~planbench.reactive.isolation.confine`: no capabilities, no new processes)
  *before* the controller's module is imported, builds the controller, runs ``setup`` and
  ``reset`` (untimed), tells the benchmark the loop may start, and answers the simulation's calls
  until the run ends. It sends the benchmark nothing else: a run's record never comes from here.
- the **simulation's process** (the slot's validator, where no plugin code ever runs) calls
  :func:`simulate_run`: sensing, integration, velocity clipping, joint clamping, the compute
  charged from the kernel's CPU clock of the controller's process, certification of every tick,
  then the verdict: :func:`~planbench.reactive.runner.evaluate_run` and the control model
  (:func:`~planbench.reactive.control_model.check_record`) on the trajectory and the
  simulation's own timing record. It returns the run's raw fields and its evaluation together.
"""

from __future__ import annotations

import gc
import math
import os
import socket
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from planbench.problem import pose_error
from planbench.reactive.control_model import check_record
from planbench.reactive.runner import (
    RunRecord,
    RunSettings,
    control_rng_of,
    control_task,
    evaluate_run,
    simulate,
)
from planbench.reactive.scenario import Scenario
from planbench.scene import Obstacle, Scene
from planbench.validate import Evaluation

__all__ = ["current_cpu", "evaluate_record", "serve_run", "simulate_remote", "simulate_run"]

_STATUS = {"success": "success", "collision": "collision", "timeout": "timeout", "error": "error", "crash": "crash"}


def _error(message: str, t0: float, tb: str = "") -> dict[str, Any]:
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "target": "pose",
        "status": "error",
        "message": message,
        "info": {},
        "planning_time": math.nan,
        "setup_time": math.nan,
        "wall_time": time.perf_counter() - t0,
        "traceback": tb,
        "prepared": False,
        "path": None,
        "times": None,
    }


def serve_run(
    scenario_ref: str | Scenario,
    controller_name: str,
    settings: dict[str, Any],
    seed: int,
    sock: socket.socket,
    notify: Callable[[str], None],
) -> dict[str, Any] | None:
    """The controller's side of one run (module docstring). None once the run has been served;
    the raw fields of an ``error`` (not prepared) when the controller could not be built or set up."""
    from planbench.reactive.isolation import IsolationUnavailable, confine
    from planbench.reactive.remote import serve_controller
    from planbench.reactive.sets import load_scenario
    from planbench.registry import CONTROLLERS

    t0 = time.perf_counter()
    try:
        scenario = scenario_ref if isinstance(scenario_ref, Scenario) else load_scenario(scenario_ref)
    except Exception as exc:
        return _error(f"could not load the scenario: {type(exc).__name__}: {exc}", t0, traceback.format_exc())
    try:
        confine()
    except IsolationUnavailable as exc:
        return _error(f"controllers run confined and this machine cannot confine them: {exc}", t0)
    try:
        controller = CONTROLLERS.make(controller_name, **settings)
        if _warm(controller, scenario):
            controller = CONTROLLERS.make(controller_name, **settings)  # nothing of the warm-up kept
        controller.setup(control_task(scenario))
        controller.reset(np.array(scenario.problem.start), control_rng_of(seed))
    except Exception as exc:
        return _error(f"could not prepare the run: {type(exc).__name__}: {exc}", t0, traceback.format_exc())
    # What exists now lives for the run: collected once here, then out of the collector's reach.
    # A full collection of the 90,000-170,000 objects a controller's process holds costs 18-45 ms
    # of the controller's charged time: a missed deadline whenever the collector chose to run one.
    gc.collect()
    gc.freeze()
    notify("plan")
    serve_controller(sock, controller, scenario.problem.robot.nq, scenario.problem.goal)
    gc.unfreeze()  # collectable again as the process ends (frozen, the bindings report them leaked)
    return None


WARM_STEPS = 40
"""Steps of the warm-up (:func:`_warm`): enough for a controller that plans a slice per tick to
reach its search at 100 Hz (``matrix-field-guided``: the plan's geometry in about ten slices)."""


def _warm(controller: Any, scenario: Scenario) -> bool:
    """Compile the controller's numba code (or load numba's on-disk cache) and meet its other
    first-call costs before its run: two frames of a scene of its own (:func:`warm_scene`, nothing
    of the scenario's obstacles) through ``setup``, ``reset``, ``update`` and :data:`WARM_STEPS`
    steps, untimed, so that the run's first frames and first plan are not charged them. A failure
    here is left to the run to meet. True when ``controller`` was used for it; False when it says
    ``warm_up = False`` (:attr:`~planbench.reactive.controller.Controller.warm_up`)."""
    if not getattr(controller, "warm_up", True):
        return False
    try:
        from planbench.reactive.sensing import Sensor

        p = scenario.problem
        rng = np.random.default_rng(0)
        sensor = Sensor(scenario.sensing, p.robot)
        start = np.array(p.start)
        task = control_task(scenario)
        controller.setup(task)
        controller.reset(start.copy(), rng)
        half = WARM_STEPS // 2
        for k in range(2):
            t = k * half * task.period
            frame = _as_delivered(sensor.capture(warm_scene(p.goal.pose.position, k), start, t, k, rng))
            controller.update(frame)
            for i in range(half):
                controller.step(t + i * task.period, start.copy(), frame, p.goal)
    except Exception:  # the run will meet it again, as its own error
        pass
    return True


def warm_scene(goal_position: np.ndarray, k: int) -> Scene:
    """The warm-up's scene at its frame ``k``: a 10 cm box 25 cm above the goal's position, moved
    3 cm along x at each frame (a moving obstacle for the code that tracks them); only the task's
    goal, which ``setup`` has anyway, places it."""
    x, y, z = (float(v) for v in goal_position)
    box = Obstacle("warm-up box", "box", (x + 0.03 * k, y, z + 0.25), size=(0.1, 0.1, 0.1))
    return Scene((box,), "warm-up")


def _as_delivered(frame: Any) -> Any:
    """``frame`` with read-only arrays, as :class:`~planbench.reactive.remote.GridView` delivers
    them (compiled code is specialised on whether an array is writable)."""
    from dataclasses import replace

    from planbench.reactive.remote import _grid_as_checked

    data = frame.grid.data.view()
    data.setflags(write=False)
    points = None
    if frame.points is not None:
        points = frame.points.view()
        points.setflags(write=False)
    known = frame.grid.known
    if known is not None:
        known = known.view()
        known.setflags(write=False)
    grid = _grid_as_checked(data, frame.grid.origin, frame.grid.resolution, frame.grid.outside, known)
    return replace(frame, grid=grid, points=points)


def simulate_remote(
    scenario: Scenario,
    sock: socket.socket,
    pid: int,
    *,
    seed: int = 0,
    settings: RunSettings | None = None,
    cpu: int | None = None,
) -> tuple[RunRecord, list[float]]:
    """The closed loop against the controller of process ``pid`` over ``sock``, both pinned to core
    ``cpu`` (None: the core this process is on now): the run's record and each call's hand-off
    time [s]."""
    from planbench.reactive.remote import ControllerGone, RemoteController

    own = os.sched_getaffinity(0)
    cpu = current_cpu() if cpu is None else cpu
    try:
        if cpu is not None:
            _pin(cpu, pid)
        try:
            port = RemoteController(sock, pid, scenario.problem.robot.nq)
        except ProcessLookupError as exc:
            raise ControllerGone(f"the controller's process is gone ({exc})") from exc
        port.prepare(_grid_shape(scenario))
        record = simulate(scenario, port, seed=seed, settings=settings)
        if record.overrun:
            port.kill()
    finally:
        os.sched_setaffinity(0, own)
    return record, port.handoff


def simulate_run(
    scenario: Scenario, seed: int, timing: str, sock: socket.socket, pid: int, cpu: int | None
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The simulation's side of one benchmark run (module docstring): the run's raw fields (with
    ``path`` and ``times``) and its evaluation (as a dict)."""
    t0 = time.perf_counter()
    record, handoff = simulate_remote(scenario, sock, pid, seed=seed, settings=RunSettings(timing=timing), cpu=cpu)
    loop_time = time.perf_counter() - t0
    fields = {
        "pid": pid,
        "host": socket.gethostname(),
        "target": "pose",
        "status": _STATUS[record.status],
        "message": record.message + (f" [a call was abandoned: {record.overrun}]" if record.overrun else ""),
        "info": _record_info(record, handoff),
        "planning_time": loop_time,
        "setup_time": math.nan,
        "wall_time": loop_time,
        "traceback": "",
        "prepared": True,
        "path": record.path,
        "times": record.times,
    }
    return fields, evaluate_record(scenario, record, loop_time)


def _grid_shape(scenario: Scenario) -> tuple[int, ...]:
    """The shape of the scenario's observed grids (one for the whole run), from a frame of a sensor
    and a generator of its own (the run's sensor and its noise are left as they are)."""
    from planbench.reactive.sensing import Sensor

    p = scenario.problem
    sensor = Sensor(scenario.sensing, p.robot)
    frame = sensor.capture(scenario.scene_at(0.0), np.array(p.start), 0.0, 0, np.random.default_rng(0))
    return tuple(frame.grid.data.shape)


def current_cpu() -> int | None:
    """The core this process runs on now (None where it cannot be read)."""
    try:
        with open("/proc/self/stat") as f:
            return int(f.read().rpartition(")")[2].split()[36])
    except (OSError, ValueError, IndexError):
        return None


def _pin(cpu: int, pid: int) -> None:
    """Both processes on one core: they alternate, so a hand-off is a switch on that core."""
    for who in (0, pid):
        try:
            os.sched_setaffinity(who, {cpu})
        except OSError:  # a core this process may not use, or the controller already gone
            pass


def _record_info(record: RunRecord, handoff: list[float]) -> dict[str, Any]:
    """The simulation's own record of the run, and the controller's diagnostics (as it sent them)."""
    h = np.asarray(handoff, dtype=float)
    return {
        "compute": _floats(record.compute),
        "measured": _floats(record.measured),
        "field_update_times": _floats(record.field_update_times),
        "frame_times": _floats(record.frame_times),
        "deadline_misses": int(record.deadline_misses),
        "velocity_clipped": int(record.velocity_clipped),
        "position_clamped": int(record.position_clamped),
        "collision": list(record.collision) if record.collision else None,
        "first_seen": dict(record.first_seen),
        "contact_unobserved": record.contact_unobserved,
        "handoff_median": float(np.median(h)) if len(h) else None,
        "handoff_p99": float(np.percentile(h, 99)) if len(h) else None,
        "handoff_calls": len(h),
        "controller": dict(record.info),
    }


def _floats(values: Any) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, dtype=float).tolist()]


def evaluate_record(scenario: Scenario, record: RunRecord, planning_time: float = math.nan) -> dict[str, Any]:
    """The :class:`~planbench.validate.Evaluation` (as a dict) of a closed-loop run's record: the
    control model first (a record the loop cannot produce is ``invalid``, naming the rule and the
    tick), then :func:`~planbench.reactive.runner.evaluate_run` (every tick certified again)."""
    base = Evaluation(False, "", record.status, planning_time, record.setup_time)
    if len(record.path) == 0:
        return {**base.as_dict(), "failure": f"{record.status}: {record.message}"}
    violation = check_record(scenario, record)
    if violation is not None:
        return {**base.as_dict(), "failure": f"invalid: {violation}", "n_waypoints": len(record.path)}
    m = evaluate_run(scenario, record)
    err_p, err_r = pose_error(scenario.problem.robot, record.path[-1], scenario.problem.goal.pose)
    pair = ""
    if m.failure.startswith("collision with "):  # "collision with <body> (<robot link>) at t = ..."
        body, _, link = m.failure.removeprefix("collision with ").partition(" at t")[0].rpartition(" (")
        pair = f"{link.rstrip(')')} / {body}"  # as a static run's: "<robot link> / <link or obstacle:name>"
    failure = m.failure
    return {
        **base.as_dict(),
        "success": m.success,
        "failure": failure,
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
        "unobserved_motion": m.unobserved_motion,
        "collision_observed": m.collision_observed,
    }
