"""Point-cloud obstacles: a cloud file turned into the one voxel geometry every part of planbench uses.

The geometry rule. A ``pointcloud`` obstacle with point radius ``r`` [m] is the union of the cubes
of edge ``cell = 2 r`` on the lattice ``[k cell, (k + 1) cell)`` (``k`` integer, per axis, in the
obstacle's frame) that hold at least one point. This is exactly the set of occupied leaves of
coal's octree built at resolution ``cell`` (octomap puts its leaves on the same lattice), so:

- collision checking and OMPL use that octree (:meth:`VoxelCloud.octree`);
- certified validation takes coal distances to it: exact outside the cloud, and when a body
  penetrates, the depth into the deepest single cell (a lower bound of the depth into the union;
  the verdict "collision" does not depend on it);
- :meth:`VoxelCloud.signed_distance` is the exact signed distance to the union of cubes (a k-d
  tree over cell centres outside, a search of the free neighbour cells inside), and
  :meth:`VoxelCloud.cover` voxelises it onto any grid exactly (a cell counts when its interior
  overlaps a cube), which is how the field planners' grids see it.

A point lies in its cube but not at its centre: the obstacle covers every point with a margin
between 0 and ``2 r`` depending on where in its cell it falls. Choose ``r`` as half the spacing of
the points on a surface (a cloud thinned to one point per ``2 r`` cube loses nothing).

Files: ``.npz`` with an array ``points`` (N, 3), or PLY (ASCII or binary, the vertices' x, y, z;
read with trimesh). Points are in the obstacle's frame, which is the robot's base frame unless the
obstacle has a pose.

Limits, checked before anything is allocated: a cloud file must be a regular file of at most
:data:`MAX_FILE_BYTES`, and hold at most :data:`MAX_POINTS` points. The count is read from the
file's header (the ``.npy`` header inside the ``.npz``, the PLY header) and compared with the
bytes the file holds, so a small compressed file that claims a huge array, or a header that
claims more points than follow it, is refused as such.
"""

from __future__ import annotations

import functools
import itertools
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from planbench.errors import PlanbenchError
from planbench.files.inputs import InputFileError, regular_file
from planbench.geometry.overlap import cubes_overlap_boxes

__all__ = ["MAX_FILE_BYTES", "MAX_POINTS", "PointCloudError", "VoxelCloud", "load_cloud", "read_points", "write_points"]

SUFFIXES = (".npz", ".ply")
MAX_POINTS = 10_000_000
"""The most points a cloud file may hold (240 MB as float64; voxelising 10 million peaks at 1.0 GB RSS, 15 s).
A depth camera gives 0.3 million per frame; a denser cloud loses nothing when thinned to one point
per cube of edge ``2 r`` (module docstring)."""
MAX_FILE_BYTES = 1 << 30
"""[B] The largest cloud file read (1 GiB: 10 million points as ASCII PLY are about 300 MB)."""
_OFFSET = 1 << 20  # lattice indices are stored as 21-bit unsigned fields of one int64 key
_LIMIT = 1 << 15  # octomap's 16-level tree spans +-2^15 cells around the origin


class PointCloudError(PlanbenchError, ValueError):
    """A point-cloud file or its points cannot be used (a ValueError, so scene loading reports it
    as a :class:`~planbench.errors.ProblemFileError` naming the file)."""


def read_points(path: str | Path) -> np.ndarray:
    """The (N, 3) float64 points [m] of a ``.npz`` (array ``points``) or PLY file; raises
    :class:`PointCloudError` for a missing, unreadable or malformed file, non-finite values or no points."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise PointCloudError(f"point cloud {p}: unsupported file type {p.suffix!r}; use .npz or .ply")
    try:
        size = regular_file(p, MAX_FILE_BYTES).st_size
    except InputFileError as exc:
        why = "file not found" if exc.problem.endswith("no such file") else exc.problem
        raise PointCloudError(f"point cloud {p}: {why}") from None
    pts = _read_npz(p) if suffix == ".npz" else _read_ply(p, size)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise PointCloudError(f"point cloud {p}: points must be an (N, 3) array, got shape {pts.shape}")
    if len(pts) == 0:
        raise PointCloudError(f"point cloud {p}: holds no points")
    bad = ~np.all(np.isfinite(pts), axis=1)
    if bad.any():
        raise PointCloudError(
            f"point cloud {p}: {int(bad.sum())} of {len(pts)} points are NaN or infinite; "
            "drop invalid depth pixels before saving"
        )
    return pts


def _read_npz(p: Path) -> np.ndarray:
    _check_npz(p)
    try:
        with np.load(p, allow_pickle=False) as f:
            if not hasattr(f, "files"):
                raise PointCloudError(f"point cloud {p}: a .npz archive is expected, found a single .npy array")
            if "points" not in f.files:
                raise PointCloudError(f"point cloud {p}: no array 'points' in the .npz (holds {sorted(f.files)})")
            arr = np.asarray(f["points"])
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, PointCloudError):
            raise
        raise PointCloudError(f"point cloud {p}: not a readable .npz file ({exc})") from exc
    if not np.issubdtype(arr.dtype, np.number):
        raise PointCloudError(f"point cloud {p}: 'points' must be numeric, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def _check_npz(p: Path) -> None:
    """Refuse a .npz whose ``points`` header claims a shape, type or size that cannot be used,
    before numpy decompresses it (a few MB of deflated zeros can claim gigabytes)."""
    with open(p, "rb") as f:
        if f.read(6) == b"\x93NUMPY":
            raise PointCloudError(f"point cloud {p}: a .npz archive is expected, found a single .npy array")
    try:
        with zipfile.ZipFile(p) as z:
            names = z.namelist()
            if "points.npy" not in names:
                held = sorted(n.removesuffix(".npy") for n in names)
                raise PointCloudError(f"point cloud {p}: no array 'points' in the .npz (holds {held})")
            info = z.getinfo("points.npy")
            with z.open(info) as member:
                version = np.lib.format.read_magic(member)
                read_header = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
                if version not in read_header:
                    raise ValueError(f"unsupported .npy format version {version}")
                shape, _, dtype = read_header[version](member)
                offset = member.tell()
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, PointCloudError):
            raise
        raise PointCloudError(f"point cloud {p}: not a readable .npz file ({exc})") from exc
    if dtype.hasobject or dtype.kind not in "iuf":
        raise PointCloudError(f"point cloud {p}: 'points' must be numeric (real numbers), got dtype {dtype}")
    if len(shape) != 2 or shape[1] != 3:
        raise PointCloudError(f"point cloud {p}: points must be an (N, 3) array, got shape {shape}")
    _check_count(p, shape[0])
    need = shape[0] * 3 * dtype.itemsize
    if info.file_size - offset < need:
        raise PointCloudError(
            f"point cloud {p}: truncated: its header claims {shape[0]:,} points ({need:,} bytes), "
            f"the archive holds {max(0, info.file_size - offset):,} bytes of them"
        )


def _check_count(p: Path, n: int) -> None:
    if n > MAX_POINTS:
        raise PointCloudError(
            f"point cloud {p}: holds {n:,} points, more than the {MAX_POINTS:,} planbench reads "
            "(planbench.geometry.pointcloud.MAX_POINTS); thin it to one point per cube of edge 2 r (nothing is lost)"
        )


_PLY_SIZES = {
    **dict.fromkeys(("char", "uchar", "int8", "uint8"), 1),
    **dict.fromkeys(("short", "ushort", "int16", "uint16"), 2),
    **dict.fromkeys(("int", "uint", "float", "int32", "uint32", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}


def _check_ply(p: Path, size: int) -> None:
    """Refuse a PLY whose header is missing, claims a negative or too large vertex count, or
    claims more vertices than the bytes after it can hold (before trimesh allocates for them)."""
    with open(p, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise PointCloudError(
            f"point cloud {p}: not a readable PLY file (no 'ply ... end_header' header in its first 64 kB)"
        )
    body = end + len(b"end_header")
    body += 2 if head[body : body + 2] == b"\r\n" else 1
    lines = head[:end].decode("ascii", errors="replace").splitlines()
    fmt = ""
    elements: list[tuple[str, int, list[int | None]]] = []  # (name, count, [property sizes; None for a list])
    for line in lines:
        words = line.split()
        if words[:1] == ["format"] and len(words) >= 2:
            fmt = words[1]
        elif words[:1] == ["element"] and len(words) == 3:
            try:
                count = int(words[2])
            except ValueError:
                raise PointCloudError(
                    f"point cloud {p}: not a readable PLY file (element count {words[2]!r})"
                ) from None
            if count < 0:
                raise PointCloudError(f"point cloud {p}: not a readable PLY file (element {words[1]} count {count})")
            elements.append((words[1], count, []))
        elif words[:1] == ["property"] and elements:
            elements[-1][2].append(
                None if words[1:2] == ["list"] else _PLY_SIZES.get(words[1] if len(words) > 1 else "")
            )
    vertex = [e for e in elements if e[0] == "vertex"]
    if not vertex:
        raise PointCloudError(f"point cloud {p}: no vertices in the PLY file")
    _, count, props = vertex[0]
    _check_count(p, count)
    before = elements[: elements.index(vertex[0])]
    if fmt.startswith("binary") and all(None not in e[2] for e in (*before, vertex[0])):
        need = sum(c * sum(z for z in s if z is not None) for _, c, s in (*before, vertex[0]))  # no None: checked
    else:  # ASCII (or variable-length records): at least one digit and a separator per value
        need = count * 2 * max(1, len(props))
    if size - body < need:
        raise PointCloudError(
            f"point cloud {p}: truncated: its header claims {count:,} vertices (at least {need:,} bytes), "
            f"the file holds {max(0, size - body):,} bytes after the header"
        )


def _read_ply(p: Path, size: int) -> np.ndarray:
    import trimesh

    _check_ply(p, size)
    try:
        loaded = trimesh.load(str(p), file_type="ply", process=False)
    except Exception as exc:  # trimesh raises many types on a bad file: report them all as one
        raise PointCloudError(f"point cloud {p}: not a readable PLY file ({exc})") from exc
    vertices = getattr(loaded, "vertices", None)
    if vertices is None:
        raise PointCloudError(f"point cloud {p}: no vertices in the PLY file")
    return np.asarray(vertices, dtype=np.float64)


def write_points(path: str | Path, points: np.ndarray) -> None:
    """Save (N, 3) points [m] as a compressed ``.npz`` (array ``points``, float32: sub-micrometre
    rounding at arm scale, half the size)."""
    pts = np.asarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise PointCloudError(f"points must be an (N, 3) array, got shape {pts.shape}")
    np.savez_compressed(Path(path), points=pts)


def _keys(idx: np.ndarray) -> np.ndarray:
    """One int64 per lattice index (M, 3)."""
    u = (np.asarray(idx, dtype=np.int64) + _OFFSET).T
    return (u[0] << 42) | (u[1] << 21) | u[2]


@dataclass(frozen=True, eq=False)
class VoxelCloud:
    """The union of lattice cubes of edge ``cell`` [m] that hold a point (module docstring), in the
    obstacle's frame. ``cells`` (M, 3): the cubes' integer lattice indices, unique."""

    cells: np.ndarray
    cell: float
    n_points: int = 0
    _sorted_keys: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        cells = np.asarray(self.cells, dtype=np.int64).reshape(-1, 3)
        keys = _keys(cells)
        order = np.argsort(keys)
        object.__setattr__(self, "cells", cells[order])
        object.__setattr__(self, "_sorted_keys", keys[order])

    @classmethod
    def from_points(cls, points: np.ndarray, cell: float) -> VoxelCloud:
        """The cubes of edge ``cell`` [m] holding the (N, 3) ``points`` [m]."""
        if not (math.isfinite(cell) and cell > 0):
            raise PointCloudError(f"cell size must be > 0 [m], got {cell}")
        if len(points) > MAX_POINTS:
            raise PointCloudError(
                f"{len(points):,} points are more than the {MAX_POINTS:,} planbench voxelises "
                "(planbench.geometry.pointcloud.MAX_POINTS)"
            )
        pts = np.asarray(points, dtype=float)
        idx = np.floor(pts / cell).astype(np.int64)
        if len(idx) and np.abs(idx + 0.5).max() >= _LIMIT:
            raise PointCloudError(
                f"points reach {np.abs(pts).max():.3g} m from the origin, beyond the octree's "
                f"{_LIMIT * cell:.3g} m at {cell} m cells; are they in metres, in the base frame?"
            )
        return cls(np.unique(idx, axis=0), float(cell), len(pts))

    def __len__(self) -> int:
        return len(self.cells)

    @functools.cached_property
    def centres(self) -> np.ndarray:
        """(M, 3) cube centres [m]."""
        return (self.cells + 0.5) * self.cell

    @functools.cached_property
    def _tree(self) -> Any:
        from scipy.spatial import cKDTree

        return cKDTree(self.centres)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) corners [m] of the cubes' bounding box."""
        return self.cells.min(axis=0) * self.cell, (self.cells.max(axis=0) + 1) * self.cell

    def occupied(self, idx: np.ndarray) -> np.ndarray:
        """Whether each lattice index (K, 3) is an occupied cube."""
        keys = _keys(np.asarray(idx).reshape(-1, 3))
        pos = np.clip(np.searchsorted(self._sorted_keys, keys), 0, len(self._sorted_keys) - 1)
        return np.asarray(self._sorted_keys[pos] == keys)

    def octree(self) -> Any:
        """coal's OcTree of the cubes: built from their centres at resolution ``cell``, so its
        occupied leaves are the cubes (a fresh object per call; ~10 ms for 50k cubes)."""
        import coal

        return coal.makeOctree(self.centres, self.cell)

    @functools.cached_property
    def surface(self) -> Any:
        """The union's boundary as a coal triangle mesh (BVH): every cube face whose neighbour
        cube is empty, two triangles each. Outside the union, a body's distance to it is its
        distance to this surface, and coal answers mesh-to-mesh distances about a hundred times
        faster than mesh-to-octree ones (see ``docs/robots-and-problems.md``). Built once, shared:
        read-only."""
        import coal

        quads = []
        for axis in range(3):
            for side in (-1, 1):
                step = np.zeros(3, dtype=np.int64)
                step[axis] = side
                exposed = self.cells[~self.occupied(self.cells + step)]
                quads.append(exposed[:, None, :] + _face_corners(axis, side)[None])
        corners = np.concatenate(quads)  # (F, 4, 3) lattice corners, counter-clockwise seen from outside
        keys, index = np.unique(_keys(corners.reshape(-1, 3)), return_inverse=True)
        index = index.reshape(-1, 4)
        triangles = np.concatenate([index[:, [0, 1, 2]], index[:, [0, 2, 3]]]).astype(np.int64)
        vertices = _unkey(keys) * self.cell
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(triangles), len(vertices))
        bvh.addVertices(vertices)
        bvh.addTriangles(triangles)
        bvh.endModel()
        return bvh

    # --- distances ------------------------------------------------------------------------------
    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Exact signed distance [m] from (N, 3) points to the union of cubes, negative inside."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        out = np.empty(len(pts))
        inside = self.occupied(np.floor(pts / self.cell))
        out[~inside] = self._outside_distance(pts[~inside])
        out[inside] = -self._depth(pts[inside])
        return out

    def _box_distance(self, pts: np.ndarray, centres: np.ndarray) -> np.ndarray:
        gap = np.maximum(np.abs(pts - centres) - 0.5 * self.cell, 0.0)
        return np.asarray(np.sqrt(np.einsum("...a,...a->...", gap, gap)))

    def _outside_distance(self, pts: np.ndarray) -> np.ndarray:
        """Distance to the nearest cube: the nearest centres first, then every centre that could
        be closer (a cube lies within half a diagonal of its centre)."""
        if len(pts) == 0:
            return np.zeros(0)
        k = min(8, len(self.cells))
        dist, nn = self._tree.query(pts, k=k)
        dist, nn = dist.reshape(len(pts), k), nn.reshape(len(pts), k)
        best = self._box_distance(pts[:, None, :], self.centres[nn]).min(axis=1)
        reach = best + 0.5 * math.sqrt(3.0) * self.cell
        unsure = np.flatnonzero((dist[:, -1] < reach) & (k < len(self.cells)))
        for i, near in zip(unsure, self._tree.query_ball_point(pts[unsure], reach[unsure]), strict=True):
            if near:
                best[i] = min(best[i], float(self._box_distance(pts[i], self.centres[near]).min()))
        return best

    def _depth(self, pts: np.ndarray) -> np.ndarray:
        """Distance from points inside cubes to the nearest free cell, searched in growing shells of
        neighbours: a cell in shell ``L`` (Chebyshev) is at least ``(L - 1) cell`` away, so the
        search stops once the best found is within that."""
        depth = np.full(len(pts), np.inf)
        own = np.floor(pts / self.cell).astype(np.int64)
        todo = np.arange(len(pts))
        shell = 1
        while len(todo):
            offsets = _shell(shell)
            cand = own[todo, None, :] + offsets[None, :, :]
            free = ~self.occupied(cand.reshape(-1, 3)).reshape(cand.shape[:2])
            d = self._box_distance(pts[todo, None, :], (cand + 0.5) * self.cell)
            d = np.where(free, d, np.inf).min(axis=1)
            depth[todo] = np.minimum(depth[todo], d)
            todo = todo[depth[todo] > shell * self.cell]
            shell += 1
        return depth

    # --- voxelisation ---------------------------------------------------------------------------
    def cover(
        self, rotation: np.ndarray, position: np.ndarray, origin: np.ndarray, resolution: float, i0: Any, i1: Any
    ) -> np.ndarray:
        """Which grid cells ``i0 .. i1`` (exclusive; grid ``origin`` [m], ``resolution`` [m/cell])
        overlap a cube, with the cloud placed at (``rotation``, ``position``): 1.0 when the cell's
        interior meets a cube's (faces that only touch do not count), else 0.0. Exact: interval
        overlap when the cloud is axis-aligned, a separating-axis test otherwise."""
        i0, i1 = np.asarray(i0), np.asarray(i1)
        out = np.zeros(tuple(i1 - i0))
        R = np.asarray(rotation, dtype=float)
        h = 0.5 * self.cell
        centres = self.centres @ R.T + np.asarray(position, dtype=float)
        half = np.abs(R) @ np.full(3, h)
        tol = 1e-9
        lo = np.floor((centres - half - origin) / resolution + tol).astype(np.int64)
        hi = np.ceil((centres + half - origin) / resolution - tol).astype(np.int64)  # exclusive
        span = int((hi - lo).max())
        axis_aligned = bool(np.allclose(R, np.eye(3), atol=1e-12))
        if span**3 > max(64, len(centres)):  # cubes larger than grid cells: fewer cubes than offsets
            self._cover_per_cube(out, lo, hi, i0, i1, centres, R, axis_aligned, origin, resolution)
            return out
        for off in itertools.product(range(span), repeat=3):  # a cube spans at most `span` cells per axis
            idx = lo + np.array(off)
            keep = np.all((idx < hi) & (idx >= i0) & (idx < i1), axis=1)
            if not keep.any():
                continue
            idx = idx[keep]
            if not axis_aligned:
                grid_centres = origin + (idx + 0.5) * resolution
                idx = idx[cubes_overlap_boxes(grid_centres, 0.5 * resolution, centres[keep], R, np.full(3, h), 1e-9)]
            out[tuple((idx - i0).T)] = 1.0
        return out

    def _cover_per_cube(
        self,
        out: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        i0: np.ndarray,
        i1: np.ndarray,
        centres: np.ndarray,
        R: np.ndarray,
        axis_aligned: bool,
        origin: np.ndarray,
        resolution: float,
    ) -> None:
        """:meth:`cover` one cube at a time (cubes of many grid cells): its block of grid cells
        at once when the cloud is axis-aligned, else tested in slabs of at most ~1M cells."""
        a, b = np.maximum(lo, i0), np.minimum(hi, i1)
        for k in np.flatnonzero(np.all(b > a, axis=1)):
            (x0, y0, z0), (x1, y1, z1) = a[k], b[k]
            if axis_aligned:
                out[x0 - i0[0] : x1 - i0[0], y0 - i0[1] : y1 - i0[1], z0 - i0[2] : z1 - i0[2]] = 1.0
                continue
            yz = np.stack(np.meshgrid(np.arange(y0, y1), np.arange(z0, z1), indexing="ij"), -1).reshape(-1, 2)
            step = max(1, (1 << 20) // len(yz))
            for x in range(x0, x1, step):
                xs = np.arange(x, min(x + step, x1))
                idx = np.column_stack([np.repeat(xs, len(yz)), np.tile(yz, (len(xs), 1))])
                grid_centres = origin + (idx + 0.5) * resolution
                hit = cubes_overlap_boxes(
                    grid_centres, 0.5 * resolution, centres[k], R, np.full(3, 0.5 * self.cell), 1e-9
                )
                out[tuple((idx[hit] - i0).T)] = 1.0


def _unkey(keys: np.ndarray) -> np.ndarray:
    """Lattice indices (M, 3) of keys made by :func:`_keys`."""
    mask = (1 << 21) - 1
    return np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], axis=1) - _OFFSET


def _face_corners(axis: int, side: int) -> np.ndarray:
    """The 4 corners (offsets from a cube's lower corner) of its face on ``side`` of ``axis``,
    counter-clockwise seen from outside."""
    u, v = (axis + 1) % 3, (axis + 2) % 3
    base = np.zeros(3, dtype=np.int64)
    base[axis] = 1 if side > 0 else 0
    du, dv = np.eye(3, dtype=np.int64)[u], np.eye(3, dtype=np.int64)[v]
    ring = [base, base + du, base + du + dv, base + dv]
    return np.array(ring if side > 0 else ring[::-1])


def _shell(n: int) -> np.ndarray:
    """Lattice offsets at Chebyshev distance exactly ``n``."""
    r = np.arange(-n, n + 1)
    cube = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    return cube[np.abs(cube).max(axis=1) == n]


@functools.lru_cache(maxsize=16)
def _cached_cloud(path: str, mtime_ns: int, size: int, cell: float) -> VoxelCloud:
    return VoxelCloud.from_points(read_points(path), cell)


def load_cloud(path: str | Path, radius: float) -> VoxelCloud:
    """The voxel geometry of a cloud file with point radius ``radius`` [m] (cubes of edge
    ``2 radius``), cached per file version and radius: a scene loaded by many workers or checkers
    reads its cloud once per process."""
    if not (math.isfinite(radius) and radius > 0):
        raise PointCloudError(f"point radius must be > 0 [m], got {radius}")
    p = Path(path)
    try:
        st = regular_file(p)
    except InputFileError:
        read_points(p)  # raises the right error (not found, not a regular file, bad suffix)
        raise
    return _cached_cloud(str(p.resolve()), st.st_mtime_ns, st.st_size, 2.0 * float(radius))
