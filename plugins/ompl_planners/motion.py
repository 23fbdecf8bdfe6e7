"""Motion validation for OMPL's search and simplifier: sampled, optionally certified.

A segment ``a -> b`` is checked at ``a + (j / n) (b - a)``, ``j = 1 .. n``, with
``n = ceil(max_i |b_i - a_i| / resolution)`` (:func:`planbench.metrics.densify`; ``resolution``
0.01 rad by default): no joint moves more than ``resolution`` between checked configurations. This
is fast, but blind between samples. :class:`CertifiedSegments` adds the harness's certified check
(:func:`planbench.validate.verdict_checker`, the harness's checker without the clearance
refinement) for the motions that pass the sampled check, and remembers each certified segment; the
validator from :func:`make_motion_validator` uses it while its ``certify`` flag is set (see
``motion_check`` / ``simplify_check`` and the repair of failing segments in :mod:`.base`).
OMPL's own ``DiscreteMotionValidator`` checks at points a Euclidean distance
apart instead.

The configurations of one motion go to pinocchio in one batch (``computeCollisionsInParallel`` on a
one-thread broadphase pool, the same dynamic AABB tree and geometry as
:meth:`planbench.checking.collision.CollisionChecker.in_collision`), in bisection order (the end state first,
then midpoints of ever smaller intervals, as OMPL's validator does), stopping at the first collision:
one call from Python per motion instead of one per configuration.

Threads: OMPL's PRM checks motions from a second thread too. The pinocchio call holds the GIL for
the whole batch (checked: no other Python thread runs meanwhile), so the one pool is never used by
two threads at once. OMPL 2.0.1's Python ``MotionValidator`` forwards the ``checkMotion`` overload
that reports the last valid state to the plain one without filling it in: planners that keep the
valid part of a blocked motion (KPIECE1, LBKPIECE1) then drop it, as with any Python validator there.
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import Any

import numpy as np
import pinocchio as pin
from ompl import base as ob

from planbench.checking.certified import CertifiedChecker, PathVerdict
from planbench.checking.collision import CollisionChecker

__all__ = ["CertifiedSegments", "SegmentChecker", "bisection_order", "make_motion_validator"]


def bisection_order(n: int) -> np.ndarray:
    """Indices ``0 .. n-1`` of a segment's ``n`` check points (point ``n - 1`` is the end state),
    end state first, then the midpoints of ever smaller intervals (breadth first)."""
    order = [n - 1]
    queue = deque([(-1, n - 1)])  # points strictly between two checked ones (-1: the segment's start)
    while queue:
        lo, hi = queue.popleft()
        if hi - lo < 2:
            continue
        mid = (lo + hi) // 2
        order.append(mid)
        queue.append((lo, mid))
        queue.append((mid, hi))
    return np.array(order, dtype=np.intp)


class SegmentChecker:
    """Collision checks of whole motions and paths at the harness's check points (module docstring).

    ``n_checks`` counts the configurations actually checked (a batch stops at its first collision).
    """

    def __init__(self, checker: CollisionChecker, resolution: float, pooled: bool = True) -> None:
        """``pooled``: check a motion's configurations in one call of pinocchio's batch collision
        check, on a pool of the checker's geometry built here (a copy of every obstacle: 6-12 ms
        with a frame's octrees, in one piece); False: one :meth:`CollisionChecker.in_collision`
        per configuration (the same broadphase and verdicts, nothing built), for control loops
        whose every tick must stay short."""
        self.checker = checker
        self.resolution = float(resolution)
        self._pin = pin
        self._pool = (
            pin.BroadPhaseManagerPool_DynamicAABBTreeCollisionManager(checker.robot.model, checker.geometry_model, 1)
            if pooled
            else None
        )
        self._orders: dict[int, np.ndarray] = {}
        self.n_checks = 0
        self.n_motions = 0

    def _order(self, n: int) -> np.ndarray:
        order = self._orders.get(n)
        if order is None:
            order = self._orders[n] = bisection_order(n)
        return order

    def first_hit(self, states: np.ndarray) -> int:
        """Index (in ``states``' order) of the first colliding configuration, or -1; checks in order."""
        if self._pool is None:
            for k, q in enumerate(states):
                if self.checker.in_collision(q):
                    self.n_checks += k + 1
                    return k
            self.n_checks += len(states)
            return -1
        hits = self._pin.computeCollisionsInParallel(1, self._pool, np.asfortranarray(states.T), True, True)
        k = int(np.argmax(hits)) if len(hits) else 0
        if len(hits) and hits[k]:
            self.n_checks += k + 1
            return k
        self.n_checks += len(states)
        return -1

    def motion_states(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The harness's check points of the segment ``a -> b`` (``a`` itself excluded), in the
        order they are checked (:func:`bisection_order`)."""
        # the same operations as planbench.metrics.densify on the path [a, b]
        d = b - a
        n = max(1, math.ceil(float(np.abs(d).max()) / self.resolution - 1e-12))
        s = (np.arange(1, n + 1) / n)[:, None]
        return (a + s * d)[self._order(n)]

    def motion_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when every harness check point of the segment ``a -> b`` (``a`` itself excluded) is
        collision-free."""
        self.n_motions += 1
        return self.first_hit(self.motion_states(a, b)) < 0


class CertifiedSegments:
    """Certified checks of single segments, remembered: ``free(a, b)`` runs the sampled check of
    ``segments`` first (a fast rejection of most blocked motions) and certifies only the motions
    that pass it. Every certified-free segment is kept (by its two end configurations' bytes), so
    the same motion is never certified twice (:meth:`known_free`). A returned path is still
    certified whole, as the harness does: segments certified apart can disagree with the whole-path
    check about a contact within micrometres."""

    def __init__(self, segments: SegmentChecker, certified: CertifiedChecker) -> None:
        self.segments = segments
        self.certified = certified
        self._free: set[tuple[bytes, bytes]] = set()
        self.n_certified = 0  # certified checks (segments that passed the sampled check, paths, points)
        self.n_rejected = 0  # of those, not free
        self.queries = 0  # distance queries spent
        self.time = 0.0  # [s] spent certifying

    def reset(self) -> None:
        self._free.clear()
        self.n_certified = self.n_rejected = self.queries = 0
        self.time = 0.0

    def free(self, a: np.ndarray, b: np.ndarray) -> bool:
        if not self.segments.motion_free(a, b):
            return False
        key = (a.tobytes(), b.tobytes())
        if key in self._free:
            return True
        verdict = self.check(np.stack([a, b]))
        if verdict.free:
            self._free.add(key)
        return verdict.free

    def check(self, path: np.ndarray) -> PathVerdict:
        """The certified verdict of ``path`` (counted); its segments are remembered when it is free."""

        t0 = time.perf_counter()
        verdict = self.certified.check_path(path)
        self.time += time.perf_counter() - t0
        self.queries += verdict.queries
        self.n_certified += 1
        if verdict.free:
            self._free.update((path[i].tobytes(), path[i + 1].tobytes()) for i in range(len(path) - 1))
        else:
            self.n_rejected += 1
        return verdict

    def known_free(self, path: np.ndarray, i: int) -> bool:
        """Segment ``i`` of ``path`` was certified free before."""
        return (path[i].tobytes(), path[i + 1].tobytes()) in self._free


def make_motion_validator(
    si: Any, segments: SegmentChecker, nq: int, certified: CertifiedSegments | None = None
) -> Any:
    """An OMPL ``MotionValidator`` (Python subclass) that checks motions with ``segments``, and
    certifies those that pass while its ``certify`` attribute is true (``certified`` given)."""

    index = range(nq)

    class _HarnessMotionValidator(ob.MotionValidator):
        certify = False

        def checkMotion(self, s1: Any, s2: Any, *rest: Any) -> bool:  # noqa: N802 (OMPL's name)
            a = np.array([s1[i] for i in index])
            b = np.array([s2[i] for i in index])
            if self.certify and certified is not None:
                return certified.free(a, b)
            return segments.motion_free(a, b)

    return _HarnessMotionValidator(si)
