"""One benchmark run as a typed record: what the parent builds from a suite and a worker receives.

A :class:`RunTask` crosses the process boundary as data only: :meth:`RunTask.to_wire` gives JSON
data (sent in a :mod:`planbench.bench.wire` message, never a pickle) and :meth:`RunTask.from_wire`
checks every field's type on the way back in.
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from planbench.bench.db import RunKey
from planbench.bench.kinds import KINDS
from planbench.bench.suite import (
    DEFAULT_GRACE,
    DEFAULT_MEMORY_LIMIT,
    DEFAULT_SETUP_TIMEOUT,
    DEFAULT_TIME_LIMIT,
    DEFAULT_VALIDATION_TIMEOUT,
)
from planbench.bench.wire import BadMessage

__all__ = ["RunTask"]


@dataclass(frozen=True)
class RunTask:
    """One run: ``planner`` with ``settings`` on problem ``problem_ref`` with ``seed``, under the
    suite's limits [s, MiB] (``memory_limit`` 0: none), ``validation`` settings and ``postprocess`` stage.

    ``settings`` are already parsed to their fields' types (JSON data). ``run_settings`` are the
    suite's result-changing settings as stored with every row (:meth:`Suite.settings_json`).
    """

    suite: str
    problem_id: str
    problem_ref: str
    label: str
    planner: str
    seed: int
    settings: dict[str, Any] = field(default_factory=dict)
    family: str = ""
    planner_version: str = ""
    time_limit: float = DEFAULT_TIME_LIMIT
    grace: float = DEFAULT_GRACE
    setup_timeout: float = DEFAULT_SETUP_TIMEOUT
    validation_timeout: float = DEFAULT_VALIDATION_TIMEOUT
    memory_limit: float = DEFAULT_MEMORY_LIMIT
    validation: dict[str, Any] = field(default_factory=dict)
    postprocess: dict[str, Any] = field(default_factory=dict)
    """The suite's post-processing stage (:class:`planbench.bench.postprocess.PostprocessSettings` fields;
    empty: none), run by the validator on a valid path."""
    fresh_process: bool = False
    run_settings: dict[str, Any] = field(default_factory=dict)
    kind: str = "static"
    """``"static"``: ``planner`` plans ``problem_ref``; ``"dynamic"``: controller ``planner`` runs
    closed-loop on scenario ``problem_ref`` (:mod:`planbench.reactive.runner`)."""
    timing: str = "measured"
    """Closed-loop runs: the compute time charged (:class:`planbench.reactive.runner.RunSettings`)."""

    @property
    def key(self) -> RunKey:
        return (self.suite, self.problem_id, self.label, self.seed)

    def to_wire(self) -> dict[str, Any]:
        """The record as JSON data (``json.dumps`` takes it; the dicts are copies)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name in _DICTS:
            out[name] = json.loads(json.dumps(out[name], allow_nan=True))
        return out

    @classmethod
    def from_wire(cls, data: Any) -> RunTask:
        """The record :meth:`to_wire` gave; :class:`~planbench.bench.wire.BadMessage` naming the
        field when ``data`` is not one."""
        if not isinstance(data, Mapping):
            raise BadMessage(f"a run task must be a JSON object, got {type(data).__name__}")
        names = {f.name for f in dataclasses.fields(cls)}
        missing, unknown = sorted(names - set(data)), sorted(str(k)[:40] for k in set(data) - names)
        if missing or unknown:
            raise BadMessage(f"run task: fields missing {missing}, unknown {unknown}")
        values: dict[str, Any] = {}
        for name in names:
            value = data[name]
            kind = _FIELD_KINDS[name]
            if kind is float and type(value) is int:
                value = float(value)
            if type(value) is not kind or (isinstance(value, float) and math.isnan(value)):
                raise BadMessage(f"run task field {name!r}: expected {kind.__name__}, got {type(value).__name__}")
            values[name] = value
        if values["kind"] not in KINDS:
            raise BadMessage(f"run task field 'kind': {values['kind'][:40]!r} is not one of {sorted(KINDS)}")
        return cls(**values)


def _field_kinds() -> dict[str, type]:
    """Each field's plain type (``dict[str, Any]`` -> ``dict``), from the annotations."""
    hints = typing.get_type_hints(RunTask)
    return {f.name: typing.get_origin(hints[f.name]) or hints[f.name] for f in dataclasses.fields(RunTask)}


_FIELD_KINDS = _field_kinds()
_DICTS = [name for name, kind in _FIELD_KINDS.items() if kind is dict]
