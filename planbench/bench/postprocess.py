"""The path post-processing stage: one shortening step applied alike to every planner's validated path.

Planners differ in what they do to their own paths before returning them (OMPL's planners run
OMPL's ``PathSimplifier`` inside their planning time; the field planners return every IK step), so
raw path lengths compare the planners' post-processing as much as their search. A suite that sets
``postprocess = "shortcut"`` hands every successful run's path, after the harness validated it,
to the same stage here, on the harness's side (the validator process, where no planner code ran):

- **shortcut**: random partial shortcutting (Geraerts and Overmars, "Creating high-quality paths for
  motion planning", IJRR 26(8), 2007; Hauser and Ng-Thow-Hing, ICRA 2010): two points drawn
  uniformly along the path's joint-space length (a point within ``snap`` of a waypoint is that
  waypoint) are joined by a straight segment when that is shorter than the path between them by
  more than ``min_gain`` *and* the harness's certified checker proves the segment free
  (:meth:`planbench.checking.certified.CertifiedChecker.check_segment`, the validation's own
  settings; a sampled coal check first refuses, cheaply, the segments that plainly collide).
  ``attempts`` draws from ``numpy.random.default_rng(seed)`` with the run's seed, so the same path
  and seed give the same result; ``time_budget`` only caps a pathological case (a run that meets it
  says so). Every point kept lies on the validated path and every new segment is certified, and the
  processed path is validated again as a whole (:func:`planbench.validate.evaluate`), so it is
  never trusted either.

Then every processed path gets the same time parameterisation the raw metrics use: ``duration``
(straight segments at the velocity limits) and ``duration_limited`` (toppra under velocity and
acceleration limits, :func:`planbench.metrics.limited_duration`). A planner's own time stamps are
not carried over: the processed path is a new path.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError

__all__ = [
    "METHODS",
    "PostprocessSettingError",
    "PostprocessSettings",
    "ShortcutResult",
    "apply",
    "segment_checker",
    "shortcut",
]

METHODS = ("none", "shortcut")
"""The post-processing stages a suite may choose (``none``: raw paths only, the default)."""


class PostprocessSettingError(InvalidConfigError):
    """A post-processing setting that cannot be used; says which values are accepted."""


@dataclass(frozen=True)
class PostprocessSettings:
    """The post-processing stage of a suite (``[suite] postprocess`` and the ``[postprocess]`` table)."""

    method: str = "none"
    """``"none"`` (raw paths only) or ``"shortcut"`` (see the module docstring)."""
    attempts: int = 200
    """Shortcut tries per path [count] (a try draws two points and, when worth it, checks one segment)."""
    time_budget: float = 10.0
    """[s] at most this long per path, a guard only: the stage stops early (and says so) past it,
    which makes that one path depend on the machine's speed."""
    min_gain: float = 1e-4
    """[rad] a shortcut must shorten the joint path by more than this to be checked at all."""
    snap: float = 0.005
    """A drawn point within this fraction of the path's length of a waypoint is that waypoint
    (OMPL's ``shortcutPath`` uses the same 0.005), so shortcuts remove waypoints rather than add them."""
    precheck_resolution: float = 0.05
    """[rad] Before the certified check, the segment's configurations this far apart (largest joint
    motion) are tested for collision with coal (:class:`planbench.checking.collision.CollisionChecker`);
    one in collision refuses the shortcut at once. A refusal only ever loses a shortcut, never admits
    one: only the certified checker accepts. 0: no pre-check. On the tuning part most tries that are
    refused collide outright, and this made the stage several times faster with the same paths
    (docs/benchmarking.md#post-processing)."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise PostprocessSettingError(
                f"postprocess must be one of {', '.join(repr(m) for m in METHODS)}, got {self.method!r}"
            )
        if isinstance(self.attempts, bool) or not isinstance(self.attempts, int) or self.attempts < 0:
            raise PostprocessSettingError(f"postprocess attempts must be an integer >= 0, got {self.attempts!r}")
        for name in ("time_budget", "min_gain", "snap", "precheck_resolution"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise PostprocessSettingError(f"postprocess {name} must be a finite number >= 0, got {v!r}")
        if self.time_budget <= 0:
            raise PostprocessSettingError(f"postprocess time_budget must be > 0 [s], got {self.time_budget!r}")
        if self.snap >= 0.5:
            raise PostprocessSettingError(f"postprocess snap must be < 0.5 (a fraction of the length), got {self.snap}")

    @property
    def active(self) -> bool:
        return self.method != "none"


@dataclass(frozen=True)
class ShortcutResult:
    """A shortened path and how it came about."""

    path: np.ndarray
    attempts: int  # tries made
    shortcuts: int  # shortcuts taken
    checks: int  # segments handed to the checker
    out_of_time: bool  # stopped by the time budget before all attempts
    trace: tuple[tuple[float, float], ...] = ()
    """(time since the start [s], joint path length [rad]) after each try: what fewer attempts
    would have given (the tries are the same, as the draws are)."""


SegmentFree = Callable[[np.ndarray, np.ndarray], bool]


def shortcut(path: np.ndarray, segment_free: SegmentFree, settings: PostprocessSettings, seed: int) -> ShortcutResult:
    """``path`` (N, nq) shortened by random partial shortcuts whose segments ``segment_free`` proves
    free (see the module docstring). Its first and last configurations are kept exactly; it is
    never longer than ``path``."""
    path = _without_repeats(np.asarray(path, dtype=float))
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    taken = checks = 0
    out_of_time = False
    trace: list[tuple[float, float]] = []
    while len(trace) < settings.attempts and len(path) >= 3:
        if time.perf_counter() - t0 > settings.time_budget:
            out_of_time = True
            break
        candidate = _candidate(path, rng, settings)
        if candidate is not None:
            checks += 1
            shorter, q0, q1 = candidate
            if segment_free(q0, q1):
                path = shorter
                taken += 1
        trace.append((time.perf_counter() - t0, _length(path)))
    return ShortcutResult(path, len(trace), taken, checks, out_of_time, tuple(trace))


def _candidate(
    path: np.ndarray, rng: np.random.Generator, settings: PostprocessSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """One try's shortcut (the shorter path and its new segment's ends), or None when the two
    points drawn leave nothing worth checking."""
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    total = cum[-1]
    s0, s1 = np.sort(rng.uniform(0.0, total, 2))
    a0, _, q0 = _point(path, cum, s0, settings.snap * total)
    _, b1, q1 = _point(path, cum, s1, settings.snap * total)
    if b1 - a0 < 2:
        return None  # no waypoint between the two points: the path is straight there already
    shorter = _without_repeats(np.vstack([path[: a0 + 1], q0, q1, path[b1:]]))
    if total - _length(shorter) <= settings.min_gain:  # also: float round-off never lengthens a path
        return None
    return shorter, q0, q1


def _point(path: np.ndarray, cum: np.ndarray, s: float, snap: float) -> tuple[int, int, np.ndarray]:
    """The point at length ``s`` along ``path`` as (the waypoint before it, the one after it, q);
    within ``snap`` of a waypoint it is that waypoint (both indices its own)."""
    k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(path) - 2))
    if s - cum[k] <= snap:
        return k, k, path[k].copy()
    if cum[k + 1] - s <= snap:
        return k + 1, k + 1, path[k + 1].copy()
    u = (s - cum[k]) / (cum[k + 1] - cum[k])
    return k, k + 1, path[k] + u * (path[k + 1] - path[k])


def _length(path: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) > 1 else 0.0


def _without_repeats(path: np.ndarray) -> np.ndarray:
    """``path`` without consecutive repeated waypoints (zero-length segments)."""
    if len(path) < 2:
        return path.copy()
    keep = np.concatenate([[True], np.any(np.diff(path, axis=0) != 0.0, axis=1)])
    return path[keep].copy()


def segment_checker(problem: Any, validation: Any, settings: PostprocessSettings) -> SegmentFree:
    """Whether a straight segment of ``problem`` is free: the harness's certified checker with the
    ``validation`` settings (:class:`planbench.ValidationSettings`) decides, after a sampled coal
    pre-check every ``settings.precheck_resolution`` rad that can only refuse."""
    from planbench.checking.certified import CertifiedChecker
    from planbench.checking.collision import CollisionChecker
    from planbench.metrics import densify

    certified = CertifiedChecker.for_problem(problem, validation.certification(measure_clearance=False))
    sampled = CollisionChecker.for_problem(problem) if settings.precheck_resolution > 0 else None

    def free(a: np.ndarray, b: np.ndarray) -> bool:
        if sampled is not None:
            dense, _ = densify(np.stack([a, b]), settings.precheck_resolution)
            if any(sampled.in_collision(q) for q in dense[1:-1]):
                return False
        return bool(certified.check_segment(a, b).free)

    return free


def apply(problem: Any, result: Any, evaluation: Any, validation: Any, settings: PostprocessSettings, seed: int) -> Any:
    """``evaluation`` (of ``result``, a :class:`planbench.PlanResult`, validated with ``validation``,
    :class:`planbench.ValidationSettings`) with its ``processed_*`` metrics filled in: a successful
    run's path put through the stage ``settings`` with ``seed``, then validated again by
    :func:`planbench.validate.evaluate`. Unchanged where the stage is ``none`` or the run failed;
    a processed path that does not validate (which would be a bug here) is kept out, its failure in
    ``postprocess_note``."""
    if not settings.active or not evaluation.success or result.path is None:
        return evaluation
    from planbench.planner import PlanResult, PlanStatus
    from planbench.validate import evaluate

    t0 = time.perf_counter()
    done = shortcut(result.path, segment_checker(problem, validation, settings), settings, seed)
    spent = time.perf_counter() - t0
    processed = evaluate(problem, PlanResult(PlanStatus.SUCCESS, path=done.path, target=result.target), validation)
    common = {"postprocess_time": spent, "postprocess_shortcuts": done.shortcuts}
    if not processed.success:
        return dataclasses.replace(
            evaluation, **common, postprocess_note=f"processed path refused: {processed.failure}"
        )
    note = (
        f"time budget of {settings.time_budget:g} s reached after {done.attempts} attempts" if done.out_of_time else ""
    )
    return dataclasses.replace(
        evaluation,
        **common,
        processed_n_waypoints=processed.n_waypoints,
        processed_joint_path_length=processed.joint_path_length,
        processed_ee_path_length=processed.ee_path_length,
        processed_min_clearance=processed.min_clearance,
        processed_duration=processed.duration,
        processed_duration_limited=processed.duration_limited,
        postprocess_note=note,
    )
