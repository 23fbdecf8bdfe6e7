"""A run's record: what the benchmark stores of every run, whether it ended or was ended.

Made in the main process from a worker's checked result and the validator's verdict
(:func:`record_from`), or for a run that produced nothing of its own (:func:`failure_record`).
"""

from __future__ import annotations

import math
from typing import Any

from planbench.bench.procs import OUTPUT_HEADER
from planbench.validate import Evaluation

__all__ = ["Record", "failure_record", "ran_out_of_memory", "record_from"]

Record = dict[str, Any]
"""The fields :meth:`planbench.bench.db.ResultsDB.add_run` stores besides the run's key."""


def failure_record(status: str, message: str, traceback: str = "", planning_time: float = math.nan) -> Record:
    """A record for a run that produced none itself (killed, crashed, or a result not kept)."""
    evaluation = Evaluation(False, f"{status}: {message}", status, planning_time, math.nan).as_dict()
    return {
        "evaluation": evaluation,
        "message": message,
        "traceback": traceback,
        "path": None,
        "times": None,
        "info": {},
        "wall_time": math.nan,
        "validation_time": math.nan,
        "elapsed": math.nan,
        "pid": None,
        "host": "",
    }


def record_from(fields: dict[str, Any], evaluation: dict[str, Any] | None, validation_time: float) -> Record:
    """The record of a run from its checked raw result and the validator's verdict (None when there
    is nothing to validate: the run could not be prepared)."""
    if evaluation is None:
        status, message = fields["status"], fields["message"]
        failure = f"{status}: {message}" if message else status
        evaluation = Evaluation(False, failure, status, fields["planning_time"], fields["setup_time"]).as_dict()
    wall = fields["wall_time"] + (validation_time if math.isfinite(validation_time) else 0.0)
    return {
        "evaluation": evaluation,
        "message": fields["message"],
        "traceback": fields["traceback"],
        "path": fields["path"],
        "times": fields["times"],
        "info": fields["info"],
        "wall_time": wall,
        "validation_time": validation_time,
        "elapsed": math.nan,
        "pid": fields["pid"],
        "host": fields["host"],
    }


def ran_out_of_memory(message: str, traceback: str) -> bool:
    """Whether a run ended in ``MemoryError``: the harness's message names it, or the traceback's
    exception line does (the worker's output, appended after :data:`OUTPUT_HEADER`, does not count)."""
    if "MemoryError" in message:
        return True
    own = traceback.split(OUTPUT_HEADER, 1)[0]
    return any(line.startswith("MemoryError") for line in own.splitlines())
