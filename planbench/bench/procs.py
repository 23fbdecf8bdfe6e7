"""Process lifetime for the benchmark's children: sessions, death with the parent, group kills, and
bounded output files.

Why each piece:

- :func:`detach` puts a child in its own session (so its process group is its pid and a planner's
  subprocesses join that group; Ctrl-C in the terminal does not reach it) and ties its life to the
  parent's with ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux, checked against the parent's pid
  in case the parent died before the call (the signal fires when the parent *thread* that started
  the child ends, which is the benchmark's loop here).
- ``PDEATHSIG`` kills only the worker, not a planner's own children. :func:`start_reaper` forks a
  tiny process into the worker's group that waits for the worker to be gone (by pid: its parent
  changes) and then kills the whole group, so grandchildren die whether the worker was killed,
  crashed or exited. A thread in the worker could not do this: ``PDEATHSIG`` kills the worker
  before such a thread runs, and a planner holding the GIL would starve it.
- A process group does not hold a planner's child that calls ``setsid``. Where the kernel lets
  this process make cgroups (v2), each worker runs in a cgroup of its own (:class:`Cgroups`,
  :func:`join_cgroup`), which no descendant can leave from inside the sandbox
  (:mod:`planbench.bench.sandbox`: the cgroup files are not writable there); killing it
  (``cgroup.kill``) kills every process in it, whatever it did to its session. The reaper does
  that when the worker is gone, the parent when it ends a worker. Where there are no cgroups,
  the worker is a child subreaper (orphans of its descendants become its children, not init's)
  and the reaper tracks its descendants while it lives and kills them all after it.
- :func:`kill_group` is how the parent ends a worker: ``killpg(pid, SIGKILL)`` (the worker, its
  reaper, the planner's children), then the process itself in case it had not reached
  :func:`detach` yet; then its cgroup.
- :class:`OutputFile` is where a worker's fds 1 and 2 go. The parent trims it when it grows past
  :data:`OUTPUT_MAX_BYTES` (keeping the tail) and reads its tail into the run's row, so a planner
  that prints without end neither reaches the terminal nor fills the disk.
- :func:`worker_dir` makes the folder of those files, locked while its benchmark runs, and removes
  the folders of benchmarks that are gone (their lock free): one killed cannot remove its own.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Iterator

from planbench.runtime.threads import THREAD_VARIABLES
from planbench.runtime.threads import limit_threads as limit_compute_threads

__all__ = [
    "Cgroups",
    "OutputFile",
    "WORKER_DIR_LOCK",
    "WORKER_DIR_PREFIX",
    "descendants",
    "detach",
    "join_cgroup",
    "kill_group",
    "limit_threads",
    "process_alive",
    "start_reaper",
    "thread_environment",
    "watch_parent",
    "worker_dir",
]


PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36
OUTPUT_MAX_BYTES = 16 * 2**20
"""A worker's output file is cut back to its tail past this size [bytes]."""
OUTPUT_KEEP_BYTES = 64 * 1024
TAIL_BYTES = 8 * 1024
"""How much of a run's output its row keeps [bytes]."""
OUTPUT_HEADER = "--- worker output (tail) ---"


def limit_threads(threads: int) -> None:
    """Cap the thread pools of OpenMP, BLAS and numba in this process, so parallel workers do not
    oversubscribe the cores, idle OpenMP threads sleep instead of spinning, and a run's arithmetic
    does not depend on ``--jobs`` (:func:`planbench.runtime.threads.limit_threads`: environment for
    what loads later, the pools of what is loaded already, numpy's OpenBLAS included)."""
    limit_compute_threads(threads)


def detach(parent_pid: int) -> None:
    """Make this process a session leader that dies with ``parent_pid`` (see the module docstring)."""
    with contextlib.suppress(OSError):
        os.setsid()
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before prctl could take effect
        _kill_own_group()


def watch_parent(parent_pid: int, interval: float = 0.5) -> None:
    """A daemon thread that kills this process group when ``parent_pid`` is no longer the parent
    (the fallback where ``PR_SET_PDEATHSIG`` does not exist)."""

    def loop() -> None:
        while True:
            time.sleep(interval)
            if os.getppid() != parent_pid:
                _kill_own_group()

    threading.Thread(target=loop, name="planbench-parent-watch", daemon=True).start()


def start_reaper(interval: float = 0.1) -> int:
    """Fork the reaper (see the module docstring) and return its pid (0 where fork is missing).

    Call it right after :func:`detach` (and :func:`join_cgroup`) and before any thread starts: the
    child is a copy of a single-threaded interpreter that only sleeps and polls.
    """
    if not hasattr(os, "fork"):  # pragma: no cover
        return 0
    worker = os.getpid()
    cgroup = _own_cgroup()
    if not cgroup:  # no cgroup: the worker keeps its descendants' orphans, the reaper tracks them
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    pid = os.fork()
    if pid:
        return pid
    try:  # the reaper: hold no fd of the worker's (its pipes must close when the worker ends)
        os.closerange(3, 65536)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1):
            signal.signal(sig, signal.SIG_IGN)
        tracked: dict[int, bytes] = {}
        while os.getppid() == worker:
            if not cgroup:
                tracked.update(descendants(worker))
                tracked.pop(os.getpid(), None)
            time.sleep(interval if cgroup else 2.5 * interval)
        if cgroup:
            _write(os.path.join(cgroup, "cgroup.kill"), "1")  # this process too
        _kill_tracked(tracked)
        _kill_own_group()
    finally:
        os._exit(0)
    return 0  # pragma: no cover


def _start_time(pid: int) -> bytes | None:
    """The start time of ``pid`` (field 22 of its stat), which tells it from a later process that
    reuses the number; None when it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
        return stat[stat.rindex(b")") + 2 :].split()[19]
    except (OSError, IndexError, ValueError):
        return None


def descendants(root: int) -> dict[int, bytes]:
    """Every live descendant of ``root``, with its start time (one pass over /proc)."""
    parents: dict[int, int] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                stat = f.read()
            parents[int(name)] = int(stat[stat.rindex(b")") + 2 :].split()[1])
        except (OSError, ValueError, IndexError):
            continue
    children: dict[int, list[int]] = {}
    for pid, ppid in parents.items():
        children.setdefault(ppid, []).append(pid)
    out: dict[int, bytes] = {}
    stack = list(children.get(root, ()))
    while stack:
        pid = stack.pop()
        start = _start_time(pid)
        if start is not None and pid not in out:
            out[pid] = start
            stack.extend(children.get(pid, ()))
    return out


def _kill_tracked(tracked: dict[int, bytes]) -> None:
    """SIGKILL the tracked processes that are still the same processes, and their descendants,
    until none is left (a process forked while this runs is caught on the next pass)."""
    for _ in range(50):
        alive = {pid: start for pid, start in tracked.items() if _start_time(pid) == start}
        if not alive:
            return
        for pid in alive:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        tracked = {}
        for pid in alive:
            tracked.update(descendants(pid))
        tracked.pop(os.getpid(), None)


def _write(path: str, text: str) -> bool:
    try:
        with open(path, "w") as f:
            f.write(text)
        return True
    except OSError:
        return False


def _own_cgroup() -> str:
    """The cgroup v2 directory this process is in when it is one :class:`Cgroups` made, else ""."""
    try:
        with open("/proc/self/cgroup") as f:
            line = next((ln for ln in f if ln.startswith("0::")), "")
    except OSError:
        return ""
    mount = _cgroup2_mount()
    rel = line[3:].strip()
    if not mount or f"/{Cgroups.PREFIX}" not in rel:
        return ""
    return os.path.join(mount, rel.lstrip("/"))


def join_cgroup(path: str = "") -> bool:
    """Move this process into the cgroup ``path`` (made by :class:`Cgroups` in the parent); its
    later children start there. False (and nothing done) without one."""
    return bool(path) and _write(os.path.join(path, "cgroup.procs"), "0")


def _cgroup2_mount() -> str:
    """Where the cgroup v2 hierarchy is mounted ("" when it is not)."""
    try:
        with open("/proc/self/mountinfo") as f:
            for line in f:
                left, _, right = line.partition(" - ")
                if right.split(" ", 1)[0] == "cgroup2":
                    return left.split()[4]
    except OSError:
        pass
    return ""


class Cgroups:
    """The cgroups of one benchmark's workers: ``<own cgroup>/planbench-<pid>/worker-<n>``, or none
    where this process may not make cgroups, or ``PLANBENCH_CGROUPS=0`` says not to (then
    :attr:`base` is "" and every call does nothing)."""

    PREFIX = "planbench-"

    def __init__(self) -> None:
        self.base = ""
        if os.environ.get("PLANBENCH_CGROUPS") == "0":  # the fallback, on purpose (tests)
            return
        mount = _cgroup2_mount()
        try:
            with open("/proc/self/cgroup") as f:
                rel = next((ln[3:].strip() for ln in f if ln.startswith("0::")), None)
        except OSError:
            rel = None
        if not mount or rel is None:
            return
        parent = os.path.join(mount, rel.lstrip("/"))
        _remove_stale(parent)
        base = os.path.join(parent, f"{self.PREFIX}{os.getpid()}")
        try:
            os.makedirs(base, exist_ok=True)
        except OSError:
            return
        if os.path.exists(os.path.join(base, "cgroup.kill")):
            self.base = base
        else:  # a kernel before 5.14: no cgroup.kill
            with contextlib.suppress(OSError):
                os.rmdir(base)

    def make(self, name: str) -> str:
        """A new cgroup for one worker ("" without cgroups)."""
        if not self.base:
            return ""
        path = os.path.join(self.base, name)
        try:
            os.mkdir(path)
        except FileExistsError:
            pass
        except OSError:
            return ""
        return path

    @staticmethod
    def kill(path: str) -> None:
        """Kill every process in cgroup ``path`` and remove it once it is empty."""
        if not path:
            return
        _write(os.path.join(path, "cgroup.kill"), "1")
        _remove(path)

    def close(self) -> None:
        if self.base:
            for name in os.listdir(self.base) if os.path.isdir(self.base) else []:
                if os.path.isdir(os.path.join(self.base, name)):
                    self.kill(os.path.join(self.base, name))
            _remove(self.base)
            self.base = ""


def _remove(path: str, wait: float = 2.0) -> None:
    """rmdir a cgroup, waiting up to ``wait`` s for its killed processes to be gone."""
    end = time.monotonic() + wait
    while True:
        try:
            os.rmdir(path)
            return
        except FileNotFoundError:
            return
        except OSError:
            if time.monotonic() > end:
                return
            time.sleep(0.01)


def _remove_stale(parent: str) -> None:
    """Remove the cgroups of benchmarks that are gone (killed before they could)."""
    try:
        names = [n for n in os.listdir(parent) if n.startswith(Cgroups.PREFIX)]
    except OSError:
        return
    for name in names:
        pid = name[len(Cgroups.PREFIX) :]
        if not pid.isdigit() or process_alive(int(pid)):
            continue
        base = os.path.join(parent, name)
        for sub in os.listdir(base):
            if os.path.isdir(os.path.join(base, sub)):
                Cgroups.kill(os.path.join(base, sub))
        _remove(base, wait=0.5)


WORKER_DIR_PREFIX = "planbench-workers-"
"""A benchmark's folder for its workers' output files and scratch folders, in the system's temporary
folder: this prefix, the benchmark's pid, a dash, a random part."""
WORKER_DIR_LOCK = ".lock"
"""The file in that folder that its benchmark holds locked (``flock``) while it runs."""


def worker_dir() -> tuple[str, int]:
    """A new folder for this benchmark's workers (:data:`WORKER_DIR_PREFIX`) and the descriptor of
    its lock, which the caller keeps open while it runs; first the folders of benchmarks that are
    gone are removed: a benchmark killed (``SIGKILL``, out of memory) cannot remove its own, and
    each one left a folder of output files in the temporary folder for good. Gone means the folder's
    lock can be taken (the kernel drops a lock with its process, whatever pid namespace that process
    was in); a folder without a lock file goes by whether the pid in its name runs."""
    parent = tempfile.gettempdir()
    pattern = re.compile(re.escape(WORKER_DIR_PREFIX) + r"(\d+)-")
    with contextlib.suppress(OSError):
        for name in os.listdir(parent):
            match = pattern.match(name)
            path = os.path.join(parent, name)
            with contextlib.suppress(OSError):
                if match is None or os.lstat(path).st_uid != os.getuid() or not os.path.isdir(path):
                    continue  # not a benchmark's folder, or another user's
                if _gone(path, int(match.group(1))):
                    shutil.rmtree(path, ignore_errors=True)
    new = ".planbench-new-"  # the folder is locked before it takes a name that the sweep reads
    made = tempfile.mkdtemp(prefix=new, dir=parent)
    lock = os.open(os.path.join(made, WORKER_DIR_LOCK), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    path = os.path.join(parent, f"{WORKER_DIR_PREFIX}{os.getpid()}-{os.path.basename(made)[len(new) :]}")
    os.rename(made, path)
    return path, lock


def _gone(path: str, pid: int) -> bool:
    """Whether the benchmark of the workers' folder ``path`` (named with ``pid``) has ended."""
    try:
        lock = os.open(os.path.join(path, WORKER_DIR_LOCK), os.O_RDWR | os.O_CLOEXEC)
    except FileNotFoundError:
        return not process_alive(pid)
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False  # held: its benchmark runs
    finally:
        os.close(lock)
    return True


def _kill_own_group() -> None:
    with contextlib.suppress(OSError):
        os.killpg(os.getpgrp(), signal.SIGKILL)
    os._exit(1)  # pragma: no cover (not a group leader: at least this process goes)


def kill_group(pid: int | None) -> None:
    """SIGKILL the process group led by ``pid`` (a worker after :func:`detach`) and ``pid`` itself."""
    if not pid:
        return
    with contextlib.suppress(OSError):
        os.killpg(pid, signal.SIGKILL)
    with contextlib.suppress(OSError):
        os.kill(pid, signal.SIGKILL)


def process_alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
        return stat[stat.rindex(b")") + 2 : stat.rindex(b")") + 3] not in (b"Z", b"X")
    except FileNotFoundError:
        return False
    except OSError:  # pragma: no cover (no /proc)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True


class OutputFile:
    """The file a worker's stdout and stderr go to, kept bounded by the parent."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.dropped = 0
        """Bytes cut from the front since the last :meth:`reset`."""

    def open_for_child(self) -> None:
        """In the worker: point fds 1 and 2 here (append mode, so the parent may cut the file)."""
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_TRUNC, 0o600)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)

    def reset(self) -> None:
        """Empty the file (in the parent, before a run: a row holds only its own run's output)."""
        self.dropped = 0
        with contextlib.suppress(OSError):
            os.truncate(self.path, 0)

    def bound(self, group: int | None = None) -> None:
        """Cut the file back to its last :data:`OUTPUT_KEEP_BYTES` once it passes :data:`OUTPUT_MAX_BYTES`.

        The worker writes with ``O_APPEND``, so its next write lands at the new end. What it wrote
        between the copy of the tail and the cut would be lost (a flooding planner's last words,
        under load), so with ``group`` (the worker's process group) the group is stopped for the
        cut (``SIGSTOP``, then ``SIGCONT``): only a planner that has printed more than
        :data:`OUTPUT_MAX_BYTES` pauses, for the milliseconds of the copy.
        """
        try:
            if os.stat(self.path).st_size <= OUTPUT_MAX_BYTES:
                return
        except OSError:
            return
        stopped = group is not None and _stop_group(group)
        try:
            size = os.stat(self.path).st_size
            with open(self.path, "r+b") as f:
                f.seek(max(0, size - OUTPUT_KEEP_BYTES))
                tail = f.read(OUTPUT_KEEP_BYTES)
                f.seek(0)
                f.truncate(0)
                f.write(tail)
            self.dropped += size - len(tail)
        except OSError:
            pass
        finally:
            if stopped:
                with contextlib.suppress(OSError):
                    os.killpg(group, signal.SIGCONT)  # type: ignore[arg-type]

    def tail(self, limit: int = TAIL_BYTES) -> str:
        """The last ``limit`` bytes as text, with a note of how much came before ("" when empty)."""
        try:
            with open(self.path, "rb") as f:
                size = f.seek(0, os.SEEK_END)
                f.seek(max(0, size - limit))
                data = f.read(limit)
        except OSError:
            return ""
        if not data:
            return ""
        before = self.dropped + max(0, size - limit)
        text = data.decode("utf-8", errors="replace").replace("\x00", "\\x00")
        return (f"[... {before} bytes before this]\n" if before else "") + text


def _stop_group(group: int, wait: float = 0.5) -> bool:
    """Stop the process group ``group`` (``SIGSTOP``) and wait up to ``wait`` [s] until its leader
    is stopped (a write in progress completes first); False if it could not be signalled."""
    try:
        os.killpg(group, signal.SIGSTOP)
    except OSError:
        return False
    end = time.monotonic() + wait
    while time.monotonic() < end:
        try:
            with open(f"/proc/{group}/stat", "rb") as f:
                state = f.read().rsplit(b")", 1)[1].split()[0]
        except (OSError, IndexError):
            break  # no /proc (not Linux) or gone: cut as before
        if state in (b"T", b"t", b"Z", b"X"):
            break
        time.sleep(0.0005)
    return True


@contextlib.contextmanager
def thread_environment(threads: int) -> Iterator[None]:
    """The thread-pool variables set while a child starts, so that its libraries start no pool
    threads on import: the worker must hold a single thread when it enters its sandbox."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update({name: str(threads) for name in THREAD_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
