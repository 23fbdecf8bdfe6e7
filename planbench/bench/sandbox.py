"""The file-system and signal sandbox of a plugin's process: Linux Landlock, no third-party code.

A worker calls :func:`restrict` once, before it imports any plugin. From then on the kernel
refuses, for that process and everything it starts:

- **every write outside the run's scratch folder** -- creating, writing, truncating, renaming,
  linking or removing files and directories, making devices, FIFOs or sockets, and ``ioctl`` on
  devices (Landlock's file-system rights, as many as the kernel's ABI knows). Reading stays
  allowed, so the Python installation, the robot models and the problem files are read-only:
  a plugin can neither rewrite the problem its verdict is computed from, nor touch the results
  file or its folder, nor plant an interpreter start-up hook (``.pth``, ``sitecustomize``) in
  site-packages for the next process to load. ``/dev/null``, ``/dev/zero`` and ``/dev/full``
  stay writable.
- **signals to processes outside the sandbox** (ABI 6, ``LANDLOCK_SCOPE_SIGNAL``): the worker's
  reaper, the validators, the benchmark and other workers cannot be killed or stopped from it;
  ``ptrace`` of them is refused by Landlock at every ABI.
- **connections to abstract Unix sockets** made outside it (ABI 6).

A restriction cannot be lifted: ``no_new_privs`` is set first, as the kernel requires, and a
later ``landlock_restrict_self`` can only add rules. Mount changes are refused to a sandboxed
process, so even a root plugin cannot remount its way out.

Where the kernel has no Landlock (before 5.13, or disabled at boot), :func:`available` is False
and the benchmark warns that plugins run unconfined (``docs/benchmarking.md``, the threat model).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = [
    "WRITABLE_VARIABLE",
    "SandboxUnavailable",
    "Restriction",
    "abi_version",
    "available",
    "enter",
    "restrict",
    "writable_folders",
]

_CREATE_RULESET, _ADD_RULE, _RESTRICT_SELF = 444, 445, 446  # the same on every architecture
_CREATE_RULESET_VERSION = 1
_RULE_PATH_BENEATH = 1
_PR_SET_NO_NEW_PRIVS = 38

# Landlock's file-system access rights and the ABI that introduced each.
_EXECUTE, _WRITE_FILE, _READ_FILE, _READ_DIR = 1 << 0, 1 << 1, 1 << 2, 1 << 3
_WRITES_ABI1 = sum(1 << i for i in range(4, 13))  # remove dir/file, make char/dir/reg/sock/fifo/block/sym
_REFER, _TRUNCATE, _IOCTL_DEV = 1 << 13, 1 << 14, 1 << 15
_SCOPE_ABSTRACT_UNIX_SOCKET, _SCOPE_SIGNAL = 1 << 0, 1 << 1
_FILE_RIGHTS = _EXECUTE | _WRITE_FILE | _READ_FILE | _TRUNCATE | _IOCTL_DEV
"""The rights that apply to a file (the others apply to a directory's entries)."""

WRITABLE_DEVICES = ("/dev/null", "/dev/zero", "/dev/full")
WRITABLE_VARIABLE = "PLANBENCH_SANDBOX_WRITABLE"
"""Environment variable: folders (``os.pathsep``-separated) that sandboxed plugins may write too,
e.g. a plugin's own log folder. Each is the user's choice to trust every plugin of the benchmark
with it; never the results file's folder."""


def writable_folders() -> tuple[str, ...]:
    """The folders :data:`WRITABLE_VARIABLE` names."""
    return tuple(p for p in os.environ.get(WRITABLE_VARIABLE, "").split(os.pathsep) if p)


class SandboxUnavailable(OSError):
    """The kernel offers no Landlock (or refused the rule set)."""


class _RulesetAttr(ctypes.Structure):
    _fields_ = [
        ("handled_access_fs", ctypes.c_uint64),
        ("handled_access_net", ctypes.c_uint64),
        ("scoped", ctypes.c_uint64),
    ]


class _PathBeneathAttr(ctypes.Structure):
    _pack_ = 1
    _fields_ = [("allowed_access", ctypes.c_uint64), ("parent_fd", ctypes.c_int32)]


_libc = ctypes.CDLL(None, use_errno=True)
_libc.syscall.restype = ctypes.c_long


def abi_version() -> int:
    """The kernel's Landlock ABI (0: none)."""
    version = _libc.syscall(_CREATE_RULESET, None, ctypes.c_size_t(0), ctypes.c_uint32(_CREATE_RULESET_VERSION))
    return max(0, int(version))


def available() -> bool:
    """Whether this kernel can sandbox a plugin's writes."""
    return abi_version() >= 1


@dataclass(frozen=True)
class Restriction:
    """What :func:`restrict` made the kernel enforce."""

    abi: int
    writable: tuple[str, ...]
    signals_scoped: bool
    """Signals to processes outside the sandbox refused (ABI >= 6)."""

    def describe(self) -> str:
        scope = "signals out refused" if self.signals_scoped else "signals out NOT refused (Landlock ABI < 6)"
        return f"Landlock ABI {self.abi}: writes only under {', '.join(self.writable)}; {scope}"


def _write_rights(abi: int) -> int:
    rights = _WRITE_FILE | _WRITES_ABI1
    if abi >= 2:
        rights |= _REFER
    if abi >= 3:
        rights |= _TRUNCATE
    if abi >= 5:
        rights |= _IOCTL_DEV
    return rights


def _fail(what: str) -> SandboxUnavailable:
    code = ctypes.get_errno()
    return SandboxUnavailable(code, f"Landlock {what}: {os.strerror(code)}")


def _add_path(ruleset: int, path: str, rights: int) -> None:
    fd = os.open(path, os.O_PATH | os.O_CLOEXEC)
    try:
        if not os.path.isdir(path):
            rights &= _FILE_RIGHTS
        attr = _PathBeneathAttr(rights, fd)
        if _libc.syscall(_ADD_RULE, ruleset, _RULE_PATH_BENEATH, ctypes.byref(attr), 0) != 0:
            raise _fail(f"rule for {path}")
    finally:
        os.close(fd)


def restrict(writable: Iterable[str]) -> Restriction:
    """Sandbox this process and its future children (see the module docstring): writes only
    beneath the ``writable`` directories (and to :data:`WRITABLE_DEVICES`), no signals out.

    Threads started before the call are not restricted: call it while the process has only the
    threads planbench started. Raises :class:`SandboxUnavailable` when the kernel has no Landlock.
    """
    abi = abi_version()
    if abi < 1:
        raise SandboxUnavailable(errno.ENOSYS, "the kernel offers no Landlock (Linux >= 5.13 with lsm=landlock)")
    rights = _write_rights(abi)
    scoped = _SCOPE_SIGNAL | _SCOPE_ABSTRACT_UNIX_SOCKET if abi >= 6 else 0
    attr = _RulesetAttr(rights, 0, scoped)
    size = ctypes.sizeof(_RulesetAttr) if abi >= 6 else 8  # older kernels know only the first field
    ruleset = int(_libc.syscall(_CREATE_RULESET, ctypes.byref(attr), ctypes.c_size_t(size), ctypes.c_uint32(0)))
    if ruleset < 0:
        raise _fail("ruleset")
    try:
        paths = tuple(os.path.realpath(p) for p in writable)
        for path in paths:
            _add_path(ruleset, path, rights)
        for device in WRITABLE_DEVICES:
            with contextlib.suppress(FileNotFoundError):
                _add_path(ruleset, device, rights & _FILE_RIGHTS)
        if _libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
            raise _fail("no_new_privs")
        if _libc.syscall(_RESTRICT_SELF, ruleset, 0) != 0:
            raise _fail("restrict_self")
    finally:
        os.close(ruleset)
    return Restriction(abi, paths, bool(scoped))


def enter(scratch: str, sandboxed: bool, writable: tuple[str, ...] = ()) -> str:
    """For a process about to run plugin code: work in ``scratch`` (the current folder, ``TMPDIR``,
    numba's cache) and, when ``sandboxed``, make every other place but ``writable`` read-only for
    this process and what it starts (:func:`restrict`); what the sandbox holds, or why there is
    none, as text.

    Called while the process has one thread: Landlock restricts the calling thread and the threads
    and processes it starts later, so a thread started before could run a plugin's code unconfined.
    """
    import sys
    import tempfile

    from planbench.runtime import compile_cache

    os.makedirs(scratch, exist_ok=True)
    os.chdir(scratch)
    os.environ["TMPDIR"] = scratch
    tempfile.tempdir = None
    try:
        compile_cache.use_private_cache(os.path.join(scratch, "numba-cache"))
    except Exception as exc:  # no numba: nothing to cache
        print(f"planbench worker: no private numba cache ({type(exc).__name__}: {exc})", file=sys.stderr)
    if not sandboxed:
        return "off"
    threads = len(os.listdir("/proc/self/task"))
    if threads != 1:
        return f"refused: the process had {threads} threads before any plugin code (a planbench bug)"
    try:
        return restrict([scratch, *(p for p in writable if os.path.isdir(p))]).describe()
    except SandboxUnavailable as exc:
        return f"unavailable: {exc}"
