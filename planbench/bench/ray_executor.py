"""``--executor ray``: the benchmark's runs on a Ray cluster, with the results of one machine.

The driver (this process) keeps every job it has locally: it expands the suite, skips stored runs,
writes each record into the SQLite results file as it arrives (the only writer, so ``--resume``
after a killed driver works as locally) and shows the progress. The runs go to Ray actors, one per
worker CPU (``num_cpus=1``, spread over the nodes), each owning one warm local slot
(:class:`~planbench.bench.ray_slot.SlotActor`): its own spawned worker and validator on its node,
the same code as the local executor, so isolation, limits and the verdict boundary are the local
ones. Idle actors take the next run (dynamic load balancing); the order rows arrive in does not
change them, since a run depends only on its task.

Actors are owned by the driver: they die with it (kill -9 included), and their slots' processes
die with them (``PR_SET_PDEATHSIG``). An actor lost in the middle of a run (its node left, it was
killed) is restarted by Ray and the run is given again, up to :data:`MAX_LOSSES` times; nothing is
recorded for a lost run.

Ray is imported here only, when the executor is used: it is an optional extra.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from planbench.bench.ray_slot import SlotActor, record_from_wire, task_to_wire
from planbench.bench.runner import Record, default_jobs
from planbench.bench.task import RunTask
from planbench.bench.wire import BadMessage
from planbench.errors import InvalidConfigError, PlanbenchError

log = logging.getLogger(__name__)

__all__ = ["ClusterInfo", "RayExecutor", "RayNotInstalledError", "RayStats", "import_ray"]

INSTALL = "pip install 'planbench[ray]'"
MAX_LOSSES = 2
"""A run whose actor died this many times ends the benchmark (something is wrong with the cluster)."""
ACTOR_RESTARTS = 4
"""How often Ray restarts a dead actor (on any node with a free CPU)."""
LOOPBACK_VARIABLE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
"""With "0", a Ray instance started here uses 127.0.0.1 for every process (Ray's node address)."""


class RayNotInstalledError(PlanbenchError):
    """``--executor ray`` without Ray installed."""

    def __init__(self) -> None:
        super().__init__(f"--executor ray needs Ray, which is not installed: {INSTALL} (or pip install 'ray>=2.9')")


def import_ray() -> Any:
    """The ``ray`` module; :class:`RayNotInstalledError` (how to install it) when it is missing."""
    try:
        import ray
    except ImportError as exc:
        raise RayNotInstalledError() from exc
    return ray


@dataclass(frozen=True)
class ClusterInfo:
    """The cluster a benchmark runs on: alive ``nodes``, their ``cpus``, and the ``workers`` (actors,
    one CPU each) the benchmark starts."""

    address: str
    nodes: int
    cpus: float
    workers: int

    def size(self) -> str:
        node = "node" if self.nodes == 1 else "nodes"
        worker = "worker" if self.workers == 1 else "workers"
        return f"{self.nodes} {node}, {self.workers} {worker}"

    def describe(self) -> str:
        return f"Ray cluster {self.address} ({self.size()})"


@dataclass
class RayStats:
    """What the last :meth:`RayExecutor.run` cost the driver: per run, the ``overhead`` [s] Ray added
    (from handing the run to an actor to its record being decoded here, minus the run's own
    ``elapsed`` in its slot), and ``driver_cpu`` [s], this process's CPU time over the whole run
    (Ray's client threads, decoding and the database writes), for ``rows`` rows."""

    overhead: list[float] = field(default_factory=list)
    driver_cpu: float = 0.0
    rows: int = 0


@dataclass
class RayExecutor:
    """Runs tasks on Ray actors and hands each record to ``on_record`` in this process.

    ``jobs``: actors (default, or 0: every CPU of the cluster); ``address``: a running cluster
    (``"auto"``, ``"127.0.0.1:6379"``, ``"ray://head:10001"``), or None for a Ray instance started
    here on the loopback and stopped at the end (or the one this process is already connected to);
    ``runtime_env``: Ray's runtime environment for the actors (``py_modules``, ``working_dir``,
    ``env_vars``: how plugins not installed on every node reach them).
    """

    jobs: int | None = None
    address: str | None = None
    threads_per_worker: int = 1
    runtime_env: dict[str, Any] | None = None
    stats: RayStats = field(default_factory=RayStats, repr=False)
    _started: bool = field(default=False, repr=False)
    _info: ClusterInfo | None = field(default=None, repr=False)

    def connect(self) -> ClusterInfo:
        """Connect to the cluster (start a local instance when there is no address); idempotent."""
        if self._info is not None:
            return self._info
        if self.jobs is not None and self.jobs < 0:
            raise InvalidConfigError(f"--jobs must be >= 1 (or 0: all the cluster's CPUs), got {self.jobs}")
        local = not self.address
        if local:  # read when Ray is imported: a local instance stays on the loopback
            os.environ.setdefault(LOOPBACK_VARIABLE, "0")
        ray = import_ray()
        if not ray.is_initialized():
            options: dict[str, Any] = {
                "runtime_env": self.runtime_env,
                "log_to_driver": False,  # actors print nothing; keeps the progress bar clean
                "logging_level": logging.WARNING,
            }
            if local:
                options.update(num_cpus=self.jobs or default_jobs(), include_dashboard=False)
            try:
                ray.init(address=self.address or None, **options)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                raise PlanbenchError(f"cannot connect to the Ray cluster at {self.address!r}: {exc}") from exc
            self._started = True
        nodes = [n for n in ray.nodes() if n.get("Alive")]
        cpus = float(sum(n.get("Resources", {}).get("CPU", 0.0) for n in nodes))
        workers = self.jobs or max(1, int(cpus))
        if workers > cpus:
            log.warning("%d Ray workers asked for, the cluster has %g CPUs: the others wait for CPUs", workers, cpus)
        address = ray.get_runtime_context().gcs_address
        self._info = ClusterInfo(address, len(nodes), cpus, workers)
        return self._info

    def describe(self) -> str:
        return self.connect().describe()

    def run(self, tasks: Sequence[RunTask], on_record: Callable[[RunTask, Record], None]) -> None:
        """Run every task on the cluster; ``on_record(task, record)`` here as each one ends (in the
        order they end). On an exception (KeyboardInterrupt included) the actors are killed."""
        if not tasks:
            return
        ray = import_ray()
        info = self.connect()
        actor_class = ray.remote(num_cpus=1, max_restarts=ACTOR_RESTARTS, max_concurrency=1)(SlotActor)
        actors = [
            actor_class.options(scheduling_strategy="SPREAD").remote(self.threads_per_worker)
            for _ in range(min(info.workers, len(tasks)))
        ]
        clean = False
        self.stats = RayStats()
        cpu = time.process_time()
        try:
            _dispatch(ray, actors, tasks, on_record, self.stats)
            clean = True
        finally:
            self.stats.driver_cpu = time.process_time() - cpu
            _stop(ray, actors, graceful=clean)

    def close(self) -> None:
        """Disconnect (and stop the Ray instance this executor started)."""
        if self._started:
            import_ray().shutdown()
            self._started = False
        self._info = None


def _dispatch(
    ray: Any, actors: list[Any], tasks: Sequence[RunTask], on_record: Callable[[RunTask, Record], None], stats: RayStats
) -> None:
    """Hand tasks to idle actors until every one has a record."""
    pending: deque[RunTask] = deque(tasks)
    idle: deque[Any] = deque(actors)
    in_flight: dict[Any, tuple[Any, RunTask, float]] = {}
    losses: dict[tuple[str, str, str, int], int] = {}
    while pending or in_flight:
        while idle and pending:
            actor, task = idle.popleft(), pending.popleft()
            in_flight[actor.run.remote(task_to_wire(task))] = (actor, task, time.monotonic())
        done, _ = ray.wait(list(in_flight), num_returns=1)
        for ref in done:
            actor, task, sent = in_flight.pop(ref)
            idle.append(actor)  # a dead actor is restarted by Ray; its next call waits for that
            try:
                data = ray.get(ref)
            except ray.exceptions.RayActorError as exc:
                losses[task.key] = losses.get(task.key, 0) + 1
                if losses[task.key] >= MAX_LOSSES:
                    raise PlanbenchError(
                        f"run {task.key} lost its Ray worker {MAX_LOSSES} times (last: {_first_line(exc)}); "
                        "check the cluster (is planbench, with the suite's plugins, installed on every node?), "
                        "then run the same command with --resume"
                    ) from exc
                log.warning("run %s lost its Ray worker (%s); it runs again", task.key, _first_line(exc))
                pending.appendleft(task)
                continue
            except ray.exceptions.RayError as exc:
                raise PlanbenchError(f"a Ray worker failed running {task.key}: {exc}") from exc
            try:
                record = record_from_wire(data)
            except BadMessage as exc:  # pragma: no cover (the actor is planbench's own code)
                raise PlanbenchError(f"a Ray worker sent back an unreadable record for {task.key}: {exc}") from exc
            stats.overhead.append(time.monotonic() - sent - record["elapsed"])
            stats.rows += 1
            on_record(task, record)


def _stop(ray: Any, actors: list[Any], graceful: bool) -> None:
    """End the actors: let them stop their slots (and remove their files) when the run ended well,
    then kill them (their slots' processes die with them)."""
    if graceful:
        try:
            ray.wait([a.close.remote() for a in actors], num_returns=len(actors), timeout=10)
        except Exception:  # noqa: BLE001 (the kill below ends them anyway)
            log.debug("closing the Ray actors failed", exc_info=True)
    for actor in actors:
        try:
            ray.kill(actor, no_restart=True)
        except Exception:  # noqa: BLE001
            log.debug("killing a Ray actor failed", exc_info=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:300] if text else type(exc).__name__
