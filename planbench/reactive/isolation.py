"""What keeps a controller's compute countable from outside its process.

Two kernel facilities, no third-party code:

- :func:`forbid_new_processes` installs a seccomp filter on every thread of the calling process
  (``SECCOMP_FILTER_FLAG_TSYNC``) that refuses ``fork``, ``vfork``, ``clone`` without
  ``CLONE_THREAD`` (``EPERM``) and ``clone3`` (``ENOSYS``, so the C library falls back to ``clone``
  for threads), and ``ptrace`` and ``process_vm_writev`` on other processes. A controller's
  process can then hold threads only, and the kernel's CPU clock of the process
  (:class:`ProcessClock`) covers all of its compute. A filter cannot be removed once installed,
  and ``no_new_privs`` is set first, as the kernel requires. Syscalls of another ABI (x86's
  32-bit ``int 0x80`` or x32) are refused too, since their numbers differ.
- :class:`ProcessClock` reads another process's CPU clock (``clock_getcpuclockid``): the CPU time
  of all its threads, in ns, as the kernel accounts it, whatever that process does to its own
  clocks, modules or threads.

- :func:`drop_capabilities` empties the process's capability sets (a root process keeps its uid
  but loses ``CAP_SYS_PTRACE``, ``CAP_DAC_OVERRIDE`` and the rest), and :func:`make_undumpable`
  marks a process (the simulation's, the benchmark's) so that a process without
  ``CAP_SYS_PTRACE`` cannot read or write its memory through ``/proc/<pid>/mem``, even under the
  same uid. :func:`confine` does what a controller's process needs: undumpable, capabilities
  dropped, new processes forbidden.

Linux on x86-64 or AArch64 only; elsewhere :func:`confine` raises :class:`IsolationUnavailable`
and the benchmark says so.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import platform
import struct
import time

__all__ = [
    "IsolationUnavailable",
    "ProcessClock",
    "confine",
    "drop_capabilities",
    "forbid_new_processes",
    "make_undumpable",
]


class IsolationUnavailable(OSError):
    """The kernel or architecture does not offer what a controller's isolation needs."""


# Per architecture: (AUDIT_ARCH, {syscall: action}, clone number, seccomp number); actions are
# "errno" (EPERM), "enosys" or "clone" (allowed only with CLONE_THREAD).
_ARCHES = {
    "x86_64": (
        0xC000003E,
        {57: "errno", 58: "errno", 101: "errno", 311: "errno", 435: "enosys", 56: "clone"},
        317,
    ),
    "aarch64": (
        0xC00000B7,
        {117: "errno", 271: "errno", 435: "enosys", 220: "clone"},
        277,
    ),
}
_X32_BIT = 0x40000000
_CLONE_THREAD = 0x00010000
_RET_ALLOW = 0x7FFF0000
_RET_ERRNO = 0x00050000
_PR_SET_NO_NEW_PRIVS = 38
_SECCOMP_SET_MODE_FILTER = 1
_SECCOMP_FILTER_FLAG_TSYNC = 1
# classic BPF opcodes
_LD_W_ABS = 0x20
_JEQ_K = 0x15
_JGE_K = 0x35
_JSET_K = 0x45
_RET_K = 0x06


class _SockFilter(ctypes.Structure):
    _fields_ = [("code", ctypes.c_ushort), ("jt", ctypes.c_ubyte), ("jf", ctypes.c_ubyte), ("k", ctypes.c_uint32)]


class _SockFprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.POINTER(_SockFilter))]


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def _program(arch: str) -> list[tuple[int, int, int, int]]:
    """The filter as (code, jt, jf, k) instructions (seccomp_data: nr at 0, arch at 4, args at 16)."""
    audit, actions, _ = _ARCHES[arch]
    deny = _RET_ERRNO | errno.EPERM
    nosys = _RET_ERRNO | errno.ENOSYS
    prog: list[tuple[int, int, int, int]] = [
        (_LD_W_ABS, 0, 0, 4),
        (_JEQ_K, 1, 0, audit),  # another ABI: refused
        (_RET_K, 0, 0, deny),
        (_LD_W_ABS, 0, 0, 0),
    ]
    if arch == "x86_64":
        prog += [(_JGE_K, 0, 1, _X32_BIT), (_RET_K, 0, 0, deny)]
    for nr, action in actions.items():
        if action == "clone":  # args[0] (flags), low 32 bits on a little-endian machine
            prog += [
                (_JEQ_K, 0, 4, nr),
                (_LD_W_ABS, 0, 0, 16),
                (_JSET_K, 1, 0, _CLONE_THREAD),
                (_RET_K, 0, 0, deny),
                (_RET_K, 0, 0, _RET_ALLOW),
            ]
        else:
            prog += [(_JEQ_K, 0, 1, nr), (_RET_K, 0, 0, nosys if action == "enosys" else deny)]
    prog.append((_RET_K, 0, 0, _RET_ALLOW))
    return prog


def forbid_new_processes() -> None:
    """Refuse new processes (and writing into other processes) to every thread of this process,
    for good (module docstring). :class:`IsolationUnavailable` where the kernel cannot."""
    arch = platform.machine()
    if os.name != "posix" or platform.system() != "Linux" or arch not in _ARCHES:
        raise IsolationUnavailable(f"no process filter for {platform.system()} on {arch} (Linux x86_64/aarch64 only)")
    libc = _libc()
    if libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
        raise IsolationUnavailable(f"prctl(PR_SET_NO_NEW_PRIVS) failed: {os.strerror(ctypes.get_errno())}")
    prog = _program(arch)
    filters = (_SockFilter * len(prog))(*[_SockFilter(*ins) for ins in prog])
    fprog = _SockFprog(len(prog), filters)
    nr = _ARCHES[arch][2]
    libc.syscall.restype = ctypes.c_long
    rc = libc.syscall(
        ctypes.c_long(nr),
        ctypes.c_long(_SECCOMP_SET_MODE_FILTER),
        ctypes.c_long(_SECCOMP_FILTER_FLAG_TSYNC),
        ctypes.byref(fprog),
    )
    if rc != 0:
        err = ctypes.get_errno()
        why = os.strerror(err) if rc < 0 else f"thread {rc} could not be synchronised"
        raise IsolationUnavailable(f"seccomp filter refused: {why}")


def confine() -> None:
    """Confine the calling process for a controller: capabilities dropped, new processes forbidden,
    and undumpable (so another confined controller, as capable as this one, cannot reach into it)."""
    make_undumpable()
    drop_capabilities()
    forbid_new_processes()


_PR_SET_DUMPABLE = 4
_PR_CAPBSET_DROP = 24
_PR_CAP_AMBIENT = 47
_PR_CAP_AMBIENT_CLEAR_ALL = 4
_CAPABILITY_VERSION_3 = 0x20080522


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [("effective", ctypes.c_uint32), ("permitted", ctypes.c_uint32), ("inheritable", ctypes.c_uint32)]


def drop_capabilities() -> None:
    """Empty this process's bounding, ambient, effective, permitted and inheritable capability
    sets (every thread's: each thread has its own, so call it before threads start or accept that
    running threads keep theirs; the seccomp filter is what holds for every thread)."""
    libc = _libc()
    libc.prctl(_PR_CAP_AMBIENT, _PR_CAP_AMBIENT_CLEAR_ALL, 0, 0, 0)
    for cap in range(64):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0 and ctypes.get_errno() == errno.EINVAL:
            break  # past the last capability this kernel knows
    header = _CapHeader(_CAPABILITY_VERSION_3, 0)
    data = (_CapData * 2)()
    if libc.capset(ctypes.byref(header), data) != 0:
        raise IsolationUnavailable(f"capset failed: {os.strerror(ctypes.get_errno())}")


def make_undumpable() -> None:
    """Protect this process's memory from processes without ``CAP_SYS_PTRACE`` (same uid included)."""
    _libc().prctl(_PR_SET_DUMPABLE, 0, 0, 0, 0)


class ProcessClock:
    """The CPU time [ns] of all threads of process ``pid``, read from outside it.

    ``read()`` raises :class:`ProcessLookupError` once the process is gone."""

    def __init__(self, pid: int) -> None:
        libc = _libc()
        clock = ctypes.c_int()
        rc = libc.clock_getcpuclockid(ctypes.c_int(pid), ctypes.byref(clock))
        if rc != 0:
            raise ProcessLookupError(rc, f"no CPU clock for process {pid}: {os.strerror(rc)}")
        self.pid = pid
        self._clock = clock.value

    def read(self) -> int:
        try:
            return time.clock_gettime_ns(self._clock)
        except OSError as exc:
            raise ProcessLookupError(exc.errno, f"process {self.pid} is gone") from exc


def _check_struct() -> None:  # the layout the kernel reads: 8 bytes per instruction
    assert struct.calcsize("HBBI") == ctypes.sizeof(_SockFilter) == 8


_check_struct()
