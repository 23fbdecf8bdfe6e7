"""An RRT-Connect query advanced in slices bounded by collision checks, for a control loop.

A controller that plans inside its own control step cannot give a planner a time limit: its
compute is charged per tick, and a plan of 100 ms stalls ten 10 ms ticks. :class:`SlicedRRTConnect`
holds one OMPL query and advances it by at most ``checks`` collision checks per call to
:meth:`~SlicedRRTConnect.advance`, so a plan is spread over as many ticks as it needs, each
costing about the same.

**How a slice ends.** Each call is one OMPL ``solve`` on the same problem definition with a
``PlannerTerminationCondition`` built from a Python function that compares the checks made (state
validity calls plus the configurations the motion validator checked) with the slice's end.
RRT-Connect keeps both trees across ``solve`` calls (its ``clear`` is never called). Verified on
OMPL 2.0.1's Python API: with ``overrun_motions=None``, a query advanced in slices of 37 to 1,000
checks makes the same checks, trees and path as one ``solve`` without a limit (tested).

OMPL tests the condition once per iteration, though, and one iteration (an extension, then a
connect of as many extensions as it takes to reach the other tree) can cost hundreds of checks.
So once a slice has run ``overrun_motions`` motions (of ``ceil(extension / resolution)`` checks)
past its end, every further state and motion is refused until ``solve`` returns: the connect under
way stops there, as at an obstacle (nothing invalid enters a tree; the trees differ from an
unsliced run's from then on). A slice ends within :attr:`~SlicedRRTConnect.max_overshoot` checks of
its bound. Refusing at once (0) cuts most connects and costs RRT-Connect: on MotionBenchMaker
``box``, ``bookshelf_tall``, ``bookshelf_small``, ``table_pick``, ``cage``, ``table_under_pick``
``/0001``, 4 seeds, slices of 50 checks, at most 40,000 checks: refusing at once solved 20/24 with
a median 2,022 checks; one motion of overrun (the default) 22/24, 950 checks, at most 130 in a
slice; no bound 22/24, 744 checks, up to 318 in a slice. Either way it is deterministic: which
checks a slice makes depends on the seed and the check counts only, never on the clock.

**Exact slices** (``exact=True``). The search runs on a thread of its own, paused at every check
once its slice's checks are spent and resumed by the next :meth:`~SlicedRRTConnect.advance`: a slice
makes exactly its checks (motions are checked a configuration at a time), no iteration is cut,
and the query makes the checks, trees and path of one ``solve`` without a limit whatever the slice
sizes (tested). Only one of the two threads runs at a time (each waits on the other's semaphore),
so the checks are the same whatever the scheduler does, and the CPU time the search consumes is
the process's, charged where it is spent. This is what a 1 kHz loop needs: 5 checks a slice with a
one-motion overrun would still allow 105 checks (several milliseconds) in one tick.

**A slice's CPU time** (``advance(checks, cpu_until=...)``). A check's cost varies (a
configuration near many octree cells, a machine whose other processes slow its caches), so a
slice of a fixed count can pass a control period. Given ``cpu_until`` (a ``time.process_time``
value [s]), an exact search and the shortening also end their slice at the first check that
finds the process's CPU time past it, after at least one check. The pause changes nothing but
where the slice ends: the checks, trees and path stay those of one ``solve`` (tested). The
bounded mode ignores it (its slice's end cuts a connect).

**No batch pool.** Motions are checked a configuration at a time on the checker's own broadphase
(:class:`~.motion.SegmentChecker` with ``pooled=False``): the batch check's pool copies every
obstacle when it is built, 6-12 ms in one piece with a depth frame's octrees, which alone missed a
100 Hz tick at each plan's start (``matrix-field-guided`` on ``dynamic-test``).

**Shortening.** Once found, the path is shortened in slices too (:meth:`advance` goes on with it):
greedily, from each kept waypoint the farthest later one that a free straight motion reaches
replaces those between (each motion checked at ``resolution``, the checks counted as the search's).
It visits at most ``n (n - 1) / 2`` motions of a path of ``n`` waypoints and uses no randomness,
where OMPL's ``PathSimplifier`` runs until a time limit. An RRT-Connect path of 0.5 rad steps is a
zigzag: tracked as found, the arm would take the zigzag at the tracking speed.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from typing import Any

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planbench.checking.collision import CollisionChecker

from .motion import SegmentChecker

__all__ = ["SlicedRRTConnect"]


class SlicedRRTConnect:
    """One RRT-Connect query from ``start`` to ``goal`` [rad] against ``checker``, advanced by
    :meth:`advance` (module docstring). ``seed``: OMPL's seed for the query (every random OMPL
    object of the query is created after it is set); ``extension``: RRT-Connect's range, its longest
    extension [rad]; ``resolution``: the largest joint motion between checked configurations [rad];
    ``shorten``: shorten the path found; ``overrun_motions``: how many motions past its bound a
    slice may run to finish the iteration under way (None: no limit; module docstring); ``exact``:
    the search on a thread of its own, paused at its slice's bound (module docstring; the overrun
    then does not apply)."""

    def __init__(
        self,
        checker: CollisionChecker,
        start: np.ndarray,
        goal: np.ndarray,
        *,
        seed: int,
        extension: float = 0.5,
        resolution: float = 0.01,
        shorten: bool = True,
        overrun_motions: float | None = 1.0,
        exact: bool = False,
    ) -> None:
        self.start = np.array(start, dtype=float)
        self.goal = np.array(goal, dtype=float)
        self.shorten = shorten
        self.segments = SegmentChecker(checker, resolution, pooled=False)  # no 6-12 ms pool in one tick
        motion = math.ceil(extension / resolution - 1e-12)  # the most checks of one motion
        self.overrun = None if overrun_motions is None else math.ceil(overrun_motions * motion)
        """Checks past its bound after which a slice refuses states and motions (None: never)."""
        self.max_overshoot = None if self.overrun is None else self.overrun + motion
        """The most checks a slice may make beyond its bound (None: no limit)."""
        self._pacer = _Pacer() if exact else None
        if self._pacer is not None:
            self.overrun = self.max_overshoot = 0
            weakref.finalize(self, self._pacer.stop)  # a query dropped unfinished ends its search's thread
        self.path: np.ndarray | None = None
        """The path once found (start first), shortened as :meth:`advance` goes on; None before."""
        self.done = False
        """The path is final (found, and shortened when ``shorten``)."""
        self.slices = 0
        """Calls of :meth:`advance` that did work."""
        self._states = 0  # state validity checks
        self._end = 0  # the check count at which the current slice ends
        self._began = 0  # the check count at which it began
        self._cpu_until: float | None = None  # the process CPU time [s] at which it ends (exact, shortening)
        self._i = 0  # shortening: the waypoint from which the farthest reachable one is sought,
        self._j = 0  # the one tried now,
        self._motion: tuple[np.ndarray, int] | None = None  # and that motion's states left to check
        for what, q in (("start", self.start), ("goal", self.goal)):
            if checker.in_collision(q):
                # OMPL would wait for another goal sample (sleeping 10 ms at a time) until the slice
                # ends, and with no checks made it never would
                raise ValueError(f"the {what} configuration is in collision: check it before planning")
        self._ompl: tuple[Any, ...] | None = _query(self, checker, extension, resolution, int(seed), self._pacer)

    @property
    def checks(self) -> int:
        """Collision checks made so far: state validity calls plus the configurations of motions."""
        return self._states + self.segments.n_checks

    @property
    def spent(self) -> bool:
        """The current slice's checks are spent, or (exact search, shortening) its CPU time, once
        it made a check (module docstring)."""
        checks = self.checks
        if checks >= self._end:
            return True
        if self._cpu_until is None or checks <= self._began or (self._pacer is None and self.path is None):
            return False
        return time.process_time() >= self._cpu_until

    @property
    def refusing(self) -> bool:
        """States and motions are refused now: the slice is ``overrun`` checks past its end."""
        return self.overrun is not None and self.checks >= self._end + self.overrun

    @property
    def failed(self) -> bool:
        """The search ended without a path (an exact query whose search stopped: it never will)."""
        return self.path is None and self._pacer is not None and self._pacer.finished

    def advance(self, checks: int, cpu_until: float | None = None) -> bool:
        """Spend at most ``checks`` more checks (the search: up to :attr:`max_overshoot` beyond) on
        the search, then on shortening its path, and (exact search, shortening) stop at the first
        check past the process CPU time ``cpu_until`` [s] once one is made; True once the path is
        final (:attr:`done`)."""
        if self.done:
            return True
        self.slices += 1
        self._began = self.checks
        self._end = self._began + max(1, int(checks))
        self._cpu_until = cpu_until
        if self.path is None:
            if self._ompl is None:  # closed, or an exact search that ended without a path
                return False
            ss, stop = self._ompl[0], self._ompl[1]
            if self._pacer is None:
                status = ss.solve(stop)
            else:
                if not self._pacer.run_slice(self._end, ss):
                    return False
                status = self._pacer.status
                if self._pacer.error is not None:
                    raise self._pacer.error
            if status is None or status.asString() != "Exact solution" or not ss.haveExactSolutionPath():
                if self._pacer is not None:
                    self.close()
                return False
            found = ss.getSolutionPath()
            nq = len(self.start)
            path = np.array([[found.getState(k)[i] for i in range(nq)] for k in range(found.getStateCount())])
            path[0], path[-1] = self.start, self.goal
            self.path = path
            self.close()
            self._i, self._j = 0, len(path) - 1
            if not self.shorten:
                self.done = True
                return True
        self._shorten()
        return self.done

    def count_state(self) -> bool:
        """Count one state validity check; False when it is refused (:attr:`refusing`; an exact
        query's search waits for its slice instead, and is never refused)."""
        if self._pacer is None and self.refusing:
            return False
        self._states += 1
        return True

    def _shorten(self) -> None:
        """Greedy shortening until the slice's checks are spent (module docstring); a long
        motion is checked over several slices, each never past its bound."""
        path = self.path
        assert path is not None
        while self._i < len(path) - 2:
            if self.spent:
                return
            i, j = self._i, self._j
            free = j > i + 1 and self._motion_free(path[i], path[j])
            if free is None:
                return  # the motion goes on in the next slice
            if free:
                path = self.path = np.vstack([path[: i + 1], path[j:]])
                j = i + 1
            if j <= i + 1:
                self._i = i + 1
                self._j = len(path) - 1
            else:
                self._j = j - 1
        self.done = True

    def _motion_free(self, a: np.ndarray, b: np.ndarray) -> bool | None:
        """Whether ``a -> b`` is free at the search's check points (in the same bisection order),
        checking only what the slice has left: None when that ran out first."""
        if self._motion is None:
            self._motion = self.segments.motion_states(a, b), 0
        states, done = self._motion
        while done < len(states):
            if self.spent:
                self._motion = states, done
                return None
            take = len(states) - done if self._cpu_until is None else 1  # else the CPU time read between
            take = min(take, self._end - self.checks)
            if self.segments.first_hit(states[done : done + take]) >= 0:
                self._motion = None
                return False
            done += take
        self._motion = None
        return True

    def close(self) -> None:
        """Free the OMPL objects, ending an exact query's search (the path, once found, stays)."""
        if self._pacer is not None:
            self._pacer.stop()
        self._ompl = None


class _Pacer:
    """The thread of an exact query's search and the two semaphores by which it and the caller
    hand the turn to each other (module docstring): only one of them runs at a time."""

    def __init__(self) -> None:
        self.go = threading.Semaphore(0)  # the caller -> the search: run a slice
        self.paused = threading.Semaphore(0)  # the search -> the caller: the slice is spent, or it ended
        self.stopped = False
        self.finished = False
        self.status: Any = None
        self.error: BaseException | None = None
        self.thread: threading.Thread | None = None

    def run_slice(self, end: int, ss: Any) -> bool:
        """Let the search run until its slice is spent; True once it has ended."""
        if self.finished:
            return True
        if self.thread is None:
            stop = ob.PlannerTerminationCondition(lambda: self.stopped)
            self.thread = threading.Thread(target=self._search, args=(ss, stop), daemon=True, name="sliced-search")
            self.thread.start()
        self.go.release()
        self.paused.acquire()
        return self.finished

    def wait_turn(self, spent: bool) -> bool:
        """Before a check on the search's thread: wait for the next slice when this one is
        ``spent``; False once the search is stopped (the check is refused)."""
        if spent and not self.stopped:
            self.paused.release()
            self.go.acquire()
        return not self.stopped

    def stop(self) -> None:
        """End the search (its checks refused, the termination condition true) and its thread."""
        self.stopped = True
        thread = self.thread
        if thread is not None and thread.is_alive() and thread is not threading.current_thread():
            self.go.release()
            thread.join()

    def _search(self, ss: Any, stop: Any) -> None:
        self.go.acquire()
        try:
            if not self.stopped:
                self.status = ss.solve(stop)
        except BaseException as exc:  # handed to the caller's thread, raised there
            self.error = exc
        finally:
            self.finished = True
            self.paused.release()


def _query(
    owner: SlicedRRTConnect,
    checker: CollisionChecker,
    extension: float,
    resolution: float,
    seed: int,
    pacer: _Pacer | None,
) -> Any:
    """The OMPL objects of ``owner``'s query: the setup, its termination condition, and what they
    hold on to. States and motions are refused once the owner's slice is spent. The callbacks hold
    ``owner`` weakly: OMPL holds them, and a query dropped unfinished frees its OMPL objects with it
    (a cycle through C++ would keep them to the end of the process)."""
    owner = weakref.proxy(owner)
    nq = checker.robot.nq
    index = range(nq)
    ou.setLogLevel(ou.LOG_NONE)
    ou.RNG.setSeed(seed)  # before any random OMPL object of the query exists (as ompl_planners.base)
    space = ob.RealVectorStateSpace(nq)
    bounds = ob.RealVectorBounds(nq)
    for i in index:
        bounds.setLow(i, float(checker.robot.lower[i]))
        bounds.setHigh(i, float(checker.robot.upper[i]))
    space.setBounds(bounds)
    space.setLongestValidSegmentFraction(resolution / space.getMaximumExtent())
    in_collision, segments = checker.in_collision, owner.segments

    def my_turn() -> bool:
        """Exact: wait for the slice a check belongs to (no frame of this thread holds the owner
        meanwhile: one dropped is freed, and its search ended); False once the search is stopped."""
        assert pacer is not None
        return pacer.wait_turn(owner.spent)

    def is_valid(state: Any) -> bool:
        if pacer is None:
            return owner.count_state() and not in_collision(np.array([state[i] for i in index]))
        return my_turn() and owner.count_state() and not in_collision(np.array([state[i] for i in index]))

    def motion_free(a: np.ndarray, b: np.ndarray) -> bool:
        """Refused once the slice is spent, as at an obstacle (the connect in progress stops
        there); exact: a configuration at a time, each waiting for its slice."""
        if pacer is None:
            return not owner.refusing and segments.motion_free(a, b)
        return all(my_turn() and segments.first_hit(q[None]) < 0 for q in segments.motion_states(a, b))

    class Motions(ob.MotionValidator):
        def checkMotion(self, s1: Any, s2: Any, *rest: Any) -> bool:  # noqa: N802 (OMPL's name)
            return motion_free(np.array([s1[i] for i in index]), np.array([s2[i] for i in index]))

    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(is_valid)
    si = ss.getSpaceInformation()
    motions = Motions(si)
    si.setMotionValidator(motions)
    a, b = space.allocState(), space.allocState()
    for i in index:
        a[i], b[i] = float(owner.start[i]), float(owner.goal[i])
    ss.setStartAndGoalStates(a, b)
    planner = og.RRTConnect(si)
    planner.setRange(float(extension))
    ss.setPlanner(planner)
    ss.setup()
    stop = ob.PlannerTerminationCondition(lambda: owner.spent)
    return ss, stop, motions, planner, space
