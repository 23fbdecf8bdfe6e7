"""Reading the files planbench is given, without hanging or running out of memory on bad ones.

Every input file (problem, scene and scenario JSON, suite and robot TOML, meshes, point clouds,
URDF) is checked before it is opened: it must be a *regular* file (a FIFO would block the open
forever, ``/dev/zero`` would be read until memory runs out, a folder cannot be read), and text
files are read up to :data:`MAX_TEXT_BYTES`. A file that fails a check raises
:class:`InputFileError` with the reason; callers turn it into their own error naming the file
(:class:`~planbench.errors.ProblemFileError`, ``SuiteFileError``, ...).

Output paths are checked by :func:`check_writable`: a folder, or a FIFO that nobody reads (opening
it for writing would block), is refused before any work is done.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Any

from planbench.errors import PlanbenchError

__all__ = [
    "MAX_TEXT_BYTES",
    "InputFileError",
    "check_writable",
    "kind_of",
    "read_bytes",
    "read_json",
    "read_text",
    "regular_file",
    "release_outputs",
]

MAX_TEXT_BYTES = 64 << 20
"""[B] The largest problem, scene, scenario, suite or robot settings file read (64 MiB). Shipped
and generated problem files are a few kB; a scene with 10,000 obstacles is about 2 MB. Point
clouds and meshes are binary files with their own limits (:mod:`planbench.geometry.pointcloud`)."""


class InputFileError(PlanbenchError):
    """A file that cannot be read as an input; ``problem`` says why (without the path)."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def kind_of(mode: int) -> str:
    """What a non-regular file is, in words (``"a folder"``, ``"a FIFO (named pipe)"``, ...)."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _stat_problem(exc: OSError) -> str:
    if exc.errno == errno.ENOENT:
        return "cannot read: no such file"
    if exc.errno == errno.ELOOP:
        return "cannot read: a loop of symbolic links"
    if exc.errno == errno.ENOTDIR:
        return "cannot read: no such file (a part of the path is not a folder)"
    return f"cannot read: {exc.strerror or exc}"


def regular_file(path: str | Path, limit: int | None = None) -> os.stat_result:
    """``path``'s stat when it is a regular file (of at most ``limit`` bytes), else
    :class:`InputFileError` saying what it is. Nothing is opened."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise InputFileError(path, _stat_problem(exc)) from None
    except ValueError as exc:  # an embedded NUL byte
        raise InputFileError(repr(str(path)), f"cannot read: not a usable path ({exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(path, f"cannot read: it is {kind_of(st.st_mode)}, not a regular file")
    if limit is not None and st.st_size > limit:
        raise InputFileError(
            path, f"cannot read: it is {_size(st.st_size)}; files of this kind are read up to {_size(limit)}"
        )
    return st


def read_bytes(path: str | Path, limit: int = MAX_TEXT_BYTES) -> bytes:
    """The content of the regular file ``path`` (at most ``limit`` bytes), opened without blocking
    and checked again once open (the file may have been replaced in between)."""
    regular_file(path, limit)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputFileError(path, _stat_problem(exc)) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputFileError(path, f"cannot read: it is {kind_of(st.st_mode)}, not a regular file")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(limit + 1)
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise InputFileError(
            path, f"cannot read: it is larger than {_size(limit)}, the most read for files of this kind"
        )
    return data


def read_text(path: str | Path, limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of ``path`` (:func:`read_bytes`); another encoding is an :class:`InputFileError`."""
    data = read_bytes(path, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputFileError(
            path,
            f"cannot read: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); is it the right file?",
        ) from None


def read_json(path: str | Path, limit: int = MAX_TEXT_BYTES) -> Any:
    """The JSON value in ``path`` (:func:`read_text`); malformed JSON, nesting too deep for the
    parser, or an integer too long to convert is an :class:`InputFileError`."""
    text = read_text(path, limit)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"not valid JSON: {exc}") from None
    except RecursionError:
        raise InputFileError(path, "not usable JSON: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise InputFileError(path, f"not usable JSON: {exc}") from None


def check_writable(path: str | Path, what: str = "output", folder_made: bool = False) -> Path:
    """``path`` when planbench may write it: not a folder, not a FIFO that nobody reads (opening
    it would block until someone does), and in an existing folder (unless the writer makes it:
    ``folder_made``). A FIFO with a reader (``--json /dev/stdout | jq``) and devices such as
    ``/dev/null`` are fine."""
    p = Path(path)
    if not str(path):
        raise PlanbenchError(f"the {what} file name is empty")
    try:
        st = os.stat(p)
    except FileNotFoundError:
        parent = p.parent
        if not folder_made and not parent.is_dir():
            raise PlanbenchError(f"cannot write {p}: folder {parent} does not exist") from None
        return p
    except OSError as exc:
        raise PlanbenchError(f"cannot write {p}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise PlanbenchError(f"cannot write {p}: it is a folder; give a file name")
    if stat.S_ISFIFO(st.st_mode):
        try:
            fd = os.open(p, os.O_WRONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        except OSError as exc:
            if exc.errno == errno.ENXIO:
                raise PlanbenchError(f"cannot write {p}: it is a FIFO (named pipe) that no process reads") from None
            raise PlanbenchError(f"cannot write {p}: {exc.strerror or exc}") from None
        _HELD.append(fd)  # closing it now would end the reader's input before planbench writes
    return p


_HELD: list[int] = []


def release_outputs() -> None:
    """Close the FIFOs :func:`check_writable` opened to see that they have a reader (the command's
    end: their reader then sees the end of its input once planbench's own writes are done)."""
    while _HELD:
        try:
            os.close(_HELD.pop())
        except OSError:
            pass


def _size(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("kiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"
