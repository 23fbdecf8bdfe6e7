"""The closed loop: a controller drives the arm at a fixed control rate through a changing scene.

Time advances in control ticks of ``T = 1 / control_rate``. At the start of tick ``k`` (time
``t = k T``):

1. **Sensing.** Frames are captured at the sensor rate (on the first tick at or after each
   ``j / rate``) from the true scene at that time and the arm's configuration, and delivered
   ``latency`` later (on the first tick at or after it).
2. **Control.** When the controller is free, it gets ``update(frame)`` for a newly delivered frame
   and ``step(t, q, frame, goal)``, through a :class:`ControllerPort` that says what each call is
   charged. Compute time is charged as on a robot: a command ready within the period drives tick
   ``k``; one that takes ``c > T`` misses ``ceil(c / T) - 1`` deadlines: the previous command is
   held during those ticks, the new one drives the tick in which it became ready, and the
   controller starts again on the tick after. ``timing="measured"`` charges what the port
   measured (:class:`LocalPort`: this process's clock; the benchmark's
   :class:`~planbench.reactive.remote.RemoteController`: the CPU time of the controller's own
   process); ``"ideal"`` charges nothing (a controller as fast as you like); ``"replay"`` charges
   the compute times recorded by an earlier run, so a run can be repeated exactly for debugging.
3. **Motion.** The command is clipped to the robot's velocity limits, the arm moves ``q + T qd``,
   clamped to its joint limits (both recorded), and the tick is certified against the true, moving
   geometry (:class:`~planbench.reactive.checker.TickChecker`).

The run ends at the first collision, when the end effector is within the problem's tolerances of
the goal pose (success), at the horizon, or when the controller raises or returns garbage (an
``error``: what was run until then is kept; a controller process that dies: a ``crash``).
:func:`evaluate_run` recomputes every verdict and metric from the recorded trajectory alone (the
benchmark calls it where the loop ran, a process where no controller code ran, after checking the
record against the control model, :mod:`planbench.reactive.control_model`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from planbench.checking.collision import CollisionChecker
from planbench.problem import pose_error
from planbench.reactive.checker import TickChecker
from planbench.reactive.controller import BadCommand, Controller, ControlTask, Observation, as_command
from planbench.reactive.exposure import Exposure
from planbench.reactive.scenario import Scenario

__all__ = [
    "ControllerPort",
    "LocalPort",
    "RunMetrics",
    "RunRecord",
    "RunSettings",
    "TIMINGS",
    "control_rng_of",
    "control_task",
    "evaluate_run",
    "run_scenario",
    "simulate",
]

TIMINGS = ("measured", "ideal", "replay")
_EPS = 1e-9


@dataclass(frozen=True)
class RunSettings:
    """How a closed-loop run is simulated."""

    timing: str = "measured"
    """Compute time charged to the controller: ``"measured"``, ``"ideal"`` (none) or ``"replay"``."""
    stall_speed: float = 0.01
    """Below this joint speed [rad/s] (norm of the applied command) the arm counts as stalled."""
    check_collisions: bool = True
    """Certify each tick and end the run at the first collision (off only for timing studies)."""

    def __post_init__(self) -> None:
        if self.timing not in TIMINGS:
            raise ValueError(f"timing must be one of {TIMINGS}, got {self.timing!r}")
        if not (math.isfinite(self.stall_speed) and self.stall_speed >= 0):
            raise ValueError(f"stall_speed must be >= 0 [rad/s], got {self.stall_speed}")


@dataclass
class RunRecord:
    """What happened in one run: the trajectory, the commands, the controller's compute times.

    ``times`` (n + 1,) [s] and ``path`` (n + 1, nq) [rad]: the state at each tick boundary;
    ``commands`` (n, nq) [rad/s]: the velocity that drove each tick (after clipping); ``measured``
    (n,) [s]: the controller's measured compute time on each tick it started on (NaN on the
    others), ``compute`` the time charged for it (``timing``: measured, zero, or replayed);
    ``field_update_times`` [s]: one per sensor frame the controller took in.
    """

    scenario: str
    controller: str
    status: str
    message: str
    times: np.ndarray
    path: np.ndarray
    commands: np.ndarray
    compute: np.ndarray
    measured: np.ndarray
    field_update_times: list[float] = field(default_factory=list)
    frame_times: list[float] = field(default_factory=list)
    deadline_misses: int = 0
    velocity_clipped: int = 0
    position_clamped: int = 0
    collision: tuple[str, str] | None = None
    info: dict[str, Any] = field(default_factory=dict)
    setup_time: float = math.nan
    """[s] the controller's ``setup`` and ``reset`` (untimed by the loop)."""
    overrun: str = ""
    """Why a call was abandoned (its command never came), when one was."""
    unobserved: np.ndarray | None = None
    """(n,) bool: the ticks of unobserved motion (:mod:`planbench.reactive.exposure`); None: not recorded."""
    first_seen: dict[str, float] = field(default_factory=dict)
    """Obstacle name -> when an observation delivered to the controller first showed it [s]."""
    contact_unobserved: bool | None = None
    """A collision with an obstacle: whether it happened in unobserved space
    (:mod:`planbench.reactive.exposure`); None: no such collision, or not recorded."""


class ControllerFault(Exception):
    """The controller raised or returned something that is not a joint velocity (``status``
    ``"error"``), or its process died (``"crash"``)."""

    def __init__(self, message: str, status: str = "error") -> None:
        super().__init__(message)
        self.status = status


class ControllerPort(Protocol):
    """How the simulation calls a controller: each call returns what it is charged [s].

    :class:`LocalPort` calls a controller object in this process (timed with this process's clock:
    for your own code, in a notebook or a debugger);
    :class:`~planbench.reactive.remote.RemoteController` calls one in another process and charges
    the CPU time it consumed there (the benchmark's way)."""

    budget: float

    def update(self, observation: Observation) -> float: ...

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Any) -> tuple[Any, float]: ...

    def info(self) -> dict[str, Any]: ...


class LocalPort:
    """A controller object called in this process, each call timed with ``time.perf_counter``."""

    def __init__(self, controller: Controller) -> None:
        self.controller = controller
        self.budget = math.inf

    def update(self, observation: Observation) -> float:
        t0 = time.perf_counter()
        self.controller.update(observation)
        return time.perf_counter() - t0

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Any) -> tuple[Any, float]:
        t0 = time.perf_counter()
        qd = self.controller.step(t, q, observation, goal)
        return qd, time.perf_counter() - t0

    def info(self) -> dict[str, Any]:
        return dict(self.controller.info())


def run_scenario(
    scenario: Scenario,
    controller: Controller,
    *,
    seed: int = 0,
    settings: RunSettings | None = None,
    replay: np.ndarray | None = None,
    name: str | None = None,
    sensor: Any = None,
) -> RunRecord:
    """Run ``controller`` on ``scenario`` in this process (module docstring): its ``setup`` and
    ``reset`` (untimed), then :func:`simulate` through a :class:`LocalPort`. Compute is timed with
    this process's clock, which the controller shares: the benchmark runs controllers in a process
    of their own instead (:mod:`planbench.reactive.remote`)."""
    problem = scenario.problem
    control_rng = control_rng_of(seed)
    task = control_task(scenario)
    t_setup = time.perf_counter()
    controller.setup(task)
    controller.reset(np.array(problem.start), control_rng)
    setup_time = time.perf_counter() - t_setup
    record = simulate(
        scenario,
        LocalPort(controller),
        seed=seed,
        settings=settings,
        replay=replay,
        name=name or getattr(controller, "name", None) or "",
        sensor=sensor,
    )
    record.setup_time = setup_time
    return record


def ticks_of(scenario: Scenario) -> int:
    """The number of control ticks of a run: as many whole periods as fit in the horizon."""
    return max(1, math.floor(scenario.horizon * scenario.control_rate + 1e-9))


def control_task(scenario: Scenario) -> ControlTask:
    """What the controller of ``scenario`` is told before it runs."""
    p = scenario.problem
    depth = scenario.sensing.model == "depth"
    cameras = tuple(scenario.sensing.cameras) if depth else ()
    margin = scenario.sensing.robot_margin if depth else 0.0
    return ControlTask(p.robot, p.start, p.goal, p.tolerances, scenario.period, scenario.name, cameras, margin)


def control_rng_of(seed: int) -> np.random.Generator:
    """The controller's random generator of run ``seed`` (the sensor's is the other child)."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1])


def simulate(
    scenario: Scenario,
    port: ControllerPort,
    *,
    seed: int = 0,
    settings: RunSettings | None = None,
    replay: np.ndarray | None = None,
    name: str = "",
    sensor: Any = None,
) -> RunRecord:
    """The closed loop of the module docstring, calling the controller through ``port`` (already
    set up and reset). ``replay``: the ``compute`` array of an earlier run, for
    ``timing="replay"``. ``sensor``: anything with the ``capture`` method of
    :class:`~planbench.reactive.sensing.Sensor` (default: the scenario's sensing model)."""
    settings = settings or RunSettings()
    if settings.timing == "replay" and replay is None:
        raise ValueError('timing="replay" needs the compute times of an earlier run (replay=record.compute)')
    problem = scenario.problem
    robot = problem.robot
    T = scenario.period
    n_ticks = ticks_of(scenario)
    sensor_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[0])
    if sensor is None:
        from planbench.reactive.sensing import Sensor

        sensor = Sensor(scenario.sensing, robot)
    checker = TickChecker(scenario) if settings.check_collisions else None
    exposure = Exposure(scenario)
    lower, upper = np.asarray(robot.lower, dtype=float), np.asarray(robot.upper, dtype=float)
    vmax = np.asarray(robot.velocity_limit, dtype=float)
    tol_p, tol_r = problem.tolerances.position, problem.tolerances.orientation

    times = np.arange(n_ticks + 1) * T
    path = np.full((n_ticks + 1, robot.nq), np.nan)
    commands = np.full((n_ticks, robot.nq), np.nan)
    compute = np.full(n_ticks, np.nan)
    measured = np.full(n_ticks, np.nan)
    unobserved = np.zeros(n_ticks, dtype=bool)
    q = np.array(problem.start, dtype=float)
    path[0] = q
    held = np.zeros(robot.nq)
    rec = RunRecord(scenario.name, name, "timeout", "", times, path, commands, compute, measured)
    pending: list[Observation] = []  # captured, not yet delivered
    latest: Observation | None = None
    fresh = False  # a frame delivered since the controller last took one in
    next_frame, free_at = 0, 0
    late: tuple[int, np.ndarray] | None = None  # (tick it takes effect, command)
    n_done = n_ticks
    status, message = "timeout", f"goal not reached within the horizon of {scenario.horizon:g} s"
    for k in range(n_ticks):
        t = times[k]
        while next_frame / scenario.sensing.rate <= t + _EPS:
            obs = sensor.capture(scenario.scene_at(t), q, t, next_frame, sensor_rng)
            pending.append(obs)
            rec.frame_times.append(t)
            next_frame += 1
        while pending and pending[0].time + scenario.sensing.latency <= t + _EPS:
            latest, fresh = pending.pop(0), True
            exposure.delivered(latest, t)
        if k >= free_at:
            port.budget = (n_ticks - k) * T
            try:
                qd, c = _compute(port, t, q, latest if fresh else None, latest, problem.goal, robot.nq, rec)
            except ControllerFault as exc:
                status, message, n_done = exc.status, f"tick {k} (t = {t:.3f} s): {exc}", k
                break
            fresh = False
            measured[k] = c
            if settings.timing == "ideal":
                c = 0.0
            elif settings.timing == "replay":
                assert replay is not None  # checked on entry
                c = float(replay[k]) if k < len(replay) and np.isfinite(replay[k]) else 0.0
            compute[k] = c
            missed = max(0, math.ceil(c / T - _EPS) - 1)
            rec.deadline_misses += missed
            free_at = k + missed + 1
            if qd is None:  # abandoned: its command never comes, and the controller is called no more
                free_at = n_ticks
            elif missed == 0:
                held = qd
            else:
                late = (k + missed, qd)
        if late is not None and late[0] == k:
            held, late = late[1], None
        command = np.clip(held, -vmax, vmax)
        rec.velocity_clipped += int(not np.array_equal(command, held))
        q_next = q + T * command
        clamped = np.clip(q_next, lower, upper)
        rec.position_clamped += int(not np.array_equal(clamped, q_next))
        commands[k] = (clamped - q) / T
        unobserved[k] = not np.array_equal(clamped, q) and exposure.in_unknown(clamped)
        if checker is not None:
            verdict = checker.check_tick(q, clamped, t, times[k + 1])
            if not verdict.free:
                when = t + verdict.fraction * T
                path[k + 1] = clamped
                rec.collision = verdict.pair
                rec.contact_unobserved = _contact_unobserved(scenario, exposure, clamped, times[k + 1], verdict.pair)
                status = "collision"
                message = f"collision at t = {when:.3f} s: {verdict.pair[0]} with {verdict.pair[1]}"
                n_done = k + 1
                break
        q = clamped
        path[k + 1] = q
        err_p, err_r = pose_error(robot, q, problem.goal.pose)
        if err_p <= tol_p and err_r <= tol_r:
            status, message, n_done = "success", f"goal reached at t = {times[k + 1]:.3f} s", k + 1
            break
    rec.status, rec.message = status, message
    rec.times, rec.path = times[: n_done + 1], path[: n_done + 1]
    rec.commands, rec.compute, rec.measured = commands[:n_done], compute[:n_done], measured[:n_done]
    rec.unobserved, rec.first_seen = unobserved[:n_done], dict(exposure.first_seen)
    try:
        rec.info = dict(port.info())
    except Exception as exc:  # diagnostics must not lose the run
        rec.info = {"info_error": f"{type(exc).__name__}: {exc}"}
    return rec


def _contact_unobserved(
    scenario: Scenario, exposure: Exposure, q: np.ndarray, t: float, pair: tuple[str, str]
) -> bool | None:
    """Whether the arm at ``q`` touches the obstacle of ``pair`` at time ``t`` only in unobserved
    space (:meth:`~planbench.reactive.exposure.Exposure.unobserved_at`); None for the arm touching
    itself, or when coal reports no contact point there."""
    if not pair[1].startswith("obstacle:"):
        return None
    checker = CollisionChecker(scenario.problem.robot, scenario.scene_at(t))
    points = [p for a, b, p in checker.contacts(q) if (a, b) == pair]
    return exposure.unobserved_at(np.array(points)) if points else None


def _compute(
    port: ControllerPort,
    t: float,
    q: np.ndarray,
    new: Observation | None,
    latest: Observation | None,
    goal: Any,
    nq: int,
    rec: RunRecord,
) -> tuple[np.ndarray | None, float]:
    """One controller turn: ``update`` for a new frame, then ``step``; the command (None when the
    turn was abandoned, :class:`~planbench.reactive.remote.Overrun`) and the time charged [s]."""
    from planbench.reactive.remote import ControllerGone, Overrun, RemoteFault

    spent = 0.0
    try:
        if new is not None:
            u = port.update(new)
            rec.field_update_times.append(u)
            spent += u
            port.budget -= u
        qd, s = port.step(t, q.copy(), latest, goal)
        spent += s
    except Overrun as over:
        rec.overrun = f"{over} ({spent + over.charged:.3f} s charged)"
        return None, spent + over.charged
    except ControllerGone as exc:
        raise ControllerFault(str(exc), status="crash") from exc
    except RemoteFault as exc:
        raise ControllerFault(str(exc)) from exc
    except Exception as exc:
        raise ControllerFault(f"the controller raised {type(exc).__name__}: {exc}") from exc
    try:
        return as_command(qd, nq), spent
    except BadCommand as bad:
        raise ControllerFault(str(bad)) from None


@dataclass(frozen=True)
class RunMetrics:
    """The metrics of one run, named as in the results file. Times in s, lengths in m or rad."""

    success: bool
    failure: str
    time_to_goal: float
    min_clearance: float
    tick_time_median: float
    tick_time_p99: float
    deadline_misses: int
    field_update_time: float
    stalled_time: float
    path_length: float
    unobserved_motion: float
    """[s] the arm moving through cells its latest observation did not know (NaN: not recorded)."""
    collision_observed: bool | None
    """Whether the obstacle hit had been shown to the controller before (None: no collision with an obstacle)."""

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def evaluate_run(scenario: Scenario, record: RunRecord, settings: RunSettings | None = None) -> RunMetrics:
    """Verdict and metrics of a run from its trajectory alone: every tick certified again against
    the true moving geometry, the goal checked at the last state, the clearance measured at every
    tick (never trusting the runner's or the controller's own account)."""
    settings = settings or RunSettings()
    problem = scenario.problem
    times, path = np.asarray(record.times, dtype=float), np.asarray(record.path, dtype=float)
    checker = TickChecker(scenario)
    failure = ""
    n = len(path)
    if n < 1 or not np.isfinite(path).all() or len(times) != n:
        raise ValueError(f"run record of {record.scenario!r}: trajectory must be finite with one time per state")
    if np.any(np.diff(times) <= 0) or abs(times[0]) > _EPS:
        raise ValueError(f"run record of {record.scenario!r}: times must start at 0 and increase")
    if times[-1] > scenario.horizon + _EPS:
        failure = "trajectory runs past the horizon"
    violations = problem.robot.limit_violations(path.max(axis=0)) + problem.robot.limit_violations(path.min(axis=0))
    if violations and not failure:
        failure = "joint limits violated: " + "; ".join(violations)
    clearance = checker.clearance(path[0], times[0])
    observed: bool | None = None
    for k in range(n - 1):
        verdict = checker.check_tick(path[k], path[k + 1], times[k], times[k + 1])
        if not verdict.free:
            when = times[k] + verdict.fraction * (times[k + 1] - times[k])
            body = verdict.pair[1]
            if body.startswith("obstacle:") and record.unobserved is not None:  # a record of simulate()
                seen_at = record.first_seen.get(body.removeprefix("obstacle:"))
                observed = bool(seen_at is not None and seen_at <= times[k + 1] + _EPS)
            unseen = ", never observed" if observed is False else ""
            if observed and record.contact_unobserved and record.collision == verdict.pair:
                unseen = ", in unobserved space"  # an obstacle shown elsewhere, hit where no frame showed it
            failure = failure or f"collision with {body} ({verdict.pair[0]}) at t = {when:.3f} s{unseen}"
            break
        clearance = min(clearance, checker.clearance(path[k + 1], times[k + 1]))
    err_p, err_r = pose_error(problem.robot, path[-1], problem.goal.pose)
    reached = err_p <= problem.tolerances.position and err_r <= problem.tolerances.orientation
    if not failure and not reached:
        if record.status in ("error", "crash"):
            failure = f"{record.status}: {record.message}"
        else:
            failure = f"goal not reached (position error {err_p * 1000:.1f} mm, orientation {err_r:.3f} rad)"
    compute = np.asarray(record.measured, dtype=float)
    compute = compute[np.isfinite(compute)]
    dt = np.diff(times)
    speed = np.linalg.norm(np.diff(path, axis=0), axis=1) / dt  # the applied command: the path is its integral
    updates = np.asarray(record.field_update_times, dtype=float)
    unobserved = math.nan
    if record.unobserved is not None:
        flags = np.asarray(record.unobserved, dtype=bool)
        if flags.shape != dt.shape:
            raise ValueError(f"run record of {record.scenario!r}: one unobserved flag per tick expected")
        unobserved = float(np.sum(dt[flags]))
    return RunMetrics(
        success=not failure,
        failure=failure,
        time_to_goal=float(times[-1]) if not failure else math.nan,
        min_clearance=float(clearance),
        tick_time_median=float(np.median(compute)) if len(compute) else math.nan,
        tick_time_p99=float(np.percentile(compute, 99)) if len(compute) else math.nan,
        deadline_misses=int(record.deadline_misses),
        field_update_time=float(np.median(updates)) if len(updates) else math.nan,
        stalled_time=float(np.sum(dt[speed < settings.stall_speed])),
        path_length=float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))),
        unobserved_motion=unobserved,
        collision_observed=observed,
    )
