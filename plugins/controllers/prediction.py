"""Where observed obstacles are going: motion estimated from successive observations only.

A controller that sees only where a crossing obstacle is pushes the arm when it is already close;
one that knows where it will be pushes earlier. :class:`MotionPredictor` estimates the motion of
occupied clusters from the frames a controller receives (no ground truth) and gives the cells they
sweep over a short horizon, which a controller adds to what its field or checks see (the
``prediction`` setting, :class:`PredictionSettings`). Per frame:

1. **Moving cells.** The cells holding a point of this frame (depth; with truth sensing, every
   occupied cell). A cell whose points stopped for more than ``prediction_gap`` [s] and came
   back starts a new *run*; a run is *moving* when the previous frame's grid knew its cell free
   (seen free, then occupied: something came in). A run is moving for ``prediction_memory`` [s]
   after it starts, so a parked obstacle stops counting. Static surfaces never count: their runs
   start where the grid knew nothing (first view) or knew them occupied (a map keeps a surface
   hidden behind a passing obstacle). A lone noisy point makes a moving cell for one frame.
2. **Clusters.** Moving cells within one cell of each other (26-neighbourhood, a k-d tree and
   ``scipy.sparse.csgraph.connected_components``), at least ``prediction_min_cells`` of them.
3. **Tracks.** Each cluster joins the track whose predicted centroid is nearest, within the
   distance ``prediction_max_speed`` covers since it was last seen plus ``prediction_gate``; the
   clusters a track takes are one (an obstacle split by an occluder stays one track). A cluster
   no track takes starts one; a track not seen for ``prediction_track_timeout`` [s] is dropped.
4. **Velocity.** The least-squares slope of the track's centroid over its last
   ``prediction_fit_frames`` frames, once it has ``prediction_min_frames``. A velocity faster than
   ``prediction_max_speed`` (noise clusters the gate joined) or with an RMS residual over
   ``prediction_max_residual`` [m] is not trusted; one slower than ``prediction_min_speed`` is
   still.
5. **Prediction.** Each trusted moving track's cells, moved along its velocity to every time in
   ``(0, prediction_horizon]`` after the frame's capture, a step of at most a cell: the swept cells.

Everything works on the frame's point cells and the cells near them, never a pass over the grid
with depth sensing (truth sensing has no points: one pass finds the occupied cells).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.reactive.controller import Observation
from planbench_plugins.ik_loop import ArmKinematics, Repulsion

__all__ = [
    "PREDICTION_MODES",
    "MotionPredictor",
    "Prediction",
    "PredictionSettings",
    "SummedRepulsion",
    "Track",
    "predicted_grid",
    "warm_up",
]

PREDICTION_MODES = ("none", "swept")
"""``"none"``: no prediction; ``"swept"``: the cells moving clusters sweep over the horizon join
what the controller sees (module docstring)."""


@dataclass(frozen=True)
class PredictionSettings:
    """How a controller predicts obstacle motion (module docstring); a mixin of the configs of
    ``matrix-field``, ``matrix-field-guided`` and ``ompl-replan`` (depth sensing only)."""

    prediction: str = "none"
    """``"none"`` or ``"swept"``: the cells moving clusters sweep over ``prediction_horizon``
    join the grid the controller reads."""
    prediction_horizon: float = 0.5
    """[s] How far ahead of a frame's capture the clusters are swept."""
    prediction_max_speed: float = 2.0
    """[m/s] Fastest believed motion: a track's gate, and a faster fit is not trusted (the
    ``dynamic`` set's obstacles peak at 1 m/s)."""
    prediction_min_speed: float = 0.15
    """[m/s] A track slower than this is still: nothing swept (a centroid's wander of a centimetre
    over a fit reads as up to 0.1 m/s)."""
    prediction_memory: float = 0.3
    """[s] A run of points in a cell seen free before counts as moving this long."""
    prediction_gap: float = 0.1
    """[s] Points may miss a cell this long (dropout) without ending its run."""
    prediction_min_cells: int = 6
    """Fewest moving cells of a cluster (fewer: noise). With ``prediction_min_speed`` chosen on
    ``dynamic-tune`` by the tracks' match to the true obstacles (``benchmarks/prediction.py``): 4 cells
    and 0.05 m/s left 38 tracks matching no obstacle in 3 fast scenarios, 6 and 0.15 none."""
    prediction_gate: float = 0.1
    """[m] Slack of a track's gate beyond what ``prediction_max_speed`` covers."""
    prediction_track_timeout: float = 0.15
    """[s] A track not seen this long is dropped."""
    prediction_fit_frames: int = 8
    """Frames of a track's least-squares velocity fit (the latest; 0.23 s at 30 Hz: a centroid
    wanders about a centimetre with the cells a surface covers)."""
    prediction_min_frames: int = 4
    """Frames a track needs before its velocity is trusted."""
    prediction_max_residual: float = 0.02
    """[m] RMS residual of the fit above which its velocity is not trusted."""

    def validate_prediction(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad setting."""
        if self.prediction not in PREDICTION_MODES:
            raise InvalidConfigError(
                f"prediction must be one of {PREDICTION_MODES} (obstacle motion from the frames), "
                f"got {self.prediction!r}"
            )
        for name in (
            "prediction_horizon",
            "prediction_max_speed",
            "prediction_memory",
            "prediction_gap",
            "prediction_gate",
            "prediction_track_timeout",
            "prediction_max_residual",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InvalidConfigError(f"{name} must be a finite number > 0, got {v!r}")
        v = self.prediction_min_speed
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InvalidConfigError(f"prediction_min_speed must be a finite number >= 0 [m/s], got {v!r}")
        for name in ("prediction_min_cells", "prediction_fit_frames", "prediction_min_frames"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InvalidConfigError(f"{name} must be an integer >= 1, got {v!r}")
        if self.prediction_min_frames < 2 or self.prediction_fit_frames < self.prediction_min_frames:
            raise InvalidConfigError(
                "a velocity needs 2 frames at least: set prediction_min_frames >= 2 and prediction_fit_frames >= "
                f"prediction_min_frames, got {self.prediction_min_frames} and {self.prediction_fit_frames}"
            )


@dataclass
class Track:
    """One moving cluster followed over frames: its centroids [m] at capture times [s]."""

    id: int
    times: list[float] = field(default_factory=list)
    centroids: list[np.ndarray] = field(default_factory=list)
    cells: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """The flat indices of its moving cells in the latest frame that showed it."""
    velocity: np.ndarray | None = None
    """[m/s] Trusted velocity, or None (too few frames, too fast, a poor fit)."""

    @property
    def last_seen(self) -> float:
        return self.times[-1]

    def predicted(self, t: float) -> np.ndarray:
        """Its centroid predicted at ``t`` [s] (the last one without a trusted velocity)."""
        v = self.velocity if self.velocity is not None else np.zeros(3)
        return self.centroids[-1] + v * (t - self.times[-1])


@dataclass(frozen=True)
class Prediction:
    """What one frame predicts: ``cells`` the flat indices of the swept cells (sorted, unique),
    ``tracks`` the tracks alive, ``moving_cells`` how many moving cells the frame had, ``moving``
    the flat indices of those in clusters (step 2): where obstacles that came in lately are, with
    or without a track (a track needs frames close together; a controller that plans between
    frames may see an obstacle move in only once)."""

    cells: np.ndarray
    tracks: tuple[Track, ...] = ()
    moving_cells: int = 0
    moving: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))


_EMPTY = np.zeros(0, dtype=np.intp)


class MotionPredictor:
    """Obstacle motion from successive observations (module docstring); ``observe`` each frame in
    order, ``reset`` between runs."""

    def __init__(self, settings: PredictionSettings) -> None:
        self.s = settings
        self.reset()

    def reset(self) -> None:
        """Forget every frame and track."""
        self._shape: tuple[int, int, int] | None = None
        # per cell, as 1 s + the time since the first frame (0: never; zeroed pages cost nothing until written)
        self._t0 = 0.0  # [s] the first frame's capture
        self._last_hit: np.ndarray = np.zeros(0)  # the latest capture with a point in it
        self._run_start: np.ndarray = np.zeros(0)  # when its current run began
        self._moving: np.ndarray = np.zeros(0, dtype=bool)  # per cell: its run began seen free
        self._mark: np.ndarray = np.zeros(0, dtype=bool)
        self._prev: OccupancyGrid | None = None
        self._grid: OccupancyGrid = OccupancyGrid.empty(np.zeros(3), np.ones(3), 1.0)  # the latest frame's
        self._points_in: tuple[np.ndarray, np.ndarray] | None = None  # its moving cells' points, and their cells
        self.tracks: list[Track] = []
        self._next_id = 0

    # --- one frame --------------------------------------------------------------------------------
    def observe(self, observation: Observation) -> Prediction:
        """Take in ``observation`` (after every earlier one) and predict from it."""
        grid, t = observation.grid, float(observation.time)
        cells, points = self._point_cells(observation)
        if self._shape != grid.shape or self._prev is None:
            self._start(grid, cells, t)
            return Prediction(_EMPTY)
        moving = self._moving_cells(grid, cells, t)
        self._prev = grid
        self._grid = grid
        self._points_in = None
        if points is not None and len(moving):  # the points of moving cells: centroids finer than a cell
            self._mark[moving] = True
            keep = self._mark[cells]
            self._mark[moving] = False
            self._points_in = (cells[keep], points[keep])
        clusters = self._clusters(moving, grid.shape)
        self._associate(clusters, grid, t)
        clustered = np.concatenate(clusters) if clusters else _EMPTY
        return Prediction(self._swept(grid, t), tuple(self.tracks), len(moving), clustered)

    def _point_cells(self, observation: Observation) -> tuple[np.ndarray, np.ndarray | None]:
        """Flat indices of the cells holding a point of the frame, one per point, and those points
        [m] (truth: the occupied cells, no points)."""
        grid = observation.grid
        if observation.points is None:
            return np.flatnonzero(np.asarray(grid.data).reshape(-1) >= 0.5), None
        pts = np.asarray(observation.points, dtype=float)
        if not len(pts):
            return _EMPTY, pts.reshape(0, 3)
        ijk = np.floor((pts - grid.origin) / grid.resolution).astype(np.intp)
        inside = np.all((ijk >= 0) & (ijk < np.array(grid.shape)), axis=1)
        flat = np.ravel_multi_index(ijk[inside].T, grid.shape)  # repeated cells: harmless, and no sort
        occupied = np.asarray(grid.data).reshape(-1)[flat] >= 0.5
        return flat[occupied], pts[inside][occupied]

    def _start(self, grid: OccupancyGrid, cells: np.ndarray, t: float) -> None:
        n = int(np.prod(grid.shape))
        self._shape = grid.shape
        self._t0 = t
        self._last_hit = np.zeros(n)  # np.full would write every page now: 40 ms on the first frame
        self._run_start = np.zeros(n)
        self._moving = np.zeros(n, dtype=bool)
        self._mark = np.zeros(n, dtype=bool)  # scratch, all false between frames
        self._last_hit[cells] = 1.0
        self._run_start[cells] = 1.0
        self._prev = grid
        self.tracks = []

    def _moving_cells(self, grid: OccupancyGrid, cells: np.ndarray, t: float) -> np.ndarray:
        """Step 1 of the module docstring: the frame's moving cells."""
        s, prev = self.s, self._prev
        assert prev is not None
        t = t - self._t0 + 1.0  # as stored (reset's comment)
        new = cells[self._last_hit[cells] < t - s.prediction_gap - 1e-6]
        if len(new):
            was_free = np.asarray(prev.data).reshape(-1)[new] < 0.5
            self._moving[new] = was_free & prev.known_at(new)
            self._run_start[new] = t
        self._last_hit[cells] = t
        young = self._run_start[cells] > t - s.prediction_memory - 1e-6
        return np.unique(cells[self._moving[cells] & young])

    def _clusters(self, moving: np.ndarray, shape: tuple[int, int, int]) -> list[np.ndarray]:
        """Step 2: the moving cells in clusters of at least ``prediction_min_cells``."""
        if len(moving) < self.s.prediction_min_cells:
            return []
        ijk = np.column_stack(np.unravel_index(moving, shape))
        pairs = cKDTree(ijk).query_pairs(1.0, p=np.inf, output_type="ndarray")
        n = len(moving)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        count, labels = connected_components(graph, directed=False)
        sizes = np.bincount(labels, minlength=count)
        order = np.argsort(labels, kind="stable")
        groups = np.split(moving[order], np.cumsum(sizes)[:-1])
        return [g for g in groups if len(g) >= self.s.prediction_min_cells]

    def _associate(self, clusters: list[np.ndarray], grid: OccupancyGrid, t: float) -> None:
        """Step 3 and 4: clusters to tracks, new tracks, dropped tracks, velocities."""
        s = self.s
        centres = [self._centroid(c) for c in clusters]
        taken: dict[int, list[int]] = {}
        fresh: list[int] = []
        for i, c in enumerate(centres):
            best, best_d = -1, math.inf
            for j, tr in enumerate(self.tracks):
                d = float(np.linalg.norm(tr.predicted(t) - c))
                gate = s.prediction_max_speed * (t - tr.last_seen) + s.prediction_gate
                if d <= gate and d < best_d:
                    best, best_d = j, d
            if best >= 0:
                taken.setdefault(best, []).append(i)
            else:
                fresh.append(i)
        for j, members in taken.items():
            tr = self.tracks[j]
            tr.cells = np.concatenate([clusters[i] for i in members])
            tr.times.append(t)
            tr.centroids.append(self._centroid(tr.cells))
            del tr.times[: -s.prediction_fit_frames], tr.centroids[: -s.prediction_fit_frames]
            tr.velocity = self._velocity(tr)
        for i in fresh:
            self.tracks.append(Track(self._next_id, [t], [centres[i]], clusters[i]))
            self._next_id += 1
        self.tracks = [tr for tr in self.tracks if tr.last_seen >= t - s.prediction_track_timeout - 1e-6]

    def _centroid(self, cells: np.ndarray) -> np.ndarray:
        """The mean [m] of this frame's points in ``cells`` (flat indices of moving cells), or of
        the cells' centres without points (truth sensing)."""
        if self._points_in is not None:
            in_cells, points = self._points_in
            mine = np.isin(in_cells, cells)
            if mine.any():
                return points[mine].mean(axis=0)  # type: ignore[no-any-return]
        grid = self._grid
        ijk = np.column_stack(np.unravel_index(cells, grid.shape))
        return grid.origin + (ijk.mean(axis=0) + 0.5) * grid.resolution  # type: ignore[no-any-return]

    def _velocity(self, track: Track) -> np.ndarray | None:
        """Step 4: the track's trusted velocity [m/s], or None."""
        s = self.s
        if len(track.times) < s.prediction_min_frames:
            return None
        times = np.asarray(track.times)
        X = np.asarray(track.centroids)
        dt = times - times.mean()
        denom = float(dt @ dt)
        if denom <= 0:
            return None
        v = (dt @ (X - X.mean(axis=0))) / denom
        residual = X - X.mean(axis=0) - np.outer(dt, v)
        rms = math.sqrt(float(np.mean(np.sum(residual**2, axis=1))))
        if float(np.linalg.norm(v)) > s.prediction_max_speed or rms > s.prediction_max_residual:
            return None
        return v  # type: ignore[no-any-return]

    def _swept(self, grid: OccupancyGrid, t: float) -> np.ndarray:
        """Step 5: flat indices of the cells the trusted moving tracks sweep."""
        s, res, shape = self.s, grid.resolution, np.array(grid.shape)
        out = []
        for tr in self.tracks:
            if tr.velocity is None:
                continue
            speed = float(np.linalg.norm(tr.velocity))
            if speed < s.prediction_min_speed:
                continue
            steps = max(1, math.ceil(speed * s.prediction_horizon / res))
            # a track this frame missed goes on from where it was last seen
            taus = (t - tr.last_seen) + s.prediction_horizon * np.arange(1, steps + 1) / steps
            ijk = np.column_stack(np.unravel_index(tr.cells, grid.shape)).astype(float)
            moved = ijk[None, :, :] + (taus[:, None] * tr.velocity / res)[:, None, :]
            idx = np.rint(moved.reshape(-1, 3)).astype(np.intp)
            idx = idx[np.all((idx >= 0) & (idx < shape), axis=1)]
            out.append(np.ravel_multi_index(idx.T, grid.shape))
        return np.unique(np.concatenate(out)) if out else _EMPTY


def predicted_grid(grid: OccupancyGrid, cells: np.ndarray) -> OccupancyGrid | None:
    """The block of ``grid``'s lattice holding ``cells`` (flat indices), those occupied (1.0), the
    rest free: a small grid whose field is the predicted cells' own; None without cells."""
    if not len(cells):
        return None
    ijk = np.column_stack(np.unravel_index(np.asarray(cells, dtype=np.intp), grid.shape))
    lo, hi = ijk.min(axis=0), ijk.max(axis=0) + 1
    data = np.zeros(tuple(int(x) for x in hi - lo))
    data[tuple((ijk - lo).T)] = 1.0
    return OccupancyGrid.unchecked(data, grid.origin + lo * grid.resolution, grid.resolution, 0.0)


class SummedRepulsion:
    """The push of ``base`` plus that of ``extra`` (the predicted cells' field): both fields on the
    loop's control points (``points is kin.points``), summed into a buffer of its own. A grid copy
    with the predicted cells set would cost a pass over the grid a frame; two lazy fields cost one
    window sum more a step."""

    def __init__(self, base: Repulsion | None, extra: Repulsion) -> None:
        self.base, self.extra = base, extra
        self._F = np.zeros((0, 3))

    @property
    def gain(self) -> float:
        return float((self.base or self.extra).gain)

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        points, F, support, joint = self.extra.forces(kin)
        if self.base is None:
            return points, F, support, joint
        if self._F.shape != F.shape:
            self._F = np.zeros_like(F, dtype=float)
        self._F[:] = F
        points, F, support, joint = self.base.forces(kin)
        if points is not kin.points:
            raise ValueError("SummedRepulsion sums fields on the loop's control points only")
        self._F += F
        return points, self._F, support, joint


def describe(prediction: Prediction) -> dict[str, Any]:
    """JSON-friendly summary of one frame's prediction (for ``info``)."""
    return {
        "tracks": len(prediction.tracks),
        "moving_tracks": sum(t.velocity is not None for t in prediction.tracks),
        "swept_cells": len(prediction.cells),
    }


def warm_up(settings: PredictionSettings, push: Callable[[OccupancyGrid], Any]) -> None:
    """Put a box moving at 0.5 m/s through a small grid past a predictor (untimed, in a controller's
    ``setup``), and call ``push`` on the grid of the cells it sweeps: scipy's k-d tree and graph
    code are loaded and the field code for that grid (the surface pass's lazy kernel) compiled
    before the first timed frame. Measured without it: the first frame 50 ms, the first
    prediction about 100 ms of charged compute (10-15 missed deadlines at 100 Hz)."""
    grid = OccupancyGrid.empty(np.zeros(3), np.full(3, 0.6), 0.02)
    u = np.arange(-0.05, 0.0501, 0.005)
    a, b = (x.ravel() for x in np.meshgrid(u, u, indexing="ij"))
    faces = []
    for axis in range(3):
        for side in (-0.05, 0.05):
            f = np.zeros((len(a), 3))
            f[:, axis], f[:, (axis + 1) % 3], f[:, (axis + 2) % 3] = side, a, b
            faces.append(f)
    surface = np.vstack(faces)
    predictor, cells = MotionPredictor(settings), _EMPTY
    for k in range(settings.prediction_fit_frames + 4):
        points = surface + np.array([0.12 + 0.5 * k / 30.0, 0.3, 0.3])
        data = np.zeros(grid.shape)
        data[tuple(grid.index_of(points).T)] = 1.0
        frame = OccupancyGrid(data, grid.origin, grid.resolution, known=np.ones(grid.shape, dtype=bool))
        cells = predictor.observe(Observation(k / 30.0, frame, k, points.astype(np.float32))).cells
    block = predicted_grid(grid, cells)
    if block is not None:
        push(block)
