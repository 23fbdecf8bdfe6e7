"""Data-only messages between the benchmark's processes, and the checks a planner's raw result passes.

Why not pickle: :meth:`multiprocessing.connection.Connection.recv` unpickles, and unpickling runs
code chosen by the sender (an object's ``__reduce__``). A worker process runs planner code, so
everything it sends is untrusted; the parent and the validator must only ever *parse* it. A
message here is::

    b"PBW1" | u64 length of the header | header (UTF-8 JSON) | raw little-endian float64 arrays

The header names the arrays (``{"arrays": {"path": [n, nq], "times": [n]}}``) in the order their
bytes follow. Decoding uses :func:`json.loads` and :func:`numpy.frombuffer` only, and checks every
length, so a malformed message is a :class:`BadMessage`, never code run or memory exhausted.

:func:`clean_result` is the one gatekeeper for a planner's raw result. The worker calls it on what
the planner returned (so it can name the bad field while it still has the object), and the
parent calls it again on the decoded message (it cannot trust the worker's encoding either). A
result that passes holds only values SQLite can store and :func:`planbench.evaluate` can read.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = [
    "BadField",
    "BadMessage",
    "INFO_MAX_BYTES",
    "MAX_MESSAGE_BYTES",
    "RESULT_FIELDS",
    "clean_result",
    "decode",
    "encode",
]

MAGIC = b"PBW1"
MAX_MESSAGE_BYTES = 160 * 2**20
"""Largest message a process accepts [bytes] (a path of a million 7-joint waypoints is 56 MB)."""
MAX_WAYPOINTS = 1_000_000
INFO_MAX_BYTES = 2**20
"""Largest ``info`` kept per run, as JSON [bytes]. Shipped planners write about 100 KiB (per-step
arrays); a bigger dict makes the run an error rather than bloating the results file."""
INFO_MAX_NODES = 300_000
INFO_MAX_DEPTH = 32
ARRAY_AS_LIST = 1000
"""Arrays in ``info`` up to this many values are kept as lists; longer ones as a short description."""
TEXT_MAX_CHARS = 64 * 1024
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1

STATUSES = (
    "success",
    "local_minimum",
    "step_limit",
    "timeout",
    "collision",
    "infeasible",
    "invalid_start",
    "invalid_goal",
    "error",
    "crash",
)
RESULT_FIELDS = (
    "status",
    "message",
    "target",
    "info",
    "planning_time",
    "setup_time",
    "wall_time",
    "traceback",
    "pid",
    "host",
    "prepared",
    "path",
    "times",
)


class BadMessage(ValueError):
    """Bytes that are not a well-formed message."""


class BadField(ValueError):
    """A field of a planner's result that the benchmark cannot keep; ``field`` names it."""

    def __init__(self, field: str, why: str) -> None:
        self.field = field
        self.why = why
        super().__init__(f"{field}: {why}")


# -- messages --------------------------------------------------------------------------------------


def encode(header: dict[str, Any], arrays: Mapping[str, np.ndarray | None] | None = None) -> bytes:
    """One message: ``header`` (JSON types only) and float64 ``arrays`` (None entries are omitted)."""
    shapes: dict[str, list[int]] = {}
    blobs: list[bytes] = []
    for name, a in (arrays or {}).items():
        if a is None:
            continue
        a = np.ascontiguousarray(a, dtype="<f8")
        shapes[name] = [int(n) for n in a.shape]
        blobs.append(a.tobytes())
    text = json.dumps({**header, "arrays": shapes}, allow_nan=True).encode("utf-8")
    return b"".join([MAGIC, struct.pack("<Q", len(text)), text, *blobs])


def decode(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The header and arrays of a message made by :func:`encode`; :class:`BadMessage` otherwise."""
    if len(data) > MAX_MESSAGE_BYTES:
        raise BadMessage(f"message of {len(data)} bytes, more than {MAX_MESSAGE_BYTES}")
    if len(data) < 12 or data[:4] != MAGIC:
        raise BadMessage("not a planbench message (bad magic)")
    (n,) = struct.unpack("<Q", data[4:12])
    if n > len(data) - 12:
        raise BadMessage("header length beyond the message")
    try:
        header = json.loads(data[12 : 12 + n].decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise BadMessage(f"header is not JSON ({type(exc).__name__})") from exc
    if not isinstance(header, dict) or not isinstance(header.get("arrays"), dict):
        raise BadMessage("header is not a JSON object with an 'arrays' entry")
    arrays: dict[str, np.ndarray] = {}
    offset = 12 + n
    for name, shape in header.pop("arrays").items():
        if not (isinstance(shape, list) and len(shape) <= 4 and all(_is_count(s) for s in shape)):
            raise BadMessage(f"array {name!r}: bad shape {str(shape)[:80]}")
        nbytes = 8 * math.prod(shape)
        if nbytes > len(data) - offset:
            raise BadMessage(f"array {name!r}: shape {shape} needs more bytes than the message has")
        arrays[str(name)] = np.frombuffer(data, dtype="<f8", count=nbytes // 8, offset=offset).reshape(shape)
        offset += nbytes
    if offset != len(data):
        raise BadMessage(f"{len(data) - offset} bytes after the last array")
    return header, arrays


def _is_count(x: Any) -> bool:
    return type(x) is int and 0 <= x <= MAX_MESSAGE_BYTES


# -- the planner's raw result ----------------------------------------------------------------------


def clean_result(fields: Mapping[str, Any]) -> dict[str, Any]:
    """``fields`` (see :data:`RESULT_FIELDS`) checked and reduced to plain values, or :class:`BadField`.

    Text is re-built as ``str`` (a subclass could change on every read), numbers as ``int`` /
    ``float``, ``info`` as JSON data within :data:`INFO_MAX_BYTES`, ``path`` as an (N, nq)
    float64 array and ``times`` as (N,). ``traceback`` and ``host`` are repaired (cut, bad
    characters escaped) rather than refused: they are the harness's words, not the planner's.
    """
    missing = [f for f in RESULT_FIELDS if f not in fields]
    extra = [str(f)[:40] for f in fields if f not in RESULT_FIELDS]
    if missing or extra:
        raise BadField("result", f"fields missing {missing}, unknown {extra}")
    out: dict[str, Any] = {}
    status = _text(fields["status"], "status")
    if status not in STATUSES:
        raise BadField("status", f"{status[:40]!r} is not a planbench status ({', '.join(STATUSES)})")
    out["status"] = status
    out["message"] = _cut(_text(fields["message"], "message"))
    target = _text(fields["target"], "target")
    if target not in ("pose", "configuration"):
        raise BadField("target", f"{target[:40]!r} is neither 'pose' nor 'configuration'")
    out["target"] = target
    out["info"] = clean_info(fields["info"])
    for name in ("planning_time", "setup_time", "wall_time"):
        out[name] = _float(fields[name], name)
    out["traceback"] = _repair(fields["traceback"], TEXT_MAX_CHARS)
    out["host"] = _repair(fields["host"], 255)
    pid = fields["pid"]
    if not (type(pid) is int and 0 < pid <= INT64_MAX):
        raise BadField("pid", f"not a process id: {_describe(pid)}")
    out["pid"] = pid
    if type(fields["prepared"]) is not bool:
        raise BadField("prepared", f"not true or false: {_describe(fields['prepared'])}")
    out["prepared"] = fields["prepared"]
    out["path"] = _path(fields["path"])
    out["times"] = _times(fields["times"], out["path"])
    return out


def clean_info(info: Any) -> dict[str, Any]:
    """``info`` as JSON data (see :func:`clean_result`); :class:`BadField` naming the bad entry."""
    if not isinstance(info, Mapping):
        raise BadField("info", f"a {type(info).__name__}, not a dict")
    budget = [INFO_MAX_NODES]
    cleaned = _json_value(info, "info", 0, budget)
    try:
        size = len(json.dumps(cleaned, allow_nan=True))
    except (TypeError, ValueError, RecursionError) as exc:  # pragma: no cover (cleaned is JSON data)
        raise BadField("info", f"not JSON-serialisable ({exc})") from exc
    if size > INFO_MAX_BYTES:
        raise BadField(
            "info", f"{size / 2**20:.1f} MiB as JSON, more than the {INFO_MAX_BYTES // 1024} KiB kept; dropped"
        )
    return cleaned  # type: ignore[no-any-return]


def _json_value(x: Any, where: str, depth: int, budget: list[int]) -> Any:
    """``x`` as JSON data (the planner's own objects never leave this function)."""
    budget[0] -= 1
    if budget[0] < 0:
        raise BadField("info", f"more than {INFO_MAX_NODES} values; dropped")
    if depth > INFO_MAX_DEPTH:
        raise BadField(where, f"nested deeper than {INFO_MAX_DEPTH} levels")
    if x is None or type(x) is bool:
        return x
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        v = int(x)
        if not INT64_MIN <= v <= INT64_MAX:
            raise BadField(where, f"integer {str(v)[:30]} is outside the 64-bit range a results file stores")
        return v
    if isinstance(x, (float, np.floating)):
        return float(x)
    if isinstance(x, str):
        return _text(x, where)  # not cut: a huge text makes ``info`` too big, which is named
    if isinstance(x, np.ndarray):
        return _array_value(x, where, depth, budget)
    if isinstance(x, Mapping):
        out = {}
        for k, v in x.items():
            key = _key(k, where)
            out[key] = _json_value(v, f"{where}[{key[:40]!r}]", depth + 1, budget)
        return out
    if isinstance(x, (list, tuple)):
        return [_json_value(v, f"{where}[{i}]", depth + 1, budget) for i, v in enumerate(x)]
    raise BadField(where, f"a {_type_name(x)}, which is not JSON data (numbers, text, lists, dicts, arrays)")


def _array_value(x: np.ndarray, where: str, depth: int, budget: list[int]) -> Any:
    if x.dtype.kind not in "biuf":
        raise BadField(where, f"an array of dtype {x.dtype}, not numbers")
    if x.size > ARRAY_AS_LIST:
        return f"<array {tuple(int(n) for n in x.shape)} {x.dtype}>"
    return _json_value(x.tolist(), where, depth, budget)


def _key(k: Any, where: str) -> str:
    if isinstance(k, str):
        return _text(k, f"{where} key")
    if isinstance(k, (bool, int, float, np.integer, np.floating)) and not isinstance(k, np.bool_):
        return json.dumps(k.item() if isinstance(k, np.generic) else k)
    raise BadField(where, f"has a key of type {_type_name(k)} (JSON keys are text)")


def _text(x: Any, where: str) -> str:
    """``x`` as a plain ``str`` that UTF-8 can encode (what SQLite stores), or :class:`BadField`."""
    if not isinstance(x, str):
        raise BadField(where, f"a {_type_name(x)}, not text")
    try:
        return str.encode(x, "utf-8").decode("utf-8")  # the base method: a subclass cannot intervene
    except UnicodeEncodeError as exc:
        raise BadField(where, f"text that is not valid UTF-8 ({exc.reason})") from exc


def _repair(x: Any, limit: int) -> str:
    """Harness text kept whatever it holds: non-text described, bad characters escaped, the tail kept."""
    if not isinstance(x, str):
        return f"<{_type_name(x)}>"
    text = str.encode(x, "utf-8", "backslashreplace").decode("utf-8")
    return text if len(text) <= limit else "[... cut ...]\n" + text[-limit:]


def _cut(text: str) -> str:
    return (
        text
        if len(text) <= TEXT_MAX_CHARS
        else text[:TEXT_MAX_CHARS] + f" [... {len(text) - TEXT_MAX_CHARS} chars cut]"
    )


def _float(x: Any, where: str) -> float:
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise BadField(where, f"a {_type_name(x)}, not a number")
    try:
        return float(x)
    except OverflowError as exc:
        raise BadField(where, "a number too large for a float") from exc


def _path(x: Any) -> np.ndarray | None:
    if x is None:
        return None
    try:
        a = np.array(x, dtype=np.float64)  # a copy: later changes by its owner do not reach us
    except (TypeError, ValueError, OverflowError) as exc:
        raise BadField("path", f"not an array of numbers ({type(exc).__name__}: {str(exc)[:200]})") from exc
    if a.ndim != 2:
        raise BadField("path", f"shape {a.shape}, not (waypoints, joints)")
    if a.shape[0] > MAX_WAYPOINTS:
        raise BadField("path", f"{a.shape[0]} waypoints, more than the {MAX_WAYPOINTS} kept")
    if a.shape[1] > 64:
        raise BadField("path", f"{a.shape[1]} columns, more than any robot's joints")
    return a


def _times(x: Any, path: np.ndarray | None) -> np.ndarray | None:
    if x is None:
        return None
    try:
        t = np.array(x, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise BadField("times", f"not an array of numbers ({type(exc).__name__})") from exc
    if path is None or t.shape != (len(path),):
        raise BadField("times", f"shape {t.shape}, not one time stamp per path waypoint")
    return t


def _type_name(x: Any) -> str:
    """A description of ``x`` that runs none of its code (no ``repr``, no ``__class__`` property)."""
    t = type(x)
    return f"{t.__module__}.{t.__qualname__}" if t.__module__ not in ("builtins", None) else t.__qualname__


def _describe(x: Any) -> str:
    if type(x) in (int, float, bool, str) or x is None:
        return repr(x)[:60]
    return _type_name(x)
