"""MoveIt's text scene format (``.scene``), read into planbench's scene JSON and written from it.

MoveIt saves the world geometry of a planning scene as text (``PlanningScene::saveGeometryToStream``,
RViz's motion planning panel "Export"; read back by ``loadGeometryFromStream``), each shape as
geometric_shapes writes it (``shapes::saveAsText``)::

    <scene name>                     # the whole first line
    * <object id>                    # each object: the rest of its line
    px py pz                         # the object's pose (MoveIt >= 1.1 and MoveIt 2 only)
    qx qy qz qw
    <number of shapes>
    <shape>                          # each shape: its type and dimensions, below
    px py pz                         # the shape's pose: in the object's frame (new layout),
    qx qy qz qw                      # in the scene's frame (old layout: no object pose)
    r g b a                          # the object's colour (0 0 0 0: none)
    <number of subframes>            # new layout only; each: its name, then a pose
    .

Shapes: ``box`` then ``x y z`` (full edge lengths [m]); ``sphere`` then ``radius``; ``cylinder``
then ``radius length`` (along its local z, as planbench's); ``cone`` then ``radius length``;
``plane`` then ``a b c d``; ``mesh`` then ``V T``, V lines ``x y z`` and T lines ``i j k``
(0-based vertex indices). Quaternions are scalar last (Eigen's ``x y z w``). Past the name line,
MoveIt reads whitespace-separated tokens; it tells the layouts apart by the line after the first
``*`` line: a pose line holds several numbers, a shape count one.

What planbench makes of it (:func:`read_moveit_scene`): each shape becomes one obstacle, named by
its object's id (``<id>/<k>``, k from 0, for an object of several shapes), at the object's pose
composed with the shape's. A mesh is written as an OBJ file (full precision) into ``mesh_dir``,
named by a hash of its vertices and triangles, because planbench's mesh obstacles are files that
coal and trimesh load (:func:`default_mesh_dir`: the user's cache, so that reading a scene writes
nothing next to it). Colours and subframes are read and dropped: no planbench obstacle has them.
Cones and planes are refused (planbench has no such obstacle). MoveIt writes 6 significant digits,
so a quaternion's norm may be off 1 by about 1e-6: it is normalised when within
:data:`QUATERNION_TOLERANCE`. A malformed file raises :class:`MoveItSceneError` naming its line.

:func:`write_moveit_scene` writes the new layout, one object per obstacle (its pose the object's,
the shape's the identity), numbers in the shortest form that reads back exactly.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.errors import PlanbenchError, ProblemFileError
from planbench.files.inputs import InputFileError, read_text

__all__ = [
    "QUATERNION_TOLERANCE",
    "SUFFIX",
    "MoveItSceneError",
    "default_mesh_dir",
    "format_moveit_scene",
    "parse_moveit_scene",
    "read_moveit_scene",
    "write_moveit_scene",
]

SUFFIX = ".scene"
QUATERNION_TOLERANCE = 1e-3
"""How far from 1 a quaternion's norm may be; it is then normalised (MoveIt's 6 digits: ~1e-6)."""

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")
_COUNT = re.compile(r"\d+\Z")
_WORD = re.compile(r"\S+")
_END = "an object ('* <id>') or the end of the scene ('.')"


class MoveItSceneError(ProblemFileError):
    """A ``.scene`` file that cannot be used, or a scene that cannot be written as one; ``line`` is
    the 1-based line at fault (None when no one line is)."""

    def __init__(self, path: object, problem: str, line: int | None = None) -> None:
        self.line = line
        super().__init__(path, f"line {line}: {problem}" if line else problem)


def default_mesh_dir() -> Path:
    """Where a ``.scene`` file's meshes go unless told: ``$XDG_CACHE_HOME/planbench/moveit-meshes``
    (``~/.cache`` without it). Files there are named by their content, so it only ever grows by
    new meshes and may be deleted at any time (the next read writes them again)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "planbench" / "moveit-meshes"


# --- reading -------------------------------------------------------------------------------------
class _Tokens:
    """The tokens after the name line, read as MoveIt's ``>>`` reads them, with their line numbers."""

    def __init__(self, lines: Sequence[str], source: str) -> None:
        self.lines = lines
        self.source = source
        self.line = 1  # 1-based line of the last token read
        self._next_row = 1  # index of the next line to split
        self._words: list[re.Match[str]] = []
        self._at = 0

    def fail(self, problem: str, line: int | None = None) -> MoveItSceneError:
        return MoveItSceneError(self.source, problem, line or self.line)

    def _word(self, what: str) -> re.Match[str]:
        while self._at >= len(self._words):
            if self._next_row >= len(self.lines):
                last = max((k + 1 for k, text in enumerate(self.lines) if text.strip()), default=1)
                raise self.fail(f"the file ends where {what} should be (is it cut short?)", last)
            self._words = list(_WORD.finditer(self.lines[self._next_row]))
            self._at = 0
            self._next_row += 1
            self.line = self._next_row
        self._at += 1
        return self._words[self._at - 1]

    def token(self, what: str) -> str:
        return self._word(what).group()

    def rest_of_line(self) -> str:
        """The text after the last token on its line (an object's id), trimmed."""
        rest = self.lines[self.line - 1][self._words[self._at - 1].end() :].strip()
        self._at = len(self._words)
        return rest

    def numbers(self, n: int, what: str) -> np.ndarray:
        """The next ``n`` numbers (gathered one by one: a count the file cannot hold ends at its end,
        never in an allocation of that size)."""
        out = []
        for _ in range(n):
            text = self.token(what)
            value = float(text) if _NUMBER.match(text) else math.nan
            if not math.isfinite(value):
                raise self.fail(f"{what} must be a finite number, got {text!r}")
            out.append(value)
        return np.array(out, dtype=np.float64)

    def positive(self, what: str) -> float:
        value = float(self.numbers(1, what)[0])
        if value <= 0:
            raise self.fail(f"{what} must be > 0, got {value:g}")
        return value

    def counts(self, n: int, what: str, below: int | None = None) -> list[int]:
        out = []
        for _ in range(n):
            text = self.token(what)
            if not _COUNT.match(text):
                raise self.fail(f"{what} must be a whole number >= 0, got {text!r}")
            value = int(text)
            if below is not None and value >= below:
                raise self.fail(f"{what} must be below {below}, got {value}")
            out.append(value)
        return out

    def pose(self, what: str) -> tuple[np.ndarray, np.ndarray]:
        """(position [m], unit quaternion x y z w)."""
        position = self.numbers(3, f"{what}: the position x y z")
        q = self.numbers(4, f"{what}: the quaternion x y z w")
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise self.fail(f"{what}: the quaternion x y z w = {q.tolist()} is not a rotation (norm {norm:.6g}, not 1)")
        return position, q / norm


def read_moveit_scene(path: str | Path, mesh_dir: str | Path | None = None) -> dict[str, Any]:
    """The scene in a MoveIt ``.scene`` file as a ``planbench-scene/1`` object (what
    :meth:`planbench.scene.Scene.from_dict` reads); its meshes are written into ``mesh_dir``
    (:func:`default_mesh_dir` when None). :class:`MoveItSceneError` for a file that cannot be used."""
    try:
        text = read_text(path)
    except InputFileError as exc:
        raise MoveItSceneError(path, exc.problem) from None
    return parse_moveit_scene(text, str(path), Path(mesh_dir) if mesh_dir is not None else default_mesh_dir())


def parse_moveit_scene(text: str, source: str, mesh_dir: Path) -> dict[str, Any]:
    """:func:`read_moveit_scene` on the file's text (``source`` names it in errors)."""
    lines = [line.rstrip("\r") for line in text.split("\n")]
    if not text.strip():
        raise MoveItSceneError(source, "the file is empty; a MoveIt scene is its name, its objects, then '.'", 1)
    new_layout = _new_layout(lines)
    tokens = _Tokens(lines, source)
    obstacles: list[dict[str, Any]] = []
    seen: dict[str, int] = {}
    while True:
        marker = tokens.token(_END)
        if marker == ".":
            break
        if marker != "*":
            raise tokens.fail(f"expected {_END}, got {marker!r}")
        line = tokens.line
        oid = tokens.rest_of_line()
        if not oid:
            raise tokens.fail("an object line '*' without the object's id")
        if oid in seen:
            raise tokens.fail(
                f"object {oid!r} appears twice (lines {seen[oid]} and {line}); MoveIt would keep the last one "
                "only: remove or rename one"
            )
        seen[oid] = line
        obstacles.extend(_read_object(tokens, oid, new_layout, mesh_dir))
    return {"name": lines[0].strip() or Path(source).stem, "obstacles": obstacles}


def _new_layout(lines: Sequence[str]) -> bool:
    """MoveIt's test: the line after the first ``*`` line is an object pose (several numbers) in
    the new layout, a shape count in the old one."""
    for k in range(1, len(lines)):
        if lines[k].startswith("*"):
            return k + 1 < len(lines) and len(lines[k + 1].split()) > 1
    return False


def _read_object(tokens: _Tokens, oid: str, new_layout: bool, mesh_dir: Path) -> list[dict[str, Any]]:
    where = f"object {oid!r}"
    object_pose = tokens.pose(f"{where}: its pose") if new_layout else None
    (n,) = tokens.counts(1, f"{where}: the number of shapes")
    out = []
    for k in range(n):
        what = f"{where}, shape {k + 1} of {n}"
        shape = _read_shape(tokens, what, mesh_dir)
        position, q = tokens.pose(f"{what}: its pose")
        tokens.numbers(4, f"{what}: the colour r g b a")
        if object_pose is not None:
            q_object = pin.Quaternion(object_pose[1])
            position = object_pose[0] + q_object * position
            q = (q_object * pin.Quaternion(q)).normalized().coeffs()
        name = oid if n == 1 else f"{oid}/{k}"
        out.append({"name": name, **shape, "position": position.tolist(), "orientation_xyzw": list(map(float, q))})
    if new_layout:
        (m,) = tokens.counts(1, f"{where}: the number of subframes")
        for j in range(m):
            tokens.token(f"{where}: the name of subframe {j + 1}")
            tokens.pose(f"{where}: subframe {j + 1}'s pose")
    return out


def _read_shape(tokens: _Tokens, what: str, mesh_dir: Path) -> dict[str, Any]:
    kind = tokens.token(f"{what}: its type")
    if kind == "box":
        return {"type": "box", "size": [tokens.positive(f"{what}: box size {a}") for a in "xyz"]}
    if kind == "sphere":
        return {"type": "sphere", "radius": tokens.positive(f"{what}: sphere radius")}
    if kind == "cylinder":
        radius = tokens.positive(f"{what}: cylinder radius")
        return {"type": "cylinder", "radius": radius, "length": tokens.positive(f"{what}: cylinder length")}
    if kind == "cone":
        raise tokens.fail(
            f"{what} is a cone, and planbench has no cone obstacle: replace it in MoveIt by a cylinder of its "
            "radius and length (which holds it) or by a mesh, and export the scene again"
        )
    if kind == "plane":
        raise tokens.fail(
            f"{what} is a plane (infinite), and planbench's obstacles are bounded: replace it in MoveIt by a "
            "thin box where it matters (say 2 x 2 x 0.01 m) and export the scene again"
        )
    if kind == "mesh":
        return {"type": "mesh", "path": str(_read_mesh(tokens, what, mesh_dir))}
    raise tokens.fail(f"{what}: unknown shape type {kind!r}; MoveIt writes box, sphere, cylinder, cone, plane or mesh")


def _read_mesh(tokens: _Tokens, what: str, mesh_dir: Path) -> Path:
    nv, nt = tokens.counts(2, f"{what}: the mesh's vertex and triangle counts")
    if nt == 0:
        raise tokens.fail(f"{what}: a mesh without triangles")
    vertices = tokens.numbers(3 * nv, f"{what}: a mesh vertex coordinate").reshape(nv, 3)
    triangles = np.array(tokens.counts(3 * nt, f"{what}: a mesh triangle's vertex index", below=nv)).reshape(nt, 3)
    return _write_obj(vertices, triangles, mesh_dir, what)


def _write_obj(vertices: np.ndarray, triangles: np.ndarray, mesh_dir: Path, what: str) -> Path:
    """The mesh as an OBJ file in ``mesh_dir``, named by its content (written once, atomically:
    benchmark workers may read the same scene at once)."""
    digest = hashlib.sha256(vertices.astype("<f8").tobytes() + triangles.astype("<i8").tobytes()).hexdigest()
    target = mesh_dir / f"moveit-mesh-{digest[:24]}.obj"
    if target.is_file():
        return target
    lines = ["# a mesh of a MoveIt .scene file, written by planbench"]
    lines += [f"v {_num(x)} {_num(y)} {_num(z)}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
    try:
        mesh_dir.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=mesh_dir, prefix=".moveit-mesh-", suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            f.write("\n".join(lines) + "\n")
        os.replace(tmp, target)
    except OSError as exc:
        raise PlanbenchError(
            f"cannot write the mesh of {what} into {mesh_dir}: {exc.strerror or exc}; "
            "give Scene.load a mesh_dir where planbench may write"
        ) from None
    return target


# --- writing -------------------------------------------------------------------------------------
def write_moveit_scene(scene: Mapping[str, Any], path: str | Path) -> None:
    """Write a ``planbench-scene/1`` object (``Scene.to_dict()``) as a MoveIt ``.scene`` file."""
    Path(path).write_text(format_moveit_scene(scene, str(path)))


def format_moveit_scene(scene: Mapping[str, Any], target: str = "<scene>") -> str:
    """The text of :func:`write_moveit_scene` (``target`` names the file in errors): the new layout,
    one object per obstacle. Capsules and point clouds have no MoveIt shape: MoveItSceneError."""
    out = [_one_line(str(scene.get("name", "scene")), "the scene's name", target, empty_ok=True)]
    for o in scene.get("obstacles", []):
        name = _one_line(str(o["name"]), "obstacle name", target)
        out += [f"* {name}", _nums(o["position"]), _nums(o["orientation_xyzw"]), "1"]
        out += _shape_lines(o, target)
        out += ["0 0 0", "0 0 0 1", "0 0 0 0", "0"]
    out.append(".")
    return "\n".join(out) + "\n"


def _shape_lines(o: Mapping[str, Any], target: str) -> list[str]:
    kind = o["type"]
    if kind == "box":
        return ["box", _nums(o["size"])]
    if kind == "sphere":
        return ["sphere", _num(o["radius"])]
    if kind == "cylinder":
        return ["cylinder", _nums([o["radius"], o["length"]])]
    if kind == "mesh":
        vertices, triangles = _mesh_arrays(o, target)
        return [
            "mesh",
            f"{len(vertices)} {len(triangles)}",
            *(_nums(v) for v in vertices),
            *(" ".join(map(str, t)) for t in triangles),
        ]
    raise MoveItSceneError(
        target,
        f"obstacle {o['name']!r} is a {kind}, which MoveIt's scene format has no shape for; "
        "save the scene as .json, or replace the obstacle by boxes, spheres, cylinders or a mesh",
    )


def _mesh_arrays(o: Mapping[str, Any], target: str) -> tuple[np.ndarray, np.ndarray]:
    """A mesh obstacle's vertices (scaled) [m] and triangles, in its file's order."""
    import trimesh

    mesh: Any = None
    try:
        mesh = trimesh.load(str(o["path"]), force="mesh", process=False)
    except Exception:  # trimesh raises many types on a file it cannot read: report them all as one
        pass
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MoveItSceneError(target, f"obstacle {o['name']!r}: trimesh cannot read the triangles of {o['path']}")
    s = np.asarray(o.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
    triangles = np.asarray(mesh.faces, dtype=np.int64)
    if np.prod(np.sign(s)) < 0:  # a mirror: keep the triangles facing out
        triangles = triangles[:, ::-1]
    return np.asarray(mesh.vertices, dtype=np.float64) * s, triangles


def _one_line(name: str, what: str, target: str, empty_ok: bool = False) -> str:
    if "\n" in name or "\r" in name or name != name.strip() or not (name or empty_ok):
        raise MoveItSceneError(
            target, f"{what} {name!r} cannot be written: MoveIt reads a name as one line, trimmed, and not empty"
        )
    return name


def _num(x: Any) -> str:
    """A number as the shortest text that reads back to the same float (``1``, not ``1.0``)."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def _nums(xs: Any) -> str:
    return " ".join(_num(x) for x in xs)
