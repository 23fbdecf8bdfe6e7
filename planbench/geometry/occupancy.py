"""Occupancy grids: the task-space voxel input of the matrix-field planner.

``data[i, j, k]`` is the occupancy in [0, 1] of the cell whose centre is
``origin + (np.array([i, j, k]) + 0.5) * resolution`` (axis order world x, y, z). Values may be
binary (a voxelized scene) or probabilistic (a sensor); nothing here thresholds them away.
``outside`` is the occupancy assumed beyond the grid: 0 = free, 1 = walled in.

``known`` says which cells were observed (a bool array of the grid's shape): a cell a sensor has
not seen is *unknown*, whatever its ``data`` value (0 there: no evidence of an obstacle, not
evidence of free space). ``None``, the default, means every cell is known: a grid voxelised from
the exact scene (static problems, ``truth`` sensing). So a cell is in one of three states: known
occupied, known free, unknown (docs/sensing.md).

Rule for partly covered cells when voxelizing a scene (``rule=``):

- ``"any"`` (default): 1 if any part of the cell overlaps an obstacle, else 0. Conservative: an
  obstacle grows by at most one cell, it never shrinks, and walls thinner than a cell still show.
- ``"center"``: 1 if the cell centre lies inside an obstacle.
- ``"fraction"``: the fraction of the cell's volume inside obstacles (a probabilistic grid).

Overlap and fraction are measured on the ``subsamples**3`` midpoints of a regular subdivision of
each cell (default 4 per edge, 64 per cell): ``"fraction"`` is then the midpoint-rule estimate of the
covered volume, and ``"any"`` misses only slivers thinner than ``resolution / subsamples`` (for
boxes, ``"any"`` is exact instead: a separating-axis test of the cell against the box). Only
cells the obstacle's surface passes through are sub-sampled (found with exact signed distances).
Mesh obstacles are voxelized with coal (a cell-sized box against the mesh): the ``"any"`` rule,
whatever rule is asked for. Point clouds (unions of lattice cubes, :mod:`planbench.geometry.pointcloud`)
are voxelized exactly for ``"any"`` (a cell counts when its interior meets a cube) and ``"center"``;
``"fraction"`` sub-samples the cells that ``"any"`` marks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.errors import ResourceLimitError
from planbench.geometry.overlap import cubes_overlap_boxes
from planbench.scene import Obstacle, Scene

__all__ = ["MAX_GRID_CELLS", "OccupancyGrid", "cover_block", "grid_shape", "grow_cells", "merge_cells", "scene_grid"]

RULES = ("any", "center", "fraction")
MAX_GRID_CELLS = 1 << 26
"""The most cells an occupancy grid may have (67 million, e.g. 406^3: 512 MiB as float64, and
the matrix field of such a grid takes several GiB more). A grid over an arm's workspace (a 2.6 m
cube) has 2.2 million cells at 0.02 m and 140 million at 0.005 m... which is refused: choose a
coarser resolution, or bounds around the robot. The count is computed from the bounds and the
resolution before anything is allocated (:func:`grid_shape`), so a far-away obstacle or a tiny
resolution is a :class:`~planbench.errors.ResourceLimitError` naming the figure, not a
``MemoryError``."""


def grid_shape(lower: np.ndarray, upper: np.ndarray, resolution: float) -> tuple[int, int, int]:
    """Cells per axis of a grid covering [lower, upper] at ``resolution`` [m/cell] (rounded up);
    :class:`~planbench.errors.ResourceLimitError` past :data:`MAX_GRID_CELLS`."""
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    if not (np.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be > 0 [m/cell], got {resolution}")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise ValueError(f"grid bounds must be finite, got {lower} and {upper}")
    cells = np.maximum(1.0, np.ceil((upper - lower) / resolution - 1e-9))
    total = float(np.prod(cells))
    if not total <= MAX_GRID_CELLS:
        extent = " x ".join(f"{x:.3g}" for x in upper - lower)
        counts = " x ".join(f"{x:.0f}" for x in cells)
        raise ResourceLimitError(
            f"an occupancy grid over {extent} m at {resolution:g} m per cell would have {counts} = {total:.3g} "
            f"cells, more than the {MAX_GRID_CELLS:,} planbench allocates "
            "(planbench.geometry.occupancy.MAX_GRID_CELLS): "
            "use a coarser resolution, or check for an obstacle far from the robot"
        )
    return tuple(int(x) for x in cells)  # type: ignore[return-value]


def _checked_known(known: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``known`` as a bool array of ``shape`` (a ``ValueError`` naming both otherwise)."""
    known = np.asarray(known)
    if known.dtype != np.bool_ or known.shape != tuple(shape):
        raise ValueError(
            f"known must be a bool array of the grid's shape {tuple(shape)}, got {known.dtype} {known.shape}"
        )
    return known


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """A 3D occupancy grid. ``origin`` [m] is the corner of cell (0, 0, 0); ``resolution`` [m/cell];
    ``known``: which cells were observed (module docstring; None: all)."""

    data: np.ndarray
    origin: np.ndarray
    resolution: float
    outside: float = 0.0
    known: np.ndarray | None = None

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 3:
            raise ValueError(f"occupancy data must be 3D (x, y, z), got shape {data.shape}")
        if not np.issubdtype(data.dtype, np.floating):
            data = data.astype(np.float64)
        if data.size and not (np.all(np.isfinite(data)) and data.min() >= 0.0 and data.max() <= 1.0):
            raise ValueError("occupancy values must be finite and in [0, 1]")
        origin = np.asarray(self.origin, dtype=float).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"origin must be 3 finite numbers [m], got {self.origin}")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be > 0 [m/cell], got {self.resolution}")
        if not 0.0 <= self.outside <= 1.0:
            raise ValueError(f"outside occupancy must be in [0, 1], got {self.outside}")
        if self.known is not None:
            object.__setattr__(self, "known", _checked_known(self.known, data.shape))
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "resolution", float(self.resolution))

    @property
    def known_mask(self) -> np.ndarray:
        """Which cells were observed: :attr:`known`, or a read-only all-true view when every cell is."""
        if self.known is not None:
            return self.known
        return np.broadcast_to(np.True_, self.data.shape)

    def known_at(self, cells: np.ndarray) -> np.ndarray:
        """Whether each of ``cells`` (flat indices, C order) was observed (bool, one per cell): what
        ``known_mask.reshape(-1)[cells]`` gives, without unpacking a mask that arrived packed (a
        controller's frame: :mod:`planbench.reactive.remote`)."""
        cells = np.asarray(cells, dtype=np.intp)
        if self.known is None:
            return np.ones(cells.shape, dtype=bool)
        return self.known.reshape(-1)[cells]

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.data.shape  # type: ignore[return-value]

    @property
    def upper(self) -> np.ndarray:
        """World position of the far corner of the grid [m]."""
        return self.origin + np.array(self.shape) * self.resolution

    def cell_centers(self) -> np.ndarray:
        """(nx, ny, nz, 3) array of cell-centre positions [m]."""
        axes = [self.origin[a] + (np.arange(n) + 0.5) * self.resolution for a, n in enumerate(self.shape)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def index_of(self, points: np.ndarray) -> np.ndarray:
        """Integer cell index (N, 3) containing each point; may lie outside the grid."""
        return np.floor((np.asarray(points, dtype=float) - self.origin) / self.resolution).astype(int)

    def occupancy_at(self, points: np.ndarray) -> np.ndarray:
        """Occupancy of the cell containing each point (``outside`` beyond the grid)."""
        idx = self.index_of(np.atleast_2d(points))
        inside = np.all((idx >= 0) & (idx < np.array(self.shape)), axis=1)
        out = np.full(len(idx), self.outside, dtype=self.data.dtype)
        i = idx[inside]
        out[inside] = self.data[i[:, 0], i[:, 1], i[:, 2]]
        return out

    # --- constructors ---------------------------------------------------------------------
    @classmethod
    def empty(
        cls, lower: np.ndarray, upper: np.ndarray, resolution: float, outside: float = 0.0, dtype: type = np.float64
    ) -> OccupancyGrid:
        """A free grid covering the box [lower, upper] (rounded up to whole cells)."""
        lower = np.asarray(lower, dtype=float)
        upper = np.asarray(upper, dtype=float)
        if np.any(upper <= lower):
            raise ValueError(f"grid bounds must have upper > lower, got {lower} and {upper}")
        if not 0.0 <= outside <= 1.0:  # before allocating
            raise ValueError(f"outside occupancy must be in [0, 1], got {outside}")
        return cls.unchecked(np.zeros(grid_shape(lower, upper, resolution), dtype=dtype), lower, resolution, outside)

    @classmethod
    def unchecked(
        cls,
        data: np.ndarray,
        origin: np.ndarray,
        resolution: float,
        outside: float = 0.0,
        known: np.ndarray | None = None,
    ) -> OccupancyGrid:
        """A grid whose maker guarantees its cells: ``data`` a 3D floating array with values in
        [0, 1]. Its origin, resolution, ``outside`` and ``known`` are checked as the constructor
        checks them; the pass over every cell is skipped (5 ms on a 142^3 grid, every sensor frame)."""
        if data.ndim != 3 or not np.issubdtype(data.dtype, np.floating):
            raise ValueError(f"occupancy data must be a 3D floating array, got {data.dtype} {data.shape}")
        grid = cls(np.zeros((1, 1, 1), dtype=data.dtype), origin, resolution, outside)
        object.__setattr__(grid, "data", data)
        object.__setattr__(grid, "known", None if known is None else _checked_known(known, data.shape))
        return grid

    @classmethod
    def from_scene(
        cls,
        scene: Scene,
        resolution: float,
        bounds: tuple[np.ndarray, np.ndarray] | None = None,
        rule: str = "any",
        subsamples: int = 4,
        padding: float = 0.0,
        outside: float = 0.0,
    ) -> OccupancyGrid:
        """Voxelize a scene's obstacles (see the module docstring for ``rule``).

        ``bounds`` = (lower, upper) corners [m]; by default the scene's bounding box grown by
        ``padding`` [m] on every side.
        """
        if rule not in RULES:
            raise ValueError(f"unknown voxelization rule {rule!r}; use one of {RULES}")
        if subsamples < 1:
            raise ValueError("subsamples must be >= 1 (sample points per cell edge)")
        if bounds is None:
            lo, hi = scene.aabb()
            bounds = (lo - padding, hi + padding)
        grid = cls.empty(bounds[0], bounds[1], resolution, outside)
        data = grid.data
        shape = np.array(grid.shape)
        for obstacle in scene.obstacles:
            lo, hi = obstacle.aabb()
            i0 = np.clip(np.floor((lo - grid.origin) / resolution).astype(int), 0, shape)
            i1 = np.clip(np.floor((hi - grid.origin) / resolution).astype(int) + 1, 0, shape)
            if np.any(i1 <= i0):
                continue
            block = cover_block(obstacle, grid.origin, resolution, i0, i1, rule, subsamples)
            view = data[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]]
            if rule == "fraction":  # overlapping obstacles: occupancy is the union, capped at 1
                np.minimum(view + block, 1.0, out=view)
            else:
                np.maximum(view, block, out=view)
        return grid

    @classmethod
    def from_points(
        cls,
        points: np.ndarray,
        resolution: float,
        bounds: tuple[np.ndarray, np.ndarray] | None = None,
        min_points: int = 1,
        outside: float = 0.0,
        known: np.ndarray | None = None,
    ) -> OccupancyGrid:
        """A binary grid from an (N, 3) point cloud [m]: a cell is occupied when it holds at least
        ``min_points`` points. Points outside ``bounds`` are dropped; NaN rows (invalid depth
        pixels) are ignored. Default bounds: the cloud's bounding box plus one cell.

        ``known``: the cells the sensor saw free (bool, the grid's shape, for instance from
        :func:`planbench.geometry.views.mark_seen`); the grid's :attr:`known` is then those and
        every cell that holds a point (it is modified in place). Without it, every cell counts as
        known.
        """
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"a point cloud must be an (N, 3) array, got shape {pts.shape}")
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if bounds is None:
            if len(pts) == 0:
                raise ValueError("cannot infer grid bounds from an empty point cloud; pass bounds=")
            bounds = (pts.min(axis=0) - resolution, pts.max(axis=0) + resolution)
        grid = cls.empty(bounds[0], bounds[1], resolution, outside)
        idx = grid.index_of(pts)
        keep = np.all((idx >= 0) & (idx < np.array(grid.shape)), axis=1)
        counts = np.zeros(grid.shape, dtype=np.int64)
        np.add.at(counts, tuple(idx[keep].T), 1)
        grid.data[...] = counts >= min_points
        if known is None:
            return grid
        known = _checked_known(known, grid.shape)
        known |= counts > 0
        object.__setattr__(grid, "known", known)  # this constructor's own grid, not yet handed out
        return grid


def scene_grid(
    scene: Scene, resolution: float, margin: float = 0.0, *, robot: Any = None, aligned: bool = False
) -> OccupancyGrid | None:
    """The grid every grid-based planner voxelizes a scene into (rule ``"any"``: a cell touching
    an obstacle is occupied, so the grid never misses a thin wall).

    Bounds: the obstacles' bounding box grown by ``margin`` [m] (a field's reach plus a cell).
    With ``robot``, cut to the cube of half-side ``robot.reach() + margin`` around its base,
    since nothing farther can touch the arm or push a point on it. ``aligned`` rounds the bounds
    out to multiples of ``resolution`` (an octree's cells lie on that lattice). ``None`` when the
    scene is empty or no obstacle lies in the cube.
    """
    if len(scene) == 0:
        return None
    lo, hi = scene.aabb()
    lo, hi = np.asarray(lo) - margin, np.asarray(hi) + margin
    if robot is not None:
        half = robot.reach() + margin
        lo, hi = np.maximum(lo, -half), np.minimum(hi, half)
        if np.any(hi <= lo):
            return None
    if aligned:
        lo = np.floor(lo / resolution) * resolution
        hi = np.maximum(np.ceil(hi / resolution) * resolution, lo + resolution)
    return OccupancyGrid.from_scene(scene, resolution, bounds=(lo, hi), rule="any")


def cover_block(
    obstacle: Obstacle,
    origin: np.ndarray,
    resolution: float,
    i0: np.ndarray,
    i1: np.ndarray,
    rule: str,
    subsamples: int,
) -> np.ndarray:
    """Coverage in [0, 1] of the cells ``i0..i1`` (integer (3,) corners, ``i1`` exclusive) of the
    grid at ``origin`` [m] by one obstacle, following ``rule`` (the voxelisation of a scene's grid,
    and of a sensed frame's obstacles)."""
    n = i1 - i0
    if obstacle.type == "mesh":
        return _mesh_cover(obstacle, origin, resolution, i0, n)
    if obstacle.type == "pointcloud":
        return _cloud_cover(obstacle, origin, resolution, i0, i1, rule, subsamples)
    centres = _points(origin, resolution, i0, n, np.array([0.5]))
    sd = obstacle.signed_distance(centres).reshape(tuple(n))
    if rule == "center":
        return (sd <= 0.0).astype(float)
    # Cells farther than half a diagonal from the surface are wholly inside or outside; only the
    # cells the surface passes through need sub-sampling.
    half_diagonal = 0.5 * np.sqrt(3.0) * resolution
    out = (sd <= -half_diagonal).astype(float)
    boundary = np.argwhere(np.abs(sd) < half_diagonal)
    if len(boundary) and rule == "any" and obstacle.type == "box":
        centres_b = origin + (i0 + boundary + 0.5) * resolution
        out[tuple(boundary.T)] = _cube_box_overlap(centres_b, 0.5 * resolution, obstacle)
    elif len(boundary):
        offsets = (np.arange(subsamples) + 0.5) / subsamples
        sub = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), -1).reshape(-1, 3)
        pts = origin + (i0 + boundary[:, None, :] + sub[None, :, :]) * resolution
        inside = obstacle.contains(pts.reshape(-1, 3)).reshape(len(boundary), -1)
        cover = inside.mean(axis=1) if rule == "fraction" else inside.any(axis=1).astype(float)
        out[tuple(boundary.T)] = cover
    return out


def _cube_box_overlap(centres: np.ndarray, half: float, obstacle: Any) -> np.ndarray:
    """Exact overlap (1.0 or 0.0) of axis-aligned cubes (centres (N, 3), half edge ``half``) with a
    box obstacle (:func:`planbench.geometry.overlap.cubes_overlap_boxes`)."""
    extents = 0.5 * np.array(obstacle.size)
    hit = cubes_overlap_boxes(centres, half, np.array(obstacle.position), obstacle.rotation, extents, 1e-12)
    return hit.astype(float)  # type: ignore[no-any-return]


def _points(origin, resolution, i0, n, offsets) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Sample points at ``offsets`` (fractions of a cell) in cells i0 .. i0+n, as (M, 3)."""
    axes = [
        origin[a] + (i0[a] + np.arange(n[a])[:, None] + offsets[None, :]).reshape(-1) * resolution for a in range(3)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _cloud_cover(obstacle, origin, resolution, i0, i1, rule, subsamples) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Coverage of the cells i0..i1 by a point cloud's cubes: exact for ``"any"`` and ``"center"``
    (cube lookups, no sampling of empty space); ``"fraction"`` samples only the overlapped cells."""
    if rule == "center":
        centres = _points(origin, resolution, i0, i1 - i0, np.array([0.5]))
        return obstacle.contains(centres).reshape(tuple(i1 - i0)).astype(float)  # type: ignore[no-any-return]
    out = obstacle.cloud().cover(obstacle.rotation, np.array(obstacle.position), origin, resolution, i0, i1)
    if rule == "fraction":
        cells = np.argwhere(out > 0)
        offsets = (np.arange(subsamples) + 0.5) / subsamples
        sub = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), -1).reshape(-1, 3)
        pts = origin + (i0 + cells[:, None, :] + sub[None, :, :]) * resolution
        out[tuple(cells.T)] = obstacle.contains(pts.reshape(-1, 3)).reshape(len(cells), -1).mean(axis=1)
    return out  # type: ignore[no-any-return]


def _mesh_cover(obstacle, origin, resolution, i0, n) -> np.ndarray:  # type: ignore[no-untyped-def]
    import coal

    mesh = obstacle.collision_geometry()
    tf = coal.Transform3s(obstacle.rotation, np.array(obstacle.position, dtype=float))
    cell = coal.Box(resolution, resolution, resolution)
    req, out = coal.CollisionRequest(), np.zeros(tuple(n))
    for idx in np.ndindex(*n):
        centre = origin + (i0 + np.array(idx) + 0.5) * resolution
        res = coal.CollisionResult()
        if coal.collide(cell, coal.Transform3s(np.eye(3), centre), mesh, tf, req, res):
            out[idx] = 1.0
    return out


def grow_cells(mask: np.ndarray, cells: int) -> np.ndarray:
    """A new bool array: ``mask`` (3-D, bool) and every cell within ``cells`` cells of one of its
    True cells along each axis (a cube of side ``2 * cells + 1`` around each; nothing wraps at the
    faces). One axis at a time with shifted slices: a few milliseconds for a 142^3 grid, where
    ``scipy.ndimage.binary_dilation`` takes 15 times longer."""
    if mask.ndim != 3 or mask.dtype != bool:
        raise ValueError(f"grow_cells needs a 3-D bool array, got {mask.ndim}-D {mask.dtype}")
    if cells < 0:
        raise ValueError(f"cells must be >= 0, got {cells}")
    grown = mask.copy()
    for axis in range(3):
        lo = (slice(None),) * axis + (slice(None, -1),)
        hi = (slice(None),) * axis + (slice(1, None),)
        for _ in range(cells):
            before = grown.copy()
            grown[hi] |= before[lo]
            grown[lo] |= before[hi]
    return grown


def merge_cells(occupied: np.ndarray) -> list[tuple[tuple[int, int, int], tuple[int, int, int]]]:
    """Disjoint boxes of cells whose union is exactly the ``True`` cells of a 3D boolean array, as
    (lower index, upper index exclusive) per box. Greedy: maximal runs along z in each (x, y) column;
    runs with the same z extent in neighbouring y columns of one x slice join into rectangles;
    rectangles with the same y and z extent in neighbouring x slices join into boxes. A voxelized
    box scene gives about one box per obstacle: what grid-based collision checkers hand to coal."""
    occupied = np.asarray(occupied, dtype=bool)
    nx, ny, _ = occupied.shape
    # rectangles per x slice: (j0, j1, k0, k1)
    open_boxes: dict[tuple[int, int, int, int], int] = {}  # rectangle -> first x index
    boxes: list[tuple[tuple[int, int, int], tuple[int, int, int]]] = []
    for i in range(nx + 1):
        rects: set[tuple[int, int, int, int]] = set()
        if i < nx:
            active: dict[tuple[int, int], int] = {}  # z run -> first y index
            for j in range(ny + 1):
                runs: set[tuple[int, int]] = set()
                if j < ny and occupied[i, j].any():
                    padded = np.concatenate([[False], occupied[i, j], [False]])
                    edges = np.flatnonzero(padded[1:] != padded[:-1])
                    runs = {(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)}
                for run in list(active):
                    if run not in runs:
                        rects.add((active.pop(run), j, *run))
                for run in runs:
                    active.setdefault(run, j)
        for rect in list(open_boxes):
            if rect not in rects:
                j0, j1, k0, k1 = rect
                boxes.append(((open_boxes.pop(rect), j0, k0), (i, j1, k1)))
        for rect in rects:
            open_boxes.setdefault(rect, i)
    return boxes
