"""The closed loop across a process boundary: the simulation on one side, the controller on the other.

The simulation (:func:`planbench.reactive.runner.simulate`) runs in a process where no controller
code has run; the controller runs in a process of its own (:func:`serve_controller`), with new
processes forbidden (:func:`~planbench.reactive.isolation.forbid_new_processes`). They exchange
one message and its answer per call, over a stream socket pair::

    kind (1 byte) | length (u32, little endian) | payload

simulation -> controller: ``P`` the grid's shape, before the run (the controller's side
allocates its grids, uncharged), ``U`` an observation (a binary header, the change from the grid its slot
held four frames before, its points: :class:`GridRing`), ``S`` a step (``t`` and ``q`` as
float64), ``E`` the end of the run. controller -> simulation: ``p`` grids allocated, ``u`` update done,
``c`` the command (``nq`` float64), ``i`` the controller's ``info()`` as JSON, ``x`` a fault
(UTF-8 text: the controller raised or returned something that is not a joint velocity).

**Compute is charged from outside** (:class:`RemoteController`). The simulation reads the kernel's
CPU clock of the controller's process (all its threads) after every answer; the time charged to a
call is the CPU time the process consumed since the previous answer, so work a background thread
does between ticks is charged to the next call. A controller cannot start other processes, so
this is all of its compute; nothing the controller's process does to its own clocks or modules
changes it, and it does not grow with other load on the machine (CPU time, not wall time). The
wall-clock round trip of each call is recorded apart (``handoff``). Both processes are pinned to
one core for the run: they never compute at the same time, and a hand-off on one core is a
direct switch (a few µs) where one across cores waits for the other core to wake (60-100 µs
measured on an idle 2-core VM).

A call waits on the wall clock as long as the controller keeps consuming CPU within what is left
of the horizon; past that its command can no longer take effect, the call is abandoned
(:class:`Overrun`) and the controller's process is killed once its ``info`` is read (after the
late answer, thrown away, when it comes within :data:`LATE_WAIT` seconds). A call that consumes no
CPU (the controller sleeps or waits) is abandoned after :data:`IDLE_WAIT` seconds of wall time.
"""

from __future__ import annotations

import json
import math
import os
import select
import signal
import socket
import struct
import sys
import time
from typing import Any

import lz4.block
import numpy as np

from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.controller import BadCommand, Observation, as_command
from planbench.reactive.isolation import ProcessClock
from planbench.scene import Scene

__all__ = [
    "IDLE_WAIT",
    "ControllerGone",
    "Overrun",
    "RemoteController",
    "RemoteFault",
    "GRID_SLOTS",
    "GridRing",
    "GridView",
    "serve_controller",
]

_HEAD = struct.Struct("<cI")
_FRAME = struct.Struct("<dqI??3q3dddqqqqq")
"""A frame's header: time, frame number, slot, fresh, all values 1, the grid's shape, origin,
resolution and outside value, then the counts of cells cleared and set, of points, and the bytes of
the known mask and of the scene's JSON (-1: none). Fixed binary fields: a JSON header cost the
controller 40-70 us a frame to parse, with its caches cold after the simulation's work."""
MAX_ANSWER_BYTES = 2**20
"""Largest answer the simulation reads [bytes] (a command is ``8 nq``; ``info`` JSON at most this)."""
MAX_FRAME_BYTES = 2**28
"""Largest message the controller's side reads [bytes] (a frame: its grid's change, points, scene)."""
IDLE_WAIT = 10.0
"""[s] of wall time a call may go on without the controller consuming CPU before it is abandoned."""
POLL = 0.05
"""[s] between checks of a call's CPU time while the simulation waits for its answer."""
CPU_OVERRUN = "the call consumed more CPU time than was left of the horizon"
"""Why a call was abandoned for its CPU time (:attr:`RemoteController.abandoned`)."""
LATE_WAIT = 5.0
"""[s] of wall time the simulation waits after the run for the answer of a call abandoned for its
CPU time, to ask the controller's ``info`` after it (the run's verdict is already made)."""


class RemoteFault(Exception):
    """The controller raised, or answered something that is not what the protocol asks."""


class ControllerGone(RemoteFault):
    """The controller's process closed the connection or died."""


class Overrun(Exception):
    """A call consumed more CPU time than was left of the horizon, or waited without computing for
    :data:`IDLE_WAIT`; ``charged`` [s] is what it consumed when abandoned."""

    def __init__(self, charged: float, why: str) -> None:
        super().__init__(why)
        self.charged = charged


# -- framing -----------------------------------------------------------------------------------


def _send(sock: socket.socket, kind: bytes, payload: bytes = b"") -> None:
    head = _HEAD.pack(kind, len(payload))
    if len(payload) < 65536:  # one system call for the per-tick messages
        sock.sendall(head + payload)
    else:
        sock.sendall(head)
        sock.sendall(payload)


def _recv_exact(sock: socket.socket, n: int) -> bytearray:
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        k = sock.recv_into(view[got:], n - got)
        if k == 0:
            raise ControllerGone("the controller's process closed the connection")
        got += k
    view.release()
    return buf


def _recv(sock: socket.socket, limit: int) -> tuple[bytes, bytearray]:
    kind, length = _HEAD.unpack(_recv_exact(sock, _HEAD.size))
    if length > limit:
        raise RemoteFault(f"sent a message of {length} bytes (limit {limit})")
    return kind, _recv_exact(sock, length) if length else bytearray()


# -- observations --------------------------------------------------------------------------------


GRID_SLOTS = 4
"""Grids kept per run on the controller's side: frame ``j`` is written into slot ``j %
GRID_SLOTS``, so the arrays of an observation stay as delivered while the next
``GRID_SLOTS - 1`` frames arrive."""


class GridRing:
    """The simulation's side of a run's grids: what each of the controller's :data:`GRID_SLOTS`
    slots holds, and the change that turns it into a new frame.

    A frame is sent as the cells of its slot to clear and the cells to set (flat indices, values
    unless all are 1), not as a grid: a sensed grid is mostly free (0.8 % of 2.9 M cells on the
    shipped scenarios) and changes little from frame to frame, so the controller, which is charged
    for receiving it, reads little and writes little."""

    def __init__(self) -> None:
        self._held: list[tuple[tuple[int, ...], np.ndarray, np.ndarray] | None] = [None] * GRID_SLOTS
        self._frames = 0

    def prepared(self, shape: tuple[int, ...]) -> None:
        """The controller has allocated every slot of ``shape``, all free."""
        self._held = [(tuple(shape), np.zeros(0, dtype=np.int64), np.zeros(0))] * GRID_SLOTS

    def write(self, obs: Observation) -> bytes:
        """The frame's message: a binary header (:data:`_FRAME`), then the change's arrays, the known
        mask, the points and the scene's JSON."""
        grid = np.asarray(obs.grid.data, dtype=np.float64)
        j = self._frames % GRID_SLOTS
        self._frames += 1
        cells = np.flatnonzero(grid != 0)  # of a bool mask: 10 times faster than of the floats (27 -> 2.6 ms at 142^3)
        values = grid.reshape(-1)[cells]
        held = self._held[j]
        if held is None or held[0] != grid.shape:
            clear, changed = np.zeros(0, dtype=np.int64), np.ones(len(cells), dtype=bool)
            fresh = True
        else:
            _, old_cells, old_values = held
            clear = np.setdiff1d(old_cells, cells, assume_unique=True)
            at = np.searchsorted(old_cells, cells).clip(max=max(len(old_cells) - 1, 0))
            if len(old_cells):
                same = (old_cells[at] == cells) & (old_values[at] == values)
            else:
                same = np.zeros(len(cells), bool)
            changed = ~same
            fresh = False
        self._held[j] = (grid.shape, cells, values)
        set_cells, set_values = cells[changed], values[changed]
        known = None
        if obs.grid.known is not None:  # a bit per cell, LZ4-compressed: the controller reads 4x fewer bytes
            known = lz4.block.compress(np.packbits(obs.grid.known.reshape(-1)).tobytes(), store_size=False)
        ones = bool(np.all(set_values == 1.0))
        points = None if obs.points is None else np.ascontiguousarray(obs.points, dtype="<f4")
        if grid.ndim != 3 or (points is not None and (points.ndim != 2 or points.shape[1] != 3)):
            raise ValueError(
                f"a frame needs a 3-D grid and (N, 3) points, got {grid.shape} and "
                f"{None if points is None else points.shape}"
            )
        scene = None if obs.scene is None else json.dumps(obs.scene.to_dict()).encode()
        head = _FRAME.pack(
            float(obs.time),
            int(obs.frame),
            j,
            fresh,
            ones,
            *grid.shape,
            *(float(x) for x in obs.grid.origin),
            float(obs.grid.resolution),
            float(obs.grid.outside),
            len(clear),
            len(set_cells),
            -1 if points is None else len(points),
            -1 if known is None else len(known),
            -1 if scene is None else len(scene),
        )
        parts = [head, clear.astype("<i8").tobytes(), set_cells.astype("<i8").tobytes()]
        if not ones:
            parts.append(set_values.astype("<f8").tobytes())
        if known is not None:
            parts.append(known)
        if points is not None:
            parts.append(points.tobytes())
        if scene is not None:
            parts.append(scene)
        return b"".join(parts)


class GridView:
    """The controller's side of a run's grids: :data:`GRID_SLOTS` arrays of its own memory, each
    changed in place by the frames written into it (:class:`GridRing`)."""

    def __init__(self) -> None:
        self._slots: dict[int, np.ndarray] = {}

    def prepare(self, shape: tuple[int, ...]) -> None:
        """Allocate every slot of ``shape``, free, each page written once."""
        for j in range(GRID_SLOTS):
            slot = np.empty(int(np.prod(shape)))
            slot.fill(0.0)  # every page written now: reading a never-written page costs a fault each time
            self._slots[j] = slot

    def read(self, message: bytes | bytearray) -> Observation:
        """The observation of a frame message; :class:`RemoteFault` when the controller still holds
        arrays of the frame its slot held before (it must copy what it keeps longer)."""
        (
            t,
            frame,
            j,
            fresh,
            ones,
            nx,
            ny,
            nz,
            ox,
            oy,
            oz,
            resolution,
            outside,
            n_clear,
            n_set,
            n_points,
            n_known,
            n_scene,
        ) = _FRAME.unpack_from(message)
        shape = (nx, ny, nz)
        at = _FRAME.size
        clear = np.frombuffer(message, dtype="<i8", count=n_clear, offset=at)
        at += 8 * n_clear
        cells = np.frombuffer(message, dtype="<i8", count=n_set, offset=at)
        at += 8 * n_set
        if ones:
            values: Any = 1.0
        else:
            values = np.frombuffer(message, dtype="<f8", count=n_set, offset=at)
            at += 8 * n_set
        slot = self._slots.get(j)
        if slot is not None and sys.getrefcount(slot) > 3:  # the dict, this name, the argument
            raise RemoteFault(
                f"the controller still holds arrays of an observation {GRID_SLOTS} frames old, which this "
                f"frame overwrites: observation arrays stay as delivered for {GRID_SLOTS - 1} more frames; "
                "copy what you keep longer"
            )
        if fresh or slot is None or slot.size != nx * ny * nz:
            slot = np.zeros(nx * ny * nz)
            self._slots[j] = slot
        slot[clear] = 0.0
        slot[cells] = values
        grid = slot.reshape(shape)
        grid.flags.writeable = False
        view = memoryview(message)
        packed = None
        if n_known >= 0:  # a view of the message, inflated when first read: no copy of it
            packed = view[at : at + n_known]
            at += n_known
        points = None
        if n_points >= 0:
            points = np.frombuffer(message, dtype="<f4", count=3 * n_points, offset=at).reshape(n_points, 3)
            at += 12 * n_points
        scene = None if n_scene < 0 else view[at : at + n_scene]
        occupancy = _grid_as_checked(grid, np.array((ox, oy, oz)), resolution, outside, packed=packed)
        return _delivered(t, occupancy, frame, points, scene)


class _DeliveredObservation(Observation):
    """An :class:`Observation` whose scene (truth sensing) is parsed when first read: most
    controllers never read it, and they are charged for receiving the frame."""

    @property  # type: ignore[override]
    def scene(self) -> Scene | None:
        cached = self.__dict__.get("_scene")
        if cached is None and self.__dict__["_scene_json"] is not None:
            cached = Scene.from_dict(json.loads(bytes(self.__dict__["_scene_json"])), "observation")
            self.__dict__["_scene"] = cached
        return cached

    @scene.setter
    def scene(self, value: Scene | None) -> None:  # dataclasses.replace sets it
        self.__dict__.update(_scene=value, _scene_json=None)


def _delivered(
    t: float, grid: OccupancyGrid, frame: int, points: np.ndarray | None, scene: memoryview | None
) -> Observation:
    obs = object.__new__(_DeliveredObservation)
    for name, value in (("time", t), ("grid", grid), ("frame", frame), ("points", points), ("_scene_json", scene)):
        obs.__dict__[name] = value
    return obs


class _DeliveredGrid(OccupancyGrid):
    """An :class:`OccupancyGrid` whose ``known`` mask arrives packed (a bit per cell, LZ4-compressed)
    and is unpacked when first read: a controller that never reads it is charged only for
    receiving its bytes."""

    def _bits(self) -> np.ndarray:
        """The mask's bits, a bit per cell (C order, most significant bit first), inflated once."""
        bits = self.__dict__.get("_unpacked_bits")
        if bits is None:
            cells = int(np.prod(self.data.shape))
            packed = lz4.block.decompress(self.__dict__["_packed"], uncompressed_size=(cells + 7) // 8)
            bits = self.__dict__["_unpacked_bits"] = np.frombuffer(packed, dtype=np.uint8)
        return bits

    @property  # type: ignore[override]
    def known(self) -> np.ndarray | None:
        cached = self.__dict__.get("_known")
        if cached is None:
            cells = int(np.prod(self.data.shape))
            cached = np.unpackbits(self._bits(), count=cells).view(bool).reshape(self.data.shape)
            cached.flags.writeable = False
            self.__dict__["_known"] = cached
        return cached

    @known.setter
    def known(self, value: np.ndarray | None) -> None:  # dataclasses.replace sets it
        self.__dict__["_known"] = value

    def known_at(self, cells: np.ndarray) -> np.ndarray:
        """Bits of ``cells`` read from the packed mask: no bool per cell of the grid is made."""
        if self.__dict__.get("_known") is not None:
            return super().known_at(cells)
        cells = np.asarray(cells, dtype=np.intp)
        return ((self._bits()[cells >> 3] >> (7 - (cells & 7))) & 1).astype(bool)


def _grid_as_checked(
    data: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    outside: float,
    known: np.ndarray | None = None,
    packed: bytes | memoryview | None = None,
) -> OccupancyGrid:
    """The grid without :class:`OccupancyGrid`'s checks of every cell (milliseconds on a sensed
    grid, which the controller would be charged for): the simulation's sensor built and checked
    it, and the file comes from the simulation. ``packed``: its known mask as sent, unpacked when
    first read (:class:`_DeliveredGrid`), instead of ``known``."""
    grid = object.__new__(OccupancyGrid if packed is None else _DeliveredGrid)
    fields = {"data": data, "origin": origin, "resolution": resolution, "outside": float(outside)}
    grid.__dict__.update(fields, **({"known": known} if packed is None else {"_packed": packed}))
    return grid


# -- the controller's side -------------------------------------------------------------------------


def serve_controller(sock: socket.socket, controller: Any, nq: int, goal: Any) -> None:
    """Answer the simulation's calls with ``controller`` until the run ends (``E``) or the
    connection closes. Runs in the controller's process: nothing here is trusted by the other side."""
    latest: Observation | None = None
    grids = GridView()
    while True:
        try:
            kind, payload = _recv(sock, MAX_FRAME_BYTES)
        except (RemoteFault, OSError):
            return
        if kind == b"P":
            grids.prepare(tuple(int(x) for x in json.loads(payload)["shape"]))
            _send(sock, b"p")
        elif kind == b"U":
            latest = None
            try:
                latest = grids.read(payload)
            except RemoteFault as fault:
                _send(sock, b"x", str(fault).encode())
                continue
            try:
                controller.update(latest)
            except Exception as exc:
                _send(sock, b"x", f"the controller raised {type(exc).__name__}: {exc}"[:4000].encode())
                continue
            _send(sock, b"u")
        elif kind == b"S":
            values = np.frombuffer(payload, dtype=np.float64)
            t, q = float(values[0]), values[1:].copy()
            try:
                qd = controller.step(t, q, latest, goal)
            except Exception as exc:
                _send(sock, b"x", f"the controller raised {type(exc).__name__}: {exc}"[:4000].encode())
                continue
            answer = command_bytes(qd, nq)
            _send(sock, *answer)
        elif kind == b"E":
            try:
                info = json.dumps(dict(controller.info()), default=str, allow_nan=True).encode()
            except Exception as exc:
                info = json.dumps({"info_error": f"{type(exc).__name__}: {exc}"}).encode()
            _send(sock, b"i", info[:MAX_ANSWER_BYTES])
            return


def command_bytes(qd: Any, nq: int) -> tuple[bytes, bytes]:
    """The answer to a step: ``c`` and the velocities, or ``x`` naming what is wrong with them."""
    try:
        return b"c", as_command(qd, nq).astype("<f8").tobytes()
    except BadCommand as bad:
        return b"x", str(bad)[:4000].encode()


# -- the simulation's side -------------------------------------------------------------------------


class RemoteController:
    """The controller of a run as the simulation sees it: calls over ``sock`` to process ``pid``,
    each charged the CPU time that process consumed (module docstring).

    ``handoff`` [s]: each call's wall-clock round trip less the CPU time charged for it (the cost
    of the hand-off, and of waiting for the core when the machine is loaded)."""

    def __init__(self, sock: socket.socket, pid: int, nq: int) -> None:
        self.sock = sock
        self.pid = pid
        self.nq = nq
        self.clock = ProcessClock(pid)
        self.grids = GridRing()
        self._cpu = self.clock.read()
        self.handoff: list[float] = []
        self.wall: list[float] = []
        self.budget = math.inf
        """[s] CPU time a call may consume before it is abandoned (the simulation sets it to what
        is left of the horizon)."""
        self.abandoned: str | None = None
        """Why a call was abandoned (:class:`Overrun`), once one was: its answer is never read, so
        the connection holds nothing the next message could be matched with."""

    def prepare(self, shape: tuple[int, ...]) -> None:
        """Have the controller's process allocate its grids of ``shape`` before the run, uncharged
        (writing 4 x 23 MB once would otherwise cost the first frames milliseconds each)."""
        self.budget = IDLE_WAIT
        kind, _, _ = self._call(b"P", json.dumps({"shape": list(shape)}).encode())
        if kind != b"p":
            raise RemoteFault(f"answered {kind!r} to the preparation of its grids")
        self.grids.prepared(shape)
        self._cpu = self.clock.read()
        self.handoff.clear()
        self.wall.clear()
        self.budget = math.inf

    def update(self, observation: Observation) -> float:
        kind, _, charged = self._call(b"U", self.grids.write(observation))
        if kind != b"u":
            raise RemoteFault(f"answered {kind!r} to an observation")
        return charged

    def step(self, t: float, q: np.ndarray, observation: Any, goal: Any) -> tuple[np.ndarray, float]:
        payload = np.concatenate([[t], np.asarray(q, dtype=float)]).astype("<f8").tobytes()
        kind, answer, charged = self._call(b"S", payload)
        if kind != b"c":
            raise RemoteFault(f"answered {kind!r} to a step")
        if len(answer) != 8 * self.nq:
            raise RemoteFault(f"sent a command of {len(answer)} bytes, expected {self.nq} float64")
        try:
            return as_command(np.frombuffer(answer, dtype="<f8"), self.nq), charged
        except BadCommand as bad:
            raise RemoteFault(str(bad)) from None

    def info(self) -> dict[str, Any]:
        """The controller's diagnostics (JSON data as sent; the benchmark cleans them). After a
        call abandoned for its CPU time, its late answer is awaited for up to :data:`LATE_WAIT`
        seconds and thrown away first (a plan that ran past the horizon's end); after one abandoned
        for computing nothing, or a late answer that does not come, the controller is not asked."""
        if self.abandoned is not None and not self._drain_late_answer():
            return {"info_error": f"not asked: a call was abandoned ({self.abandoned})"}
        self.abandoned = None
        self.budget = 5.0  # info() is not timed, but may not run forever
        try:
            kind, answer, _ = self._call(b"E", b"")
            data = json.loads(answer) if kind == b"i" else {"info_error": f"answered {kind!r} to the end"}
        except (RemoteFault, Overrun, OSError, ValueError) as exc:
            data = {"info_error": f"{type(exc).__name__}: {exc}"}
        return data if isinstance(data, dict) else {"info": data}

    def _drain_late_answer(self) -> bool:
        """Read and drop the answer of the call abandoned for its CPU time, when it comes within
        :data:`LATE_WAIT` s; True when the connection then holds nothing (the next answer is the
        next call's)."""
        if self.abandoned != CPU_OVERRUN:
            return False
        timeout = self.sock.gettimeout()
        self.sock.settimeout(LATE_WAIT)  # an answer begun and never finished blocks no read for longer
        try:
            ready, _, _ = select.select([self.sock], [], [], LATE_WAIT)
            if not ready:
                return False
            _recv(self.sock, MAX_ANSWER_BYTES)
        except (OSError, RemoteFault, ControllerGone):
            return False
        finally:
            self.sock.settimeout(timeout)
        return True

    def kill(self) -> None:
        """End the controller's process and its group (it is a session leader of its own)."""
        for send in (os.killpg, os.kill):
            try:
                send(self.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    def _call(self, kind: bytes, payload: bytes) -> tuple[bytes, bytearray, float]:
        if self.abandoned is not None:
            raise RemoteFault(
                f"a call was abandoned earlier ({self.abandoned}): its answer would be read as this "
                "call's, so the controller is asked nothing more"
            )
        t0 = time.perf_counter()
        try:
            _send(self.sock, kind, payload)
        except OSError as exc:
            raise ControllerGone(f"the controller's process is gone ({exc})") from exc
        self._wait(t0)
        try:
            answer_kind, answer = _recv(self.sock, MAX_ANSWER_BYTES)
        except OSError as exc:
            raise ControllerGone(f"the controller's process is gone ({exc})") from exc
        wall = time.perf_counter() - t0
        charged = self._charge()
        self.wall.append(wall)
        self.handoff.append(max(0.0, wall - charged))
        if answer_kind == b"x":
            raise RemoteFault(answer.decode("utf-8", "replace")[:4000])
        return answer_kind, answer, charged

    def _charge(self) -> float:
        try:
            now = self.clock.read()
        except ProcessLookupError as exc:
            raise ControllerGone("the controller's process died") from exc
        spent, self._cpu = now - self._cpu, now
        return spent * 1e-9

    def _wait(self, t0: float) -> None:
        """Wait for the answer, abandoning the call as the module docstring says."""
        idle_since, cpu_seen = t0, self._cpu
        while True:
            ready, _, _ = select.select([self.sock], [], [], POLL)
            if ready:
                return
            try:
                cpu = self.clock.read()
            except ProcessLookupError:
                return  # the read that follows meets the closed connection
            now = time.perf_counter()
            if (cpu - self._cpu) * 1e-9 > self.budget:
                self.abandoned = CPU_OVERRUN
                raise Overrun((cpu - self._cpu) * 1e-9, self.abandoned)
            if cpu != cpu_seen:
                idle_since, cpu_seen = now, cpu
            elif now - idle_since > IDLE_WAIT:
                self.abandoned = f"the controller computed nothing for {IDLE_WAIT:g} s"
                raise Overrun((cpu - self._cpu) * 1e-9, self.abandoned)


def socket_pair() -> tuple[socket.socket, socket.socket]:
    """A connected pair of stream sockets for :func:`serve_controller` and :class:`RemoteController`."""
    return socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
