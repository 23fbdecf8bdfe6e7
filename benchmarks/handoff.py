"""The closed loop's hand-off across the process boundary: one step call's round trip.

    python benchmarks/handoff.py [--calls 20000] [--load]

A controller that returns zeros (``NullController`` below) is served in a confined process of its
own (:func:`planbench.reactive.bench.serve_run`, as in the benchmark) and stepped ``--calls``
times by a :class:`~planbench.reactive.remote.RemoteController` (the Panda: 7 joints). Printed,
pinned to one core (as the benchmark runs) and not pinned: the wall-clock round trip of a call,
the CPU time charged for it (the controller's process, all threads) and the hand-off (round trip
less the charge), median and p99 [µs]; and, as the floor, a bare round trip of 80 bytes over a
socket pair between two Python processes doing nothing else. ``--load`` runs one busy process
per core beside it.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import socket
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from planbench.reactive.controller import Controller  # noqa: E402


class NullController(Controller):
    """Joint velocities of zero, at once."""

    name = "null"

    def step(self, t, q, observation, goal):  # type: ignore[no-untyped-def]
        return np.zeros(len(q))


def _echo(sock: socket.socket) -> None:
    while True:
        m = sock.recv(4096)
        if not m:
            return
        sock.send(m)


def bare(calls: int, cpu: int) -> np.ndarray:
    """Round trips [s] of 80 bytes between two processes pinned to ``cpu``."""
    ctx = mp.get_context("spawn")
    a, b = socket.socketpair()
    p = ctx.Process(target=_echo, args=(b,), daemon=True)
    p.start()
    assert p.pid is not None  # set by start()
    b.close()
    os.sched_setaffinity(p.pid, {cpu})
    own = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {cpu})
    out = np.empty(calls)
    msg = b"x" * 80
    for i in range(calls):
        t0 = time.perf_counter()
        a.send(msg)
        a.recv(4096)
        out[i] = time.perf_counter() - t0
    os.sched_setaffinity(0, own)
    a.close()
    p.join()
    return out


def served(calls: int, cpu: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(round trip, charged, hand-off) [s] of ``calls`` step calls to a served NullController."""
    from planbench.reactive.isolated import _controller_main
    from planbench.reactive.remote import RemoteController
    from planbench.reactive.sets import load_scenario

    scenario = load_scenario("dynamic:panda_swinging_fast_depth/0001")
    ctx = mp.get_context("spawn")
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    ready, there = ctx.Pipe(duplex=False)
    p = ctx.Process(
        target=_controller_main, args=(theirs, scenario.to_dict(), "handoff:NullController", {}, 0, there), daemon=True
    )
    p.start()
    assert p.pid is not None  # set by start()
    theirs.close()
    assert ready.recv() == "plan"
    own = os.sched_getaffinity(0)
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
        os.sched_setaffinity(p.pid, {cpu})
    port = RemoteController(ours, p.pid, 7)
    q = np.array(scenario.problem.start, dtype=float)
    charged = np.empty(calls)
    for i in range(calls):
        _, charged[i] = port.step(i * 1e-3, q, None, None)
    os.sched_setaffinity(0, own)
    ours.close()
    p.join(5)
    return np.array(port.wall), charged, np.array(port.handoff)


def _stats(x: np.ndarray) -> str:
    x = x[len(x) // 20 :] * 1e6  # the first 5 % warm caches and branch predictors
    return f"{np.median(x):7.1f} {np.percentile(x, 99):7.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--load", action="store_true", help="one busy process per core beside it")
    args = ap.parse_args()
    busy = []
    if args.load:
        busy = [mp.get_context("spawn").Process(target=_spin, daemon=True) for _ in range(os.cpu_count() or 1)]
        for b in busy:
            b.start()
    cpu = sorted(os.sched_getaffinity(0))[0]
    print(f"{'[µs] median p99':<34} round trip       charged         hand-off")
    print(f"{'bare socket pair, one core':<34} {_stats(bare(args.calls, cpu))}")
    for label, where in (("served, pinned to one core", cpu), ("served, not pinned", None)):
        wall, charged, handoff = served(args.calls, where)
        print(f"{label:<34} {_stats(wall)}  {_stats(charged)}  {_stats(handoff)}")
    for b in busy:
        b.kill()


def _spin() -> None:
    while True:
        pass


if __name__ == "__main__":
    main()
