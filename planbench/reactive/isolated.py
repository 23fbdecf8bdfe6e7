"""One closed-loop run with the controller in a process of its own, from Python.

:func:`run_isolated` is what the benchmark does for a closed-loop run, without the benchmark: the
controller is built and served in a spawned, confined process
(:func:`planbench.reactive.bench.serve_run`) and the simulation runs here, charging the CPU time
that process consumed (:mod:`planbench.reactive.remote`). Use it where the timing must be the
benchmark's; :func:`planbench.reactive.runner.run_scenario` runs a controller object in this
process instead (for debugging, or a controller of your own not yet registered).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import socket
from typing import Any

from planbench.errors import PlanbenchError
from planbench.reactive.runner import RunRecord, RunSettings
from planbench.reactive.scenario import Scenario

__all__ = ["ControllerSetupError", "IsolatedRun", "run_isolated"]

SETUP_TIMEOUT = 120.0
"""[s] for the controller's process to start, build the controller and set it up."""


class ControllerSetupError(PlanbenchError):
    """The controller's process could not build or set up the controller."""


class IsolatedRun:
    """A run's record and the wall-clock hand-off of each call [s] (round trip less the CPU charged)."""

    def __init__(self, record: RunRecord, handoff: list[float]) -> None:
        self.record = record
        self.handoff = handoff


def _controller_main(
    sock: socket.socket, scenario: dict[str, Any], name: str, settings: dict[str, Any], seed: int, ready: Any
) -> None:
    from planbench.reactive.bench import serve_run
    from planbench.runtime.threads import limit_threads

    os.setsid()  # a group of its own: killing it takes whatever it holds
    limit_threads(1)  # one core, as a benchmark worker
    fields = serve_run(Scenario.from_dict(scenario), name, settings, seed, sock, lambda phase: ready.send(phase))
    if fields is not None:
        ready.send(f"error: {fields['message']}")


def run_isolated(
    scenario: Scenario,
    controller: str,
    *,
    seed: int = 0,
    settings: RunSettings | None = None,
    cpu: int | None = None,
    **controller_settings: Any,
) -> IsolatedRun:
    """Run the registered controller ``controller`` (with ``controller_settings``) on ``scenario``
    in a confined process of its own; ``cpu``: pin both processes to that core (None: the core this
    process is on)."""
    from planbench.reactive.bench import simulate_remote
    from planbench.reactive.isolation import make_undumpable

    make_undumpable()
    ctx = mp.get_context("spawn")
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    ready_here, ready_there = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=_controller_main,
        args=(theirs, scenario.to_dict(), controller, dict(controller_settings), seed, ready_there),
        daemon=True,
        name="planbench-controller",
    )
    proc.start()
    assert proc.pid is not None  # set by start()
    theirs.close()
    ready_there.close()
    try:
        if not ready_here.poll(SETUP_TIMEOUT):
            raise ControllerSetupError(f"controller {controller!r} was not set up within {SETUP_TIMEOUT:g} s")
        try:
            phase = ready_here.recv()
        except EOFError:
            raise ControllerSetupError(f"the process of controller {controller!r} died during setup") from None
        if phase != "plan":
            raise ControllerSetupError(f"controller {controller!r}: {phase}")
        record, handoff = simulate_remote(scenario, ours, proc.pid, seed=seed, settings=settings, cpu=cpu)
        return IsolatedRun(record, handoff)
    finally:
        ours.close()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join()
