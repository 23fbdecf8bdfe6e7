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

Connecting to a cluster (``--address``) is bounded and can be interrupted: the address is parsed
and checked first, without Ray (:func:`check_reachable`: a TCP connection and the start of a gRPC
handshake, :data:`CONNECT_TIMEOUT` seconds at most), so an unreachable, refusing or silent address
is a :class:`RayClusterUnreachableError` naming it within seconds; Ray's own connection retries are
then cut from about 20 to :data:`RAY_CONNECT_RETRIES`, and ``ray.init`` runs in a helper thread
while this one waits, so Ctrl-C ends the command at once (Ray's C++ client blocks signals for as
long as it waits).

Ray is imported here only, when the executor is used: it is an optional extra.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import sys
import threading
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

__all__ = [
    "ClusterInfo",
    "RayClusterUnreachableError",
    "RayExecutor",
    "RayNotInstalledError",
    "RayStats",
    "check_reachable",
    "cluster_endpoint",
    "import_ray",
]

INSTALL = "pip install 'planbench[ray]'"
MAX_LOSSES = 2
"""A run whose actor died this many times ends the benchmark (something is wrong with the cluster)."""
ACTOR_RESTARTS = 4
"""How often Ray restarts a dead actor (on any node with a free CPU)."""
LOOPBACK_VARIABLE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
"""With "0", a Ray instance started here uses 127.0.0.1 for every process (Ray's node address)."""
CONNECT_TIMEOUT = 5.0
"""[s] The reachability check of a cluster address: the TCP connection, then the server's first
answer to a gRPC (HTTP/2) greeting, each within this time."""
RAY_CONNECT_RETRIES = 3
"""Attempts Ray makes to reach a cluster's GCS once the address passed the check (Ray's default, 20,
takes minutes when every attempt waits for its timeouts); ``RAY_NUM_REDIS_GET_RETRIES`` set in the
environment wins."""
RAY_CONNECT_ENV = {"RAY_NUM_REDIS_GET_RETRIES": str(RAY_CONNECT_RETRIES), "RAY_py_gcs_connect_timeout_s": "5"}
"""Ray's settings of its connection attempts (5 s for the GCS's first answer instead of 30), set
while connecting to an address when Ray is imported then (Ray reads them on import; a variable
already set is left as it is)."""
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"
"""A client's HTTP/2 connection preface and an empty SETTINGS frame: a gRPC server answers with its
own SETTINGS frame (RFC 9113, section 3.4)."""


class RayNotInstalledError(PlanbenchError):
    """``--executor ray`` without Ray installed."""

    def __init__(self) -> None:
        super().__init__(f"--executor ray needs Ray, which is not installed: {INSTALL} (or pip install 'ray>=2.9')")


class RayClusterUnreachableError(PlanbenchError):
    """``--address`` names a cluster that cannot be reached (no such host, refused, no answer)."""

    def __init__(self, address: str, problem: str) -> None:
        self.address = address
        self.problem = problem
        super().__init__(f"cannot connect to the Ray cluster at {address!r}: {problem}")


def cluster_endpoint(address: str | None) -> tuple[str, int] | None:
    """The (host, port) that ``ray.init(address=...)`` connects to first, for the forms planbench
    documents: ``HOST:PORT`` (the GCS; a bare host is Ray's error), ``ray://HOST[:PORT]`` (Ray
    Client, port 10001 by default), ``[IPv6]:PORT``. ``"auto"`` is ``RAY_ADDRESS`` when that is set;
    None when there is nothing to check here (no address, ``"local"``, ``"auto"`` without
    ``RAY_ADDRESS``: Ray finds a local cluster itself). :class:`InvalidConfigError` for a malformed
    address or port."""
    text = (address or "").strip()
    if text in ("", "auto"):
        text = os.environ.get("RAY_ADDRESS", "").strip()
        if text in ("", "auto"):
            return None
    if text == "local":
        return None
    default = None
    if text.startswith("ray://"):
        text, default = text[len("ray://") :], 10001
    text = text.split("/", 1)[0]
    if text.startswith("["):
        host, bracket, rest = text[1:].partition("]")
        if not bracket or (rest and not rest.startswith(":")):
            raise InvalidConfigError(f"--address {address!r}: an IPv6 address is written [HOST]:PORT")
        port_text = rest[1:]
    elif text.count(":") == 1:
        host, _, port_text = text.partition(":")
    elif ":" not in text:
        host, port_text = text, ""
    else:
        raise InvalidConfigError(f"--address {address!r}: write an IPv6 address as [HOST]:PORT")
    if not host:
        raise InvalidConfigError(f"--address {address!r} names no host: give HOST:PORT, ray://HOST:10001 or auto")
    if not port_text:
        if default is None:
            raise InvalidConfigError(
                f"--address {address!r} has no port: give HOST:PORT (the head's GCS port, 6379 by default)"
            )
        return host, default
    if not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise InvalidConfigError(f"--address {address!r}: the port must be a number from 1 to 65535, got {port_text!r}")
    return host, int(port_text)


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT, given: str | None = None) -> None:
    """Raise :class:`RayClusterUnreachableError` unless ``address`` (:func:`cluster_endpoint`)
    accepts a TCP connection and answers a gRPC greeting within ``timeout`` [s] each (the greeting is
    skipped when Ray uses TLS, ``RAY_USE_TLS``). Needs no Ray; runs in a helper thread so that name
    resolution, which no timeout bounds, cannot hold up Ctrl-C or the deadline. ``given``: the
    address as the user gave it, named in the error when it differs (``"auto"``)."""
    endpoint = cluster_endpoint(address)
    if endpoint is None:
        return
    host, port = endpoint
    if given is not None and given != address:
        address = f"{given}, found at {address}"
    tls = os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true")
    found = _in_thread(lambda: _probe(host, port, timeout, greet=not tls), 3 * timeout)
    if found is None:
        raise RayClusterUnreachableError(address, f"no answer from {host}:{port} within {3 * timeout:g} s")
    if found:
        raise RayClusterUnreachableError(address, found)


def _probe(host: str, port: int, timeout: float, greet: bool) -> str:
    """Why ``host:port`` is no Ray endpoint ("" when it looks like one)."""
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.gaierror as exc:
        return f"cannot resolve host {host!r} ({exc.strerror or exc})"
    except TimeoutError:
        return f"{host}:{port} did not accept a connection within {timeout:g} s (unreachable, or a firewall drops it)"
    except OSError as exc:
        return f"{host}:{port} refused the connection ({exc.strerror or exc}): is the cluster running, on this port?"
    with sock:
        if not greet:
            return ""
        try:
            sock.sendall(_HTTP2_PREFACE)
            head = sock.recv(9)
        except TimeoutError:
            return f"{host}:{port} accepts connections but did not answer within {timeout:g} s; it is not a Ray cluster"
        except OSError as exc:
            return f"{host}:{port} accepts connections, then failed ({exc.strerror or exc}); it is not a Ray cluster"
    if len(head) < 9 or head[3] != 0x04:
        return f"{host}:{port} answers, but not as a Ray cluster (gRPC) does: is this the head's GCS port?"
    return ""


def _in_thread(fn: Callable[[], Any], timeout: float | None) -> Any:
    """``fn()`` run in a daemon thread while this one waits (so Ctrl-C interrupts the wait at once);
    its exception is raised here; None when ``timeout`` [s] passes first (the thread is left to end
    on its own)."""
    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 (handed to the waiting thread)
            box["error"] = exc

    thread = threading.Thread(target=target, daemon=True, name="planbench-ray-connect")
    thread.start()
    deadline = None if timeout is None else time.monotonic() + timeout
    while thread.is_alive():
        left = None if deadline is None else deadline - time.monotonic()
        if left is not None and left <= 0:
            return None
        thread.join(0.1 if left is None else min(0.1, left))
    if "error" in box:
        raise box["error"]
    return box.get("value")


def _ray_target(address: str) -> str:
    """The address ``ray.init`` connects to for ``address``: ``"auto"`` found as Ray finds it (Ray's
    own lookup, best effort: its module is private), a loopback address as Ray rewrites it."""
    if address.startswith("ray://"):
        return address
    try:
        from ray._private.services import canonicalize_bootstrap_address
    except ImportError:  # pragma: no cover (another Ray version)
        return address
    try:
        found = canonicalize_bootstrap_address(address, None)
    except ConnectionError as exc:  # "auto" and no cluster found
        raise RayClusterUnreachableError(address, _first_line(exc)) from None
    except Exception:  # noqa: BLE001 (a private function: ray.init reports the address itself)
        return address
    return str(found) if found else address


def _init_bounded(ray: Any, address: str, options: dict[str, Any]) -> None:
    """``ray.init(address=...)`` with Ray's connection attempts bounded (:data:`RAY_CONNECT_RETRIES`),
    in a helper thread so that Ctrl-C is not held up by Ray's C++ client."""
    saved = os.environ.get("RAY_NUM_REDIS_GET_RETRIES")
    # Ray read RAY_NUM_REDIS_GET_RETRIES when it was imported (just now, or earlier in this process)
    constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
    retries = getattr(constants, "NUM_REDIS_GET_RETRIES", None)
    if isinstance(retries, int) and saved is None:
        constants.NUM_REDIS_GET_RETRIES = min(retries, RAY_CONNECT_RETRIES)  # type: ignore[union-attr]
    quiet = _Without("SIGTERM handler is not set")  # Ray's warning about its thread; planbench sets it below
    worker_log = logging.getLogger("ray._private.worker")
    worker_log.addFilter(quiet)
    try:
        _in_thread(lambda: ray.init(address=address, **options), None)
    finally:
        worker_log.removeFilter(quiet)
        if isinstance(retries, int):
            constants.NUM_REDIS_GET_RETRIES = retries  # type: ignore[union-attr]
    if threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None):  # as ray.init does on the main thread
            signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))


class _Without(logging.Filter):
    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text

    def filter(self, record: logging.LogRecord) -> bool:
        return self.text not in record.getMessage()


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
        else:
            cluster_endpoint(self.address)  # a malformed address before importing Ray
        saved = {k: os.environ.get(k) for k in RAY_CONNECT_ENV}
        if not local and "ray" not in sys.modules:  # read when Ray is imported
            for key, value in RAY_CONNECT_ENV.items():
                os.environ.setdefault(key, value)
        try:
            ray = import_ray()
        finally:
            for key, before in saved.items():
                if before is None:
                    os.environ.pop(key, None)
        if not local and not ray.is_initialized():
            # bounded, and before Ray's client (which waits minutes for an unreachable cluster, deaf to Ctrl-C)
            check_reachable(_ray_target(str(self.address)), given=str(self.address))
        if not ray.is_initialized():
            options: dict[str, Any] = {
                "runtime_env": self.runtime_env,
                "log_to_driver": False,  # actors print nothing; keeps the progress bar clean
                "logging_level": logging.WARNING,
            }
            if local:
                options.update(num_cpus=self.jobs or default_jobs(), include_dashboard=False)
            try:
                if local:
                    ray.init(address=None, **options)
                else:
                    _init_bounded(ray, str(self.address), options)
            except (ConnectionError, ValueError, RuntimeError, TimeoutError) as exc:
                if local:
                    raise PlanbenchError(f"cannot start a local Ray instance: {_first_line(exc)}") from exc
                raise RayClusterUnreachableError(str(self.address), _first_line(exc)) from exc
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
