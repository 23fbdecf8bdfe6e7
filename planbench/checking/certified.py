"""Certified path validation: a path segment is accepted only when it is *proven* collision-free.

Sampling a segment every 0.01 rad cannot see an obstacle between two samples. This module uses
distance-based conservative advancement instead (Schwarzer, Saha and Latombe, "Exact collision
checking of robot paths", 2002, and "Adaptive dynamic collision checking for single and multiple
articulated robots in complex environments", IEEE T-RO 21(3), 2005):

- **Motion bound.** On the straight joint-space segment ``q(t) = a + t (b - a)``, a point of a
  collision body can move at most ``sum_i |b_i - a_i| r_i`` (``t`` from 0 to 1), where ``r_i`` is,
  for a revolute joint ``i`` before the body, an upper bound on the distance of the body's points
  from the joint's axis, and 1 for a prismatic joint. planbench bounds ``r_i`` from the model,
  independently of the configuration: the lengths of the joint offsets between joint ``i`` and the
  body's joint (plus prismatic travel) plus the largest distance of the body's vertices from its
  joint's origin. For a pair of bodies the distance changes by at most the sum of the two bodies'
  bounds, counted only over the joints that move one body relative to the other: joints shared by
  both chains move both rigidly and do not count (self-collision pairs use relative motion).
- **Certificate.** If a pair's distance is ``d0`` at ``t0`` and ``d1`` at ``t1`` and its motion bound
  over ``[t0, t1]`` is ``m``, its distance anywhere in between is at least ``(d0 + d1 - m) / 2``.
  When that is at least the required clearance, the pair is free on the interval; otherwise the
  interval is bisected, for that pair only. A pair far from everything certifies a long segment with
  its two end distances; only close pairs pay for bisection.
- **Bounds before exact distances.** Any lower bound of the distance at the ends works in the
  certificate. Each robot mesh (and mesh obstacle) gets its convex hull, which contains it, so the
  hull's distance (coal's GJK, a few microseconds) is a lower bound of the mesh's (coal's BVH
  distance, tens to hundreds of microseconds). Exact distances are computed only where the hull's
  cannot certify.
- **Verdicts do not depend on earlier queries.** Every distance is computed with GJK's default
  initial guess and the cached-guess option off, from a cleared result, so the same configuration
  always gives the same answer whatever was checked before it.
- **Conservative at the limit.** Every computed distance is lowered by ``distance_accuracy`` (GJK's
  tolerance) before it enters a certificate. An interval whose motion bound falls below
  ``resolution`` without a certificate is a contact within a few micrometres: it is reported as a
  collision ("not provably free"), never accepted. So is a path that needs more than
  ``max_queries`` distance queries.

Clearance along the path is reported twice: ``clearance_lower``, a certified lower bound of the
smallest robot-obstacle distance over the whole path, and ``clearance_found``, the smallest exact
distance computed (the true minimum is between them). The bound is refined, branch and bound over
the pairs' intervals, until the two are within ``clearance_gap``.
"""

from __future__ import annotations

import heapq
import math
import weakref
from dataclasses import dataclass
from typing import Any

import coal
import numpy as np
import pinocchio as pin

from planbench.checking.cloud_pairs import cloud_pairs
from planbench.checking.collision import CollisionChecker, fresh_geometry_data
from planbench.robot import link_of

__all__ = ["CertifiedChecker", "CertificationSettings", "PathVerdict"]

CUM_TABLE_FLOATS = 2**22
"""Largest table of motion-bound prefix sums (pairs x waypoints, 32 MiB) a path keeps for all its
pairs at once; a longer path computes a pair's row when the search needs it."""

_CHECKERS: weakref.WeakKeyDictionary[Any, dict[Any, CertifiedChecker]] = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class CertificationSettings:
    """How paths are certified. Lengths in m."""

    required_clearance: float = 0.0
    """Smallest distance [m] allowed between the robot and an obstacle or itself along a path, on
    top of ``distance_accuracy``: with 0, a configuration closer than that (touching included) is a
    collision. Negative values tolerate shallow penetration."""
    distance_accuracy: float = 1e-6
    """Subtracted from every computed distance [m] before it certifies anything (GJK's tolerance)."""
    resolution: float = 1e-6
    """Smallest motion bound [m] an interval is bisected to; below it, a pair that is still not
    certified is reported as a collision (a contact within micrometres cannot be proven free)."""
    clearance_gap: float = 1e-3
    """The certified lower bound of the path's clearance is refined until it is within this [m] of
    the smallest distance found (or ``max_clearance_queries`` is spent)."""
    max_queries: int = 500_000
    """Distance queries one path may take before it is refused as not certifiable."""
    max_clearance_queries: int = 2_000
    """Extra distance queries spent on tightening the clearance bound (never on the verdict)."""
    measure_clearance: bool = True
    """Bracket a free path's clearance (``clearance_lower``, ``clearance_found``); False gives the
    verdict alone, with NaN clearances (a planner checking its own motions needs no more)."""

    def __post_init__(self) -> None:
        for name in ("required_clearance", "distance_accuracy", "resolution", "clearance_gap"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite [m], got {v}")
        if self.distance_accuracy < 0 or self.resolution <= 0 or self.clearance_gap <= 0:
            raise ValueError("distance_accuracy must be >= 0, resolution and clearance_gap > 0 [m]")
        if self.max_queries < 1 or self.max_clearance_queries < 0:
            raise ValueError("max_queries must be >= 1 and max_clearance_queries >= 0")


@dataclass(frozen=True)
class PathVerdict:
    """The certified checker's answer for one path.

    ``free``: every segment is proven free. Otherwise ``segment`` is the first segment with a
    collision, ``fraction`` where along it (0 at its first waypoint, 1 at its last) the collision
    begins (to within ``resolution`` of motion), ``pair`` the two bodies (robot link, link or
    ``obstacle:<name>``), ``depth`` [m] the deepest penetration of that pair the search met (0 for a
    contact that could not be proven free) and ``reason`` a sentence. Clearances [m] are over
    robot-obstacle pairs along the whole path of a free one (NaN when not measured, see
    ``measure_clearance``; for a collision, ``clearance_found`` is minus the depth); ``inf`` without
    obstacles.
    """

    free: bool
    segment: int = -1
    fraction: float = math.nan
    pair: tuple[str, str] = ("", "")
    depth: float = math.nan
    reason: str = ""
    clearance_lower: float = math.nan
    clearance_found: float = math.nan
    queries: int = 0
    exact_queries: int = 0
    configurations: int = 0

    def describe(self) -> str:
        if self.free:
            return "free"
        return (
            f"collision on segment {self.segment} at {self.fraction:.4f} of its length: "
            f"{self.pair[0]} with {self.pair[1]}, {self.reason}"
        )


class _Budget(Exception):
    """Raised inside the search when ``max_queries`` is spent."""


class _Sample:
    """One configuration along the path (at path parameter ``u``) and the distances known there."""

    __slots__ = ("u", "q", "key", "bound", "exact")

    def __init__(self, u: float, q: np.ndarray, key: int) -> None:
        self.u = u
        self.q = q
        self.key = key  # which configuration the geometry data were last placed at
        self.bound: dict[int, float] = {}  # pair -> a lower bound of its distance (hull or exact)
        self.exact: dict[int, float] = {}  # pair -> exact signed distance (coal)


class CertifiedChecker:
    """Certified collision checking of joint-space paths for one robot in one scene.

    Built from the same pinocchio ``GeometryModel`` as :class:`planbench.checking.collision.CollisionChecker`
    (robot self-collision pairs, SRDF and ignore list removed, plus every robot / obstacle pair), so
    "free" means free for the geometry that ``in_collision`` checks. Not thread-safe (own buffers).

    A path is parameterised by ``u`` in ``[0, N - 1]``: waypoint ``i`` at ``u = i``, linear in
    between. Each pair is certified over the whole path at once, bisecting where its certificate
    fails (at waypoints first, then inside segments), so a pair far from everything costs two
    distance queries however many waypoints the path has.
    """

    def __init__(self, robot: Any, scene: Any, settings: CertificationSettings | None = None) -> None:
        self.settings = settings or CertificationSettings()
        self.robot = robot
        base = CollisionChecker(robot, scene)
        self.geometry_model = base.geometry_model
        self.n_robot_geoms = base.n_robot_geoms
        self._pin = pin
        self._model = robot.model
        self._data = robot.model.createData()
        self._exact_data = fresh_geometry_data(self.geometry_model)
        self._hull_model, has_hull = _hull_model(self.geometry_model)
        self._hull_data = fresh_geometry_data(self._hull_model)
        pairs = self.geometry_model.collisionPairs
        self.n_pairs = len(pairs)
        self._pairs = [(int(p.first), int(p.second)) for p in pairs]
        # point-cloud pairs: a bounding-sphere bound and a collide-then-surface distance instead of
        # coal's octree distances (planbench.checking.cloud_pairs); pinocchio's batch call skips them
        self._clouds = cloud_pairs(self.geometry_model, self._pairs, scene, self.n_robot_geoms)
        for k in self._clouds:
            self._hull_data.deactivateCollisionPair(k)
        # a pair of two primitives: its "hull" distance is exact, no second query
        self._hull_is_exact = [
            not (has_hull[a] or has_hull[b]) and k not in self._clouds for k, (a, b) in enumerate(self._pairs)
        ]
        self._obstacle_pair = [a >= self.n_robot_geoms or b >= self.n_robot_geoms for a, b in self._pairs]
        self.motion_weights = _motion_weights(robot, self.geometry_model, self.n_robot_geoms, self._pairs)
        self.pair_margin = [0.0] * self.n_pairs
        """Clearance [m] each pair needs on top of ``required_clearance``: the reactive benchmark
        widens a moving obstacle by the distance it may travel during a tick
        (:mod:`planbench.reactive.checker`); 0 for every pair otherwise."""
        names = [o.name for o in self.geometry_model.geometryObjects]
        self._pair_names = [(_display(names[a]), _display(names[b])) for a, b in self._pairs]
        self._placed = {"hull": -1, "exact": -1}
        self._deepest: dict[int, float] = {}  # pair -> deepest penetration seen [m]
        self._found = math.inf
        self._keys = 0
        self.queries = 0
        self.exact_queries = 0
        self._limit = math.inf

    @classmethod
    def for_problem(cls, problem: Any, settings: CertificationSettings | None = None) -> CertifiedChecker:
        """The checker for a problem's robot and scene, built once per settings and cached on it."""
        settings = settings or CertificationSettings()
        per_problem = _CHECKERS.setdefault(problem, {})
        checker = per_problem.get(settings)
        if checker is None:
            checker = per_problem[settings] = cls(problem.robot, problem.scene, settings)
        return checker

    @staticmethod
    def forget(problem: Any) -> None:
        """Drop the checkers cached for ``problem``: after a check that ran out of memory, whose
        buffers may be half-built, the next one starts from a fresh checker."""
        _CHECKERS.pop(problem, None)

    # -- the scene's geometry ----------------------------------------------------------------------

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        """The checked pairs, ``(first, second)`` geometry indices in :attr:`geometry_model`, in the
        order of :attr:`pair_margin` (and of the verdicts' pair numbers)."""
        return tuple(self._pairs)

    def pairs_with(self, obstacle: str) -> list[int]:
        """Indices of the pairs (:attr:`pairs`) that involve the scene's obstacle named ``obstacle``."""
        g = self._obstacle_id(obstacle)
        return [k for k, (a, b) in enumerate(self._pairs) if g in (a, b)]

    def place_obstacle(self, obstacle: str, placement: Any) -> None:
        """Move the scene's obstacle named ``obstacle`` to ``placement`` (a pinocchio ``SE3``, base
        frame) in the exact and the hull geometry alike: for obstacles that move between checks
        (:mod:`planbench.reactive.checker`)."""
        g = self._obstacle_id(obstacle)
        self.geometry_model.geometryObjects[g].placement = placement
        self._hull_model.geometryObjects[g].placement = placement

    def _obstacle_id(self, obstacle: str) -> int:
        name = f"obstacle:{obstacle}"
        if not self.geometry_model.existGeometryName(name):
            raise KeyError(f"no obstacle {obstacle!r} in the checker's scene")
        return int(self.geometry_model.getGeometryId(name))

    # -- distances ---------------------------------------------------------------------------------

    def _new_sample(self, u: float, q: np.ndarray) -> _Sample:
        self._keys += 1
        return _Sample(u, q, self._keys)

    def _spend(self) -> None:
        self.queries += 1
        if self.queries > self._limit:
            raise _Budget

    def _query(self, which: str, s: _Sample, k: int) -> float:
        """Pair ``k``'s distance at ``s`` for the hull model or the exact one (placed there first)."""
        gm, gd = (self._hull_model, self._hull_data) if which == "hull" else (self.geometry_model, self._exact_data)
        if self._placed[which] != s.key:
            self._pin.updateGeometryPlacements(self._model, self._data, gm, gd, s.q)
            self._placed[which] = s.key
        self._spend()
        cloud = self._clouds.get(k)
        if cloud is not None:
            return cloud.bound(gd.oMg) if which == "hull" else cloud.exact(gd.oMg)
        return _distance(gm, gd, k)

    def _all_bounds(self, s: _Sample) -> None:
        """Hull distances of every pair at ``s`` in one pinocchio call."""
        self._pin.computeDistances(self._model, self._data, self._hull_model, self._hull_data, s.q)
        self._placed["hull"] = s.key
        results = self._hull_data.distanceResults
        for k in range(self.n_pairs):
            if k not in s.bound:
                self._spend()
                cloud = self._clouds.get(k)
                d = s.bound[k] = cloud.bound(self._hull_data.oMg) if cloud else float(results[k].min_distance)
                if self._hull_is_exact[k]:
                    self._note_exact(s, k, d)

    def _bound(self, s: _Sample, k: int) -> float:
        """A lower bound of pair ``k``'s distance at ``s``: exact when known, else the hulls'."""
        d = s.exact.get(k)
        if d is not None:
            return d
        d = s.bound.get(k)
        if d is None:
            d = s.bound[k] = self._query("hull", s, k)
            if self._hull_is_exact[k]:
                self._note_exact(s, k, d)
        return d

    def _exact(self, s: _Sample, k: int) -> float:
        d = s.exact.get(k)
        if d is None:
            self.exact_queries += 1
            d = self._query("exact", s, k)
            self._note_exact(s, k, d)
        return d

    def _note_exact(self, s: _Sample, k: int, d: float) -> None:
        """Keep pair ``k``'s exact distance at ``s``, the smallest robot-obstacle one found and each
        pair's deepest penetration."""
        s.exact[k] = d
        if d < self._found and self._obstacle_pair[k]:
            self._found = d
        if d < 0:
            self._deepest[k] = max(self._deepest.get(k, 0.0), -d)

    # -- paths -------------------------------------------------------------------------------------

    def check_path(self, path: np.ndarray) -> PathVerdict:
        """Certify ``path`` (an (N, nq) array; straight joint-space segments between rows)."""
        path = np.ascontiguousarray(path, dtype=float)
        if path.ndim != 2 or path.shape[1] != self.robot.nq or len(path) == 0 or not np.isfinite(path).all():
            raise ValueError(f"path must be a finite (N, {self.robot.nq}) array with N >= 1, got shape {path.shape}")
        self.queries = self.exact_queries = 0
        self._limit = self.settings.max_queries
        self._path = path
        self._delta = np.diff(path, axis=0)
        # per pair (rows), the motion bound from the path's start to each waypoint [m]: the bound is
        # linear in |dq|, so it is the weights times each joint's prefix sum of |dq|
        joint_travel = np.zeros((path.shape[1], len(path)))
        np.cumsum(np.abs(self._delta).T, axis=1, out=joint_travel[:, 1:])
        self._travel = joint_travel
        # every pair's row at once while the table is small; a long path's rows one at a time, so
        # memory grows with the waypoints, not with waypoints x pairs
        small = self.n_pairs * len(path) <= CUM_TABLE_FLOATS
        self._cum = self.motion_weights @ joint_travel if small else None
        # each pair's bound over the whole path
        self._total = self._cum[:, -1] if self._cum is not None else self.motion_weights @ joint_travel[:, -1]
        self._cum_lists: dict[int, list[float]] = {}
        self._samples: dict[float, _Sample] = {}
        self._deepest = {}
        self._found = math.inf  # smallest exact robot-obstacle distance computed [m]
        self._leaves: list[tuple[float, int, int, _Sample, _Sample]] = []
        self._tiebreak = 0
        try:
            return self._check()
        except _Budget:
            return PathVerdict(
                False,
                reason=f"not certified within {self.settings.max_queries} distance queries (a path that "
                "stays in near-contact for long is refused rather than guessed)",
                queries=self.queries,
                exact_queries=self.exact_queries,
                configurations=len(self._samples),
            )

    def check_segment(self, a: np.ndarray, b: np.ndarray) -> PathVerdict:
        """Certify the straight segment ``a -> b`` (see :meth:`check_path`)."""
        return self.check_path(np.stack([np.asarray(a, dtype=float), np.asarray(b, dtype=float)]))

    def _sample(self, u: float) -> _Sample:
        s = self._samples.get(u)
        if s is None:
            i = int(u)
            if u == i:
                q = self._path[i]
            else:
                q = self._path[i] + (u - i) * self._delta[i]
            s = self._samples[u] = self._new_sample(u, q)
        return s

    def _motion(self, k: int, u0: float, u1: float) -> float:
        """Pair ``k``'s motion bound [m] along the path from ``u0`` to ``u1``."""
        if self._cum is None:  # a long path: the joints' travel between u0 and u1, weighted
            return float(self.motion_weights[k] @ (_cum_at(self._travel.T, u1) - _cum_at(self._travel.T, u0)))
        return _cum_at(self._cum_list(k), u1) - _cum_at(self._cum_list(k), u0)

    def _cum_list(self, k: int) -> Any:
        """Pair ``k``'s prefix sums of motion bounds: a list for short paths (fastest scalar access
        in the search), an array row for long ones (converting thousands of waypoints per pair
        costs more than the search reads), computed afresh when the table is not kept."""
        if self._cum is None:
            return self.motion_weights[k] @ self._travel
        if self._cum.shape[1] > 256:
            return self._cum[k]
        cum = self._cum_lists.get(k)
        if cum is None:
            cum = self._cum_lists[k] = self._cum[k].tolist()
        return cum

    @staticmethod
    def _split(u0: float, u1: float) -> float:
        """Where to bisect ``[u0, u1]``: the waypoint nearest its middle when one lies strictly
        inside, else the middle."""
        mid = 0.5 * (u0 + u1)
        lo, hi = math.floor(u0) + 1, math.ceil(u1) - 1
        if lo <= hi:
            return float(min(max(round(mid), lo), hi))
        return mid

    def _check(self) -> PathVerdict:
        cfg = self.settings
        last = float(len(self._path) - 1)
        hit: tuple[float, int, float] | None = None  # (u, pair, depth) of the earliest collision
        for u in {0.0, last}:  # every pair starts from both ends: one pinocchio call each
            self._all_bounds(self._sample(u))
        for k in range(self.n_pairs):
            found = self._first_collision(k, last, hit[0] if hit else math.inf)
            if found is not None and (hit is None or found[0] < hit[0]):
                hit = found
        if hit is None:
            lower, found_min = self._clearance() if cfg.measure_clearance else (math.nan, math.nan)
            return PathVerdict(
                True,
                clearance_lower=lower,
                clearance_found=found_min,
                queries=self.queries,
                exact_queries=self.exact_queries,
                configurations=len(self._samples),
            )
        u, k, depth = hit
        seg = min(int(u), len(self._path) - 2) if len(self._path) > 1 else 0
        reason = (
            f"penetrating (deepest point found: {depth * 1000:.3f} mm)"
            if depth > 0
            else f"closer than {cfg.required_clearance * 1000:g} mm and not provably free at micrometre scale"
        )
        return PathVerdict(
            False,
            segment=seg,
            fraction=float(u - seg),
            pair=self._pair_names[k],
            depth=float(depth),
            reason=reason,
            clearance_found=-float(depth) if self._obstacle_pair[k] else math.nan,
            queries=self.queries,
            exact_queries=self.exact_queries,
            configurations=len(self._samples),
        )

    def _first_collision(self, k: int, last: float, stop: float) -> tuple[float, int, float] | None:
        """The earliest ``u < stop`` where pair ``k`` is closer than the required clearance, as
        (u, pair, depth), or None when the pair is certified up to ``stop``. Depth-first, earliest
        interval first: everything before the interval at hand is already certified."""
        cfg = self.settings
        floor, acc = cfg.required_clearance + self.pair_margin[k], cfg.distance_accuracy
        start = self._sample(0.0)
        if self._bound(start, k) - acc < floor and self._exact(start, k) - acc < floor:
            return 0.0, k, max(0.0, -start.exact[k])
        if last == 0.0:
            return None
        # The hot loop of certification (a pair in near-contact takes thousands of intervals): the
        # interval's end samples and their bounds travel on the stack, the motion bound comes from
        # the pair's prefix sums, and only a new midpoint costs a distance query.
        resolution = cfg.resolution
        obstacle_pair = self._obstacle_pair[k]
        end = self._sample(last)
        # A certificate: both ends and the interval's lower bound (d0 + d1 - m) / 2 at least the
        # required clearance plus the distance accuracy. The ends are checked on their own too, so
        # a waypoint is judged the same whether it ends a segment or lies inside a path.
        need = floor + acc
        d0, d1, m = self._bound(start, k), self._bound(end, k), float(self._total[k])
        if d0 >= need and d1 >= need and d0 + d1 - m >= 2 * need:  # most pairs: the whole path at once
            if obstacle_pair:
                self._leaf(k, start, end, d0, d1, m)
            return None
        cum = self._cum_list(k)
        stack = [(0.0, last, start, end, d0, d1)]
        while stack:
            u0, u1, s0, s1, d0, d1 = stack.pop()
            if u0 >= stop:
                continue
            # an end's exact distance may have been computed since this interval was pushed (by its
            # neighbour): use it, not the bound that travelled on the stack
            d0, d1 = s0.exact.get(k, d0), s1.exact.get(k, d1)
            m = _cum_at(cum, u1) - _cum_at(cum, u0)
            if d0 >= need and d1 >= need and d0 + d1 - m >= 2 * need:
                if obstacle_pair:
                    self._leaf(k, s0, s1, d0, d1, m)
                continue
            if (k not in s0.exact or k not in s1.exact) and (min(d0, d1) < need or m <= resolution):
                # an end inside a hull (or at micrometre scale): bisecting on hull bounds cannot
                # certify, the exact distances may (hulls far below their mesh are rare: measured,
                # exact distances on every failed interval made MBM paths slower, not faster)
                d0, d1 = self._exact(s0, k), self._exact(s1, k)
                if d0 >= need and d1 >= need and d0 + d1 - m >= 2 * need:
                    if obstacle_pair:
                        self._leaf(k, s0, s1, d0, d1, m)
                    continue
            if m <= resolution:
                # the collision starts within the resolution before u1 (or, when u1 is free, a
                # contact that cannot be proven free); depth: the deepest point the search saw
                return (u1 if d1 < need else u0), k, max(0.0, -d1, self._deepest.get(k, 0.0))
            um = self._split(u0, u1)
            sm = self._sample(um)
            dm = self._bound(sm, k)
            stack.append((um, u1, sm, s1, dm, d1))
            stack.append((u0, um, s0, sm, d0, dm))  # popped first: earliest interval first
        return None

    # -- clearance ---------------------------------------------------------------------------------

    def clearance(self, q: np.ndarray) -> float:
        """Smallest robot-obstacle distance [m] at ``q`` (negative when penetrating, ``inf`` without
        obstacles): hull distances of every pair first, exact distances only for the pairs whose
        hull distance is below the smallest exact one found."""
        self._limit = math.inf
        s = self._new_sample(-1.0, np.ascontiguousarray(q, dtype=float))
        return self._clearance_at(s)

    def _clearance_at(self, s: _Sample) -> float:
        self._all_bounds(s)
        order = sorted((s.bound[k], k) for k in range(self.n_pairs) if self._obstacle_pair[k])
        best = math.inf
        for bound, k in order:
            if bound >= best:
                break
            best = min(best, self._exact(s, k))
        return best

    def _leaf(self, k: int, s0: _Sample, s1: _Sample, d0: float, d1: float, m: float) -> None:
        """Remember a certified interval of an obstacle pair for the clearance refinement."""
        self._tiebreak += 1
        heapq.heappush(self._leaves, (min(d0, d1, (d0 + d1 - m) / 2), self._tiebreak, k, s0, s1))

    def _clearance(self) -> tuple[float, float]:
        """(certified lower bound, smallest exact distance found) of the robot-obstacle distance
        along the whole path, the bound tightened by branch and bound over the certified intervals
        (the interval with the smallest bound is refined first) until the two are ``clearance_gap``
        apart or ``max_clearance_queries`` is spent."""
        heap = self._leaves
        if not any(self._obstacle_pair):
            return math.inf, math.inf
        self._limit = math.inf  # clearance queries never change the verdict
        cfg = self.settings
        found = self._found  # the smallest exact robot-obstacle distance computed so far
        budget = self.queries + cfg.max_clearance_queries
        while heap and self.queries < budget:
            lower, _, k, s0, s1 = heap[0]
            if found - lower <= cfg.clearance_gap:
                break
            heapq.heappop(heap)
            m = self._motion(k, s0.u, s1.u)
            if m > cfg.clearance_gap or (k in s0.exact and k in s1.exact):
                if m <= cfg.resolution:
                    heapq.heappush(heap, (lower, 0, k, s0, s1))
                    break
                um = self._split(s0.u, s1.u)
                sm = self._sample(um)
                for a, b in ((s0, sm), (sm, s1)):
                    da, db, mm = self._bound(a, k), self._bound(b, k), self._motion(k, a.u, b.u)
                    found = min(found, a.exact.get(k, math.inf), b.exact.get(k, math.inf))
                    self._tiebreak += 1
                    heapq.heappush(heap, (max(lower, min(da, db, (da + db - mm) / 2)), self._tiebreak, k, a, b))
            else:  # a short interval: the exact distance at its closer end (only exact ones are "found")
                near_start = k not in s0.exact and (k in s1.exact or self._bound(s0, k) <= self._bound(s1, k))
                found = min(found, self._exact(s0 if near_start else s1, k))
                d0, d1 = self._bound(s0, k), self._bound(s1, k)
                self._tiebreak += 1
                heapq.heappush(heap, (max(lower, min(d0, d1, (d0 + d1 - m) / 2)), self._tiebreak, k, s0, s1))
        if not heap:  # a path of one configuration
            d = self._clearance_at(self._sample(0.0))
            return d, d
        lower, _, k, s0, s1 = heap[0]
        if not math.isfinite(found):
            found = min(self._exact(s0, k), self._exact(s1, k))
        return float(min(lower, found)), float(found)


def _cum_at(cum: Any, u: float) -> Any:
    """A piecewise-linear prefix sum at path parameter ``u`` (``cum`` a list or an array row: a
    float; rows of prefix sums, one per waypoint: a vector)."""
    i = int(u)
    a = cum[i]
    if u != i:
        a = a + (u - i) * (cum[i + 1] - a)
    return a if isinstance(a, np.ndarray) else float(a)


def _distance(gm: Any, gd: Any, k: int) -> float:
    gd.distanceResults[k].clear()
    pin.computeDistance(gm, gd, k)
    return float(gd.distanceResults[k].min_distance)


def _hull_model(gm: Any) -> tuple[Any, list[bool]]:
    """A copy of ``gm`` with every mesh replaced by its convex hull (which contains it), and which
    geometries were replaced."""
    hulls = pin.GeometryModel(gm)
    replaced = []
    for i, obj in enumerate(gm.geometryObjects):
        geom = obj.geometry
        hull = None
        if isinstance(geom, coal.BVHModelBase) and geom.num_vertices >= 4:
            try:
                mesh = geom.clone()
                mesh.buildConvexHull(False, "Qt")
                hull = mesh.convex
            except (RuntimeError, ValueError):  # a flat or degenerate mesh: its own distance is the bound
                hull = None
        if hull is not None:
            hulls.geometryObjects[i].geometry = hull
        replaced.append(hull is not None)
    return hulls, replaced


def _body_points(obj: Any) -> np.ndarray:
    """Points whose convex hull contains a geometry, in its parent joint's frame: a mesh's
    vertices, else the corners of the geometry's local bounding box."""
    geom = obj.geometry
    R, t = np.asarray(obj.placement.rotation), np.asarray(obj.placement.translation)
    if isinstance(geom, coal.BVHModelBase) and geom.num_vertices > 0:
        pts = np.asarray(geom.vertices())
    else:
        geom.computeLocalAABB()
        lo, hi = np.asarray(geom.aabb_local.min_), np.asarray(geom.aabb_local.max_)
        pts = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return np.asarray(pts @ R.T + t)


def _axis(joint_model: Any) -> np.ndarray | None:
    """The unit rotation axis of a revolute joint in its own frame (None when unknown)."""
    short = joint_model.shortname()
    if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return np.eye(3)["XYZ".index(short[-1])]
    try:
        axis = np.asarray(joint_model.extract().axis, dtype=float)
    except AttributeError:
        return None
    return axis / np.linalg.norm(axis)


def _axis_distance(points: np.ndarray, axis: np.ndarray | None) -> float:
    """Largest distance of ``points`` from the line through the origin along ``axis`` (from the
    origin itself when the axis is unknown)."""
    pts = np.atleast_2d(points)
    if axis is None:
        return float(np.linalg.norm(pts, axis=1).max())
    return float(np.linalg.norm(pts - np.outer(pts @ axis, axis), axis=1).max())


def _chain(model: Any, joint: int) -> list[int]:
    """Joints from ``joint`` up to the root (the universe, 0, excluded)."""
    out = []
    while joint > 0:
        out.append(joint)
        joint = model.parents[joint]
    return out


def _motion_weights(robot: Any, gm: Any, n_robot: int, pairs: list[tuple[int, int]]) -> np.ndarray:
    """(pairs, nq) matrix ``W``: pair ``k``'s distance changes by at most ``W[k] @ |dq|`` [m] for a
    straight joint-space motion ``dq`` (module docstring).

    For a body on joint ``j`` and a revolute joint ``i`` before it, with ``c`` the next joint after
    ``i`` towards the body: every point ``x`` of the body is within ``dist(o_c, axis_i) + |x - o_c|``
    of joint ``i``'s axis, where ``o_c``'s place in joint ``i``'s frame is fixed by the model (plus the
    travel of ``c`` when it is prismatic) and ``|x - o_c|`` is bounded by the offsets from ``c`` to
    ``j`` plus the body's extent. For ``i = j`` the distance of the body's points from the axis is
    exact. A prismatic joint moves every point after it by exactly its own motion."""
    model = robot.model
    nq = robot.nq
    kinds = {}
    for j in range(1, model.njoints):
        short = model.joints[j].shortname()
        if short.startswith("JointModelR"):
            kinds[j] = "revolute"
        elif short.startswith("JointModelP"):
            kinds[j] = "prismatic"
        else:  # the robot loader only admits 1-dof joints; say so if that ever changes
            raise ValueError(f"certified checking supports revolute and prismatic joints, not {short}")
    axes = {j: _axis(model.joints[j]) for j in kinds if kinds[j] == "revolute"}
    travel = {j: 0.0 for j in kinds}
    for j in kinds:
        if kinds[j] == "prismatic":
            i = model.joints[j].idx_q
            travel[j] = float(max(abs(robot.lower[i]), abs(robot.upper[i])))

    def body_weights(g: int) -> dict[int, float]:
        obj = gm.geometryObjects[g]
        chain = _chain(model, int(obj.parentJoint))
        if not chain:  # fixed to the world: never moves
            return {}
        points = _body_points(obj)
        out: dict[int, float] = {}
        reach = float(np.linalg.norm(points, axis=1).max())  # from the origin of the current joint
        for pos, i in enumerate(chain):
            if pos == 0:
                w = _axis_distance(points, axes.get(i))
            else:
                c = chain[pos - 1]
                t_c = np.asarray(model.jointPlacements[c].translation)
                w = _axis_distance(t_c, axes.get(i)) + travel[c] + reach
                reach += float(np.linalg.norm(t_c)) + travel[c]
            out[i] = 1.0 if kinds[i] == "prismatic" else w
        return out

    weights = {i: body_weights(i) for i in {i for pair in pairs for i in pair if i < n_robot}}
    W = np.zeros((len(pairs), nq))
    for k, (a, b) in enumerate(pairs):
        wa, wb = weights.get(a, {}), weights.get(b, {})
        for j in set(wa) ^ set(wb):  # shared joints move both bodies rigidly
            W[k, model.joints[j].idx_q] = wa.get(j, 0.0) + wb.get(j, 0.0)
    return W


def _display(geometry_name: str) -> str:
    return geometry_name if geometry_name.startswith("obstacle:") else link_of(geometry_name)
