"""Where a benchmark's runs execute: ``local`` (a process pool on this machine,
:class:`~planbench.bench.runner.Runner`) or ``ray`` (a Ray cluster,
:class:`~planbench.bench.ray_executor.RayExecutor`). Both take the same tasks and hand each record
to the same callback in this process, which alone writes the results file."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

from planbench.bench.records import Record
from planbench.bench.runner import Runner
from planbench.bench.task import RunTask
from planbench.errors import InvalidConfigError

__all__ = ["EXECUTORS", "Executor", "make_executor"]

EXECUTORS = ("local", "ray")


class Executor(Protocol):
    def run(self, tasks: Sequence[RunTask], on_record: Callable[[RunTask, Record], None]) -> None: ...

    def close(self) -> None:
        """Release what the executor holds (worker processes, a Ray connection); idempotent."""


def make_executor(
    kind: str = "local",
    jobs: int | None = None,
    address: str | None = None,
    runtime_env: dict[str, Any] | None = None,
) -> Executor:
    """The executor ``kind`` with ``jobs`` workers (default: all cores, of this machine or the
    cluster); ``address`` and ``runtime_env`` are the Ray cluster's (``ray`` only)."""
    if kind == "local":
        if address or runtime_env:
            raise InvalidConfigError("--address and a Ray runtime environment need --executor ray")
        return Runner(jobs)
    if kind == "ray":
        from planbench.bench.ray_executor import RayExecutor  # Ray is optional: imported when used

        return RayExecutor(jobs or None, address or None, runtime_env=runtime_env)
    raise InvalidConfigError(f"unknown executor {kind!r}: choose one of {', '.join(EXECUTORS)}")
