"""The Ray side of ``--executor ray``: an actor body that runs one run per call on a warm local slot.

Each actor owns a one-slot :class:`~planbench.bench.runner.Runner` on its node, so a run on the
cluster gets exactly what it gets on one machine: a spawned worker that plans and a spawned
validator that never imports planner code, deadlines enforced by killing process groups, crash,
timeout and error rows, ``fresh_process``, the memory limit and output capture. The actor process
itself runs no planner code (as the local benchmark process), so it is as trusted as that one.

Both directions are data, never pickled objects of planbench's: the driver sends a
:class:`~planbench.bench.task.RunTask` as a :mod:`planbench.bench.wire` message and gets the
record back as one (JSON and float64 bytes), which :func:`record_from_wire` checks. This module
does not import Ray: Ray wraps :class:`SlotActor` at run time (:mod:`planbench.bench.ray_executor`).
"""

from __future__ import annotations

import os
import socket
import threading
from typing import Any

from planbench.bench.records import Record
from planbench.bench.runner import Runner
from planbench.bench.task import RunTask
from planbench.bench.wire import BadMessage, decode, encode

__all__ = ["SlotActor", "record_from_wire", "record_to_wire", "task_from_wire", "task_to_wire"]

RECORD_KEYS = frozenset(
    {"evaluation", "message", "traceback", "path", "times", "info"}
    | {"wall_time", "validation_time", "elapsed", "pid", "host"}
)
"""The fields of a run's record (:func:`planbench.bench.records.record_from`)."""
_ARRAYS = ("path", "times")


def task_to_wire(task: RunTask) -> bytes:
    return encode({"type": "run", "task": task.to_wire()})


def task_from_wire(data: bytes) -> RunTask:
    header, _ = decode(data)
    return RunTask.from_wire(header.get("task"))


def record_to_wire(record: Record) -> bytes:
    header = {k: v for k, v in record.items() if k not in _ARRAYS}
    return encode({"type": "record", "record": header}, {k: record.get(k) for k in _ARRAYS})


def record_from_wire(data: bytes) -> Record:
    """The record :func:`record_to_wire` made; :class:`BadMessage` when ``data`` is not one."""
    header, arrays = decode(data)
    record = header.get("record")
    if not isinstance(record, dict) or set(record) | set(_ARRAYS) != RECORD_KEYS:
        raise BadMessage("not a run's record")
    if not isinstance(record["evaluation"], dict) or not isinstance(record["info"], dict):
        raise BadMessage("a run's record without an evaluation or info object")
    if set(arrays) - set(_ARRAYS):
        raise BadMessage(f"unexpected arrays {sorted(arrays)[:5]}")
    return {**record, **{k: arrays.get(k) for k in _ARRAYS}}


class SlotActor:
    """One benchmark slot on a Ray node; ``run`` takes a task's wire bytes, returns its record's."""

    def __init__(self, threads_per_worker: int = 1) -> None:
        # actors share a node's cores: a closed loop stays on the core its simulation starts on
        self._runner = Runner(1, threads_per_worker=threads_per_worker, pin=False)
        self._runner.keep_warm = True  # a dead worker is replaced at once, before the next call
        self._runner.start()  # the slot starts (~1 s) while the driver is busy elsewhere

    def where(self) -> dict[str, Any]:
        """Host, pid and Ray node of this actor, and whether calls run on the main thread (the
        slot's processes die with the thread that started them: ``PR_SET_PDEATHSIG``)."""
        import ray  # in a Ray worker, ray is there

        return {
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "node": ray.get_runtime_context().get_node_id(),
            "main_thread": threading.current_thread() is threading.main_thread(),
        }

    def run(self, data: bytes) -> bytes:
        task = task_from_wire(data)
        records: list[Record] = []
        self._runner.feed([task], lambda _task, record: records.append(record))
        return record_to_wire(records[0])

    def close(self) -> None:
        """Stop the slot's processes and remove their output files (a kill of the actor also ends
        them, by ``PR_SET_PDEATHSIG``, but leaves the files)."""
        self._runner.close()
