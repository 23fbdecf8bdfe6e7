"""One root exception for planbench, and the specific errors users can act on.

A failed *plan* is never an exception (it is a :class:`~planbench.planner.PlanStatus`); these
errors are for input that cannot be used at all: a malformed file, an unknown name, a bad setting.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping, Sequence
from typing import Any


class PlanbenchError(Exception):
    """Root of every error planbench raises on purpose."""


class RobotFileError(PlanbenchError):
    """A robot description or robot settings file cannot be used."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ProblemFileError(PlanbenchError):
    """A scene or problem file (JSON) cannot be used."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ScenarioFileError(PlanbenchError):
    """A scenario file (JSON, ``planbench-scenario/1``) cannot be used."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class UnknownNameError(PlanbenchError, KeyError):
    """A name (planner, robot, problem set, problem) that does not exist; lists close matches."""

    def __init__(self, kind: str, name: str, choices: Sequence[str]) -> None:
        self.kind = kind
        self.name = name
        self.choices = sorted(choices)
        close = difflib.get_close_matches(name, self.choices, n=3, cutoff=0.5)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        listing = ", ".join(self.choices[:20]) + (" ..." if len(self.choices) > 20 else "")
        super().__init__(f"unknown {kind} {name!r}.{hint} Known: {listing}")

    def __str__(self) -> str:  # KeyError would otherwise quote the message
        return str(self.args[0])


class PlannerUnavailableError(PlanbenchError):
    """A registered planner whose module cannot be imported (a missing optional dependency)."""

    def __init__(self, name: str, reason: str, hint: str = "") -> None:
        self.name = name
        self.reason = reason
        self.hint = hint
        msg = f"planner {name!r} is registered but cannot be loaded: {reason}"
        super().__init__(msg + (f" ({hint})" if hint else ""))


class DuplicatePluginError(PlanbenchError):
    """Two different plugins registered under one name of one kind (a planner, a controller): a name
    must mean one plugin, or a benchmark row could come from either. Names both sources (``sources``:
    the one registered first, then the other) and what to do (``hint``)."""

    def __init__(self, kind: str, name: str, first: str, second: str, hint: str) -> None:
        self.kind = kind
        self.name = name
        self.sources = (first, second)
        self.hint = hint
        super().__init__(f"{kind} {name!r} is registered twice: first by {first}, then by {second}. {hint}")


class InvalidConfigError(PlanbenchError, ValueError):
    """A setting outside its domain; says which setting and what is allowed."""


class ResourceLimitError(PlanbenchError, ValueError):
    """Input that would make planbench allocate more than a documented limit (an occupancy grid's
    cells, a point cloud's points, a kernel's cells): raised before allocating, with the figure
    the input asks for and the limit (a ValueError, so that a scene or problem loader names the
    file it came from)."""


class InvalidSettingError(InvalidConfigError):
    """A planner setting that cannot be used, however it was given (Python keywords, ``--set``, a
    suite file): names the planner, the setting, the value given and what is accepted.

    ``setting`` is None when the planner refused its settings as a whole and the message names none
    of them; ``value`` is then the settings given. ``where`` (a suite file, say) prefixes the
    message. :meth:`to_data` and :meth:`from_data` carry it between processes as plain data.
    """

    def __init__(
        self, planner: str, setting: str | None, value: Any, expected: str, *, where: str = "", shown: str = ""
    ) -> None:
        self.planner = planner
        self.setting = setting
        self.value = value
        self.expected = expected
        self.where = where
        self.shown = shown or show_value(value)
        what = f"setting {setting} = {self.shown} is" if setting else f"settings {self.shown} are"
        text = f"planner {planner!r}: {what} not accepted: {expected}"
        super().__init__(f"{where}: {text}" if where else text)

    def to_data(self) -> dict[str, Any]:
        """The error as JSON data (the value as its shown text)."""
        return {"planner": self.planner, "setting": self.setting, "shown": self.shown, "expected": self.expected}

    @classmethod
    def from_data(cls, data: Mapping[str, Any], where: str = "") -> InvalidSettingError:
        """The error :meth:`to_data` described (checked: the data may come from a process that ran a
        plugin); a ``TypeError`` when it is not such data."""
        texts = [data.get(k) for k in ("planner", "shown", "expected")]
        setting = data.get("setting")
        if not all(isinstance(t, str) for t in texts) or not (setting is None or isinstance(setting, str)):
            raise TypeError("not the data of an InvalidSettingError")
        planner, shown, expected = (str(t)[:2000] for t in texts)
        return cls(planner, setting, shown, expected, where=where, shown=shown)


def show_value(value: Any, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class ResultsFileError(PlanbenchError):
    """A results database that cannot be used: missing, damaged, not planbench's, or busy."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ResultsLockedError(ResultsFileError):
    """Another ``planbench bench`` is writing this results file; names that process."""

    def __init__(self, path: object, holder: str) -> None:
        self.holder = holder
        super().__init__(
            path,
            f"another benchmark is writing this results file ({holder}); wait for it to end, or choose another --out",
        )


class OutputFileError(PlanbenchError):
    """An output path a command must not write: a results file, or another SQLite database."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class UnstorableValueError(ResultsFileError, ValueError):
    """A run field whose value SQLite cannot store faithfully (an int beyond 64 bits, an object).

    Raised before anything is written, so the file is unchanged; the caller decides whether the
    run becomes an error row.
    """

    def __init__(self, path: object, column: str, value: object, why: str) -> None:
        self.column = column
        self.value = value
        text = repr(value)
        text = text if len(text) <= 80 else text[:77] + "..."
        super().__init__(path, f"run field {column!r} = {text} cannot be stored: {why}")


class DuplicateProblemError(PlanbenchError):
    """Two different problem sources with the same problem id in one selection."""

    def __init__(self, problem_id: str, first: str, second: str) -> None:
        self.problem_id = problem_id
        self.sources = (first, second)
        super().__init__(
            f"problem id {problem_id!r} is given by both {first} and {second}; results are keyed by the id, "
            "so give each problem its own id (the JSON 'id' field) or select only one of them"
        )
