"""A probabilistic occupancy map on a fixed grid: depth frames fused over time.

Each cell holds the log-odds ``l = log(p / (1 - p))`` that it is occupied, 0 (p = 0.5) before any
evidence. A frame brings two sets of cells: those its rays saw free (nearer to the camera than the
pixel's return, :func:`planbench.geometry.views.mark_seen`) and those holding a returned point
(hits). A hit adds ``logit(hit)``, a cell seen free adds ``logit(miss)`` (negative); a cell both
hit and seen free in one frame counts as a hit only. The sum is clamped to
``[logit(clamp_min), logit(clamp_max)]``, so that a cell that was occupied for a long time turns
free after a bounded number of frames once the rays pass through it again (ray clearing): a
moving obstacle leaves the map as its old cells are seen free, and a static one hidden behind
the arm keeps its evidence while no ray reaches it. A cell is occupied when ``p > occupied``,
known once any frame said anything about it. This is the sensor model of OctoMap (Hornung et al.,
2013), whose defaults these are, on a dense grid instead of an octree: the controllers read
dense grids, and the update is a few vectorised passes over it (docs/sensing.md, "A map over
time", compares the two).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime import backend as _backend

__all__ = ["MapSettings", "OccupancyMap"]


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dataclass(frozen=True)
class MapSettings:
    """The map's sensor model: probabilities in (0, 1)."""

    hit: float = 0.9
    """P(occupied) that one returned point gives its cell (> 0.5). OctoMap's default is 0.7; with
    ``clamp_min`` 0.12 that takes 3 frames to show an obstacle entering space seen free (10 cm at
    1 m/s and 30 Hz). 0.9 shows it in the first frame that sees it; a lone false point is cleared
    by the next frame's ray. Chosen on ``dynamic-tune`` (docs/sensing.md, "A map over time")."""
    miss: float = 0.4
    """P(occupied) that one ray passing a cell gives it (< 0.5)."""
    clamp_min: float = 0.12
    """Lowest probability a cell keeps: bounds how many hits turn a long-free cell occupied."""
    clamp_max: float = 0.97
    """Highest probability a cell keeps: bounds how many misses turn a long-occupied cell free."""
    occupied: float = 0.5
    """A cell is occupied above this probability."""

    def __post_init__(self) -> None:
        for name in ("hit", "miss", "clamp_min", "clamp_max", "occupied"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < float(v) < 1.0:
                raise ValueError(f"map {name} must be a probability in (0, 1), got {v!r}")
        if not self.hit > 0.5:
            raise ValueError(f"map hit must be > 0.5 (a returned point is evidence of occupancy), got {self.hit}")
        if not self.miss < 0.5:
            raise ValueError(f"map miss must be < 0.5 (a ray through a cell is evidence of free), got {self.miss}")
        if not self.clamp_min < self.occupied < self.clamp_max:
            raise ValueError(
                f"map probabilities must satisfy clamp_min < occupied < clamp_max, "
                f"got {self.clamp_min}, {self.occupied}, {self.clamp_max}"
            )

    def frames_to_clear(self) -> int:
        """Frames of misses that turn a cell at ``clamp_max`` free."""
        return math.floor((_logit(self.clamp_max) - _logit(self.occupied)) / -_logit(self.miss)) + 1

    def frames_to_occupy(self) -> int:
        """Frames of hits that turn a cell at ``clamp_min`` occupied."""
        return math.floor((_logit(self.occupied) - _logit(self.clamp_min)) / _logit(self.hit)) + 1


class OccupancyMap:
    """A dense log-odds grid (cell ``(0, 0, 0)``'s corner at ``origin`` [m]) fused frame by frame."""

    def __init__(
        self,
        origin: np.ndarray,
        shape: tuple[int, int, int],
        resolution: float,
        settings: MapSettings | None = None,
        backend: str = "auto",
    ) -> None:
        """``backend``: the update's loops compiled (``"numba"``) or in numpy (``"numpy"``); the
        same cells and values either way (:mod:`planbench.runtime.backend`; ``"auto"``: numba
        when installed)."""
        self.settings = settings or MapSettings()
        self.backend = _backend.resolve(backend)
        self.origin = np.asarray(origin, dtype=float).copy()
        self.resolution = float(resolution)
        self.log_odds = np.zeros(shape, dtype=np.float32)
        self.known = np.zeros(shape, dtype=bool)
        self._hit_mask = np.zeros(shape, dtype=bool)  # scratch: the cells hit in the frame being fused
        s = self.settings
        self._hit, self._miss = np.float32(_logit(s.hit)), np.float32(_logit(s.miss))
        self._lo, self._hi = np.float32(_logit(s.clamp_min)), np.float32(_logit(s.clamp_max))
        self._threshold = np.float32(_logit(s.occupied))

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.log_odds.shape  # type: ignore[return-value]

    def integrate(self, seen: np.ndarray, hits: np.ndarray, known: np.ndarray | None = None) -> None:
        """Fuse one frame: ``seen`` (bool, the map's shape) the cells its rays saw free, ``hits``
        the flat indices (C order, unique) of the cells holding its points, ``known`` (bool, the
        map's shape) further cells to mark known without evidence (the arm's own body)."""
        if seen.shape != self.shape or seen.dtype != np.bool_:
            raise ValueError(
                f"seen must be a bool array of the map's shape {self.shape}, got {seen.dtype} {seen.shape}"
            )
        hits = np.asarray(hits, dtype=np.int64)
        log_odds, known_flat = self.log_odds.reshape(-1), self.known.reshape(-1)
        hit = self._hit_mask.reshape(-1)
        hit[hits] = True
        flat_seen = np.ascontiguousarray(seen).reshape(-1)
        if self.backend == "numba":
            from planbench.geometry import _compiled  # on use: numba is optional

            _compiled.fuse_free(flat_seen, hit, log_odds, known_flat, self._miss, self._lo)
        else:
            free = flat_seen & ~hit
            np.logical_or(known_flat, flat_seen, out=known_flat)
            np.add(log_odds, self._miss, out=log_odds, where=free)
            np.maximum(log_odds, self._lo, out=log_odds, where=free)
        hit[hits] = False  # the scratch mask back to all false
        log_odds[hits] = np.minimum(log_odds[hits] + self._hit, self._hi)
        known_flat[hits] = True
        if known is not None:
            np.logical_or(self.known, known, out=self.known)

    def cells_of(self, points: np.ndarray) -> np.ndarray:
        """Flat indices (C order, unique) of the cells holding one of the (N, 3) ``points`` [m]
        (those outside the map left out): a frame's hits, for :meth:`integrate`."""
        idx = np.floor((np.asarray(points, dtype=float) - self.origin) / self.resolution).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < np.array(self.shape)), axis=1)
        return np.unique(np.ravel_multi_index(idx[inside].T, self.shape))

    def occupied(self) -> np.ndarray:
        """Which cells are occupied (bool, the map's shape)."""
        return self.log_odds > self._threshold

    def grid(self) -> OccupancyGrid:
        """The map as a binary occupancy grid whose ``known`` is a copy of the map's."""
        data = np.empty(self.shape, dtype=np.float64)
        if self.backend == "numba":
            from planbench.geometry import _compiled

            _compiled.above(self.log_odds.reshape(-1), self._threshold, data.reshape(-1))
        else:
            np.greater(self.log_odds, self._threshold, out=data, casting="unsafe")
        return OccupancyGrid.unchecked(data, self.origin.copy(), self.resolution, 0.0, self.known.copy())

    def clear(self) -> None:
        """Forget everything."""
        self.log_odds[...] = 0.0
        self.known[...] = False
