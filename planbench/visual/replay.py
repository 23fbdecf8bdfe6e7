"""A 3D replay of a path in one self-contained HTML file: open it in any browser, offline, no server.

Built on pinocchio's meshcat integration (``pinocchio.visualize.MeshcatVisualizer``) and meshcat's
static HTML export (``Visualizer.static_html``): the robot's collision meshes and the obstacles
(the same geometry the certified checker uses), the path as a meshcat animation (play, pause and a
time slider in the page's "Animations" controls), moving obstacles of a scenario moving with it,
and the occupancy grid the matrix field sees (scene tree "grid", hidden until switched on). No
hand-written WebGL; the page holds meshcat's own viewer and the scene as data.

What the page explains by itself:

- it opens with the arm at the path's first configuration (every body's placement is in the
  scene, not only in the animation); a run without a path shows the problem's start;
- a panel (top left) says what was run and what came of it, from a :class:`ReplayInfo` (the
  results row or the evaluation, never recomputed here): problem, robot, planner and its
  settings, verdict (success, or the validator's failure text), path length, minimum clearance,
  planning time; for a collision, where (segment, fraction, time on the replay's clock), the
  pair, the colliding robot link drawn in red at that configuration and the obstacle in red, and a
  button that moves the animation there. The same values are in the page as JSON
  (``<script type="application/json" id="planbench-replay">``);
- point-cloud obstacles (coal octrees) are one points object, a point per occupied cube at its
  centre, not a mesh of cubes.

Frames: at most :data:`MAX_FRAMES`, in real time: the path's own time stamps when it has them (a
closed-loop run, a timed planner), else each segment at the joints' velocity limits. Only bodies
that move are animated.
"""

from __future__ import annotations

import contextlib
import dataclasses
import html
import io
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.checking.collision import CollisionChecker
from planbench.errors import PlanbenchError
from planbench.files.outputs import check_output
from planbench.robot import link_of

__all__ = ["MAX_FRAMES", "ReplayInfo", "replay_html", "write_replay"]

MAX_FRAMES = 600
FPS = 30
ARM = (0.95, 0.55, 0.15, 1.0)
OBSTACLE = (0.55, 0.6, 0.7, 0.45)
HIT = (0.9, 0.15, 0.15, 0.75)  # the colliding link, drawn again where the collision is
HIT_OBSTACLE = (0.9, 0.2, 0.2, 0.4)  # the obstacle it hits


@dataclasses.dataclass(frozen=True)
class ReplayInfo:
    """What a replay's panel says about the run: taken from its evaluation or results row, not
    recomputed. Lengths [rad] (joint path) and [m] (clearance), times [s]; NaN: not measured.
    ``success`` None: no verdict to show (a path shown without a validation)."""

    problem: str = ""
    robot: str = ""
    planner: str = ""
    settings: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    seed: int | None = None
    success: bool | None = None
    failure: str = ""  # as the validator wrote it
    status: str = ""  # what the planner claimed
    path_length: float = math.nan  # joint-space [rad]
    min_clearance: float = math.nan  # [m]
    planning_time: float = math.nan  # [s]
    collision_segment: int = -1  # first segment in collision (-1: none)
    collision_fraction: float = math.nan  # where along it, 0 to 1
    collision_pair: str = ""  # "<robot link> / <link or obstacle:name>"

    @classmethod
    def from_row(cls, row: Mapping[str, Any], **given: Any) -> ReplayInfo:
        """From a results-file row, ``planbench plan``'s row or an :class:`~planbench.Evaluation`'s
        ``as_dict()`` (missing keys stay unknown); ``given`` sets fields outright."""
        settings = row.get("planner_settings")
        if isinstance(settings, str):
            try:
                settings = json.loads(settings)
            except ValueError:
                settings = {"settings": settings}
        length = row.get("joint_path_length")
        if _nan(length) and not _nan(row.get("path_length")):
            length = row.get("path_length")  # a closed-loop run's executed trajectory
        seed, segment = row.get("seed"), row.get("collision_segment")
        fields = {
            "problem": str(row.get("problem") or ""),
            "planner": str(row.get("planner") or ""),
            "settings": dict(settings) if isinstance(settings, Mapping) else {},
            "seed": None if seed is None else int(seed),
            "success": None if row.get("success") is None else bool(row["success"]),
            "failure": str(row.get("failure") or ""),
            "status": str(row.get("status") or ""),
            "path_length": _float(length),
            "min_clearance": _float(row.get("min_clearance")),
            "planning_time": _float(row.get("planning_time")),
            "collision_segment": -1 if segment is None or _nan(segment) else int(segment),
            "collision_fraction": _float(row.get("collision_fraction")),
            "collision_pair": str(row.get("collision_pair") or ""),
        }
        return cls(**{**fields, **given})

    @property
    def verdict(self) -> str:
        if self.success is None:
            return ""
        return "success (validated)" if self.success else self.failure or f"failed ({self.status or 'no reason'})"


def _float(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def _nan(x: Any) -> bool:
    return not math.isfinite(_float(x))


def _meshcat() -> Any:
    try:
        import meshcat
        import meshcat.animation
        import meshcat.geometry
    except ModuleNotFoundError:
        raise PlanbenchError("a replay needs meshcat: pip install meshcat") from None
    return meshcat


def _timeline(path: np.ndarray, times: np.ndarray | None, vmax: np.ndarray) -> np.ndarray:
    """Time stamps [s] of the path's states: its own, else each segment at the velocity limits."""
    if times is not None and len(times) == len(path):
        return np.asarray(times, dtype=float)
    seg = (np.abs(np.diff(path, axis=0)) / vmax).max(axis=1) if len(path) > 1 else np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(seg)])


def _frames(path: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (at most MAX_FRAMES) states shown, 30 a second, and their time stamps [s]; the first
    is the path's first state."""
    duration = float(times[-1]) if len(times) else 0.0
    n = int(min(MAX_FRAMES, max(2, np.ceil(duration * FPS) + 1)))
    shown = np.linspace(0.0, duration, n)
    q = np.stack([np.interp(shown, times, path[:, j]) for j in range(path.shape[1])], axis=1)
    return shown, q


def _failure_at(info: ReplayInfo | None, path: np.ndarray, times: np.ndarray) -> dict[str, Any] | None:
    """Where the run's collision is on the path (its segment and fraction as the validator wrote
    them), the configuration there and its time on the replay's clock; None without one."""
    if info is None or info.collision_segment < 0 or info.collision_segment >= len(path) - 1:
        return None
    k = info.collision_segment
    f = min(max(info.collision_fraction, 0.0), 1.0) if math.isfinite(info.collision_fraction) else 0.0
    q = path[k] + f * (path[k + 1] - path[k])
    return {
        "segment": k,
        "segments": len(path) - 1,
        "fraction": f,
        "time": float(times[k] + f * (times[k + 1] - times[k])),
        "configuration": [float(x) for x in q],
        "pair": info.collision_pair,
    }


def _is_octree(geometry: Any) -> bool:
    return type(geometry).__name__ == "OcTree"


def _cloud_points(octree: Any) -> tuple[np.ndarray, float]:
    """The centres (N, 3) [m] of an octree's occupied cubes at its finest size, and that size [m]:
    leaves octomap merged into bigger cubes are split back into cubes of the finest size."""
    boxes = np.asarray(octree.toBoxes(), dtype=float).reshape(-1, 6)
    if not len(boxes):
        return np.zeros((0, 3)), 0.0
    cell = float(boxes[:, 3].min())
    parts = []
    for size in np.unique(boxes[:, 3]):
        centres = boxes[boxes[:, 3] == size, :3]
        k = max(1, round(size / cell))
        offsets = (np.arange(k) - (k - 1) / 2) * cell
        grid = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 3)
        parts.append((centres[:, None, :] + grid[None]).reshape(-1, 3))
    return np.concatenate(parts), cell


def _points(meshcat: Any, points: np.ndarray, size: float, rgba: tuple[float, ...]) -> Any:
    """One meshcat points object: ``points`` (N, 3) [m], one colour, ``size`` [m] each."""

    class Material(meshcat.geometry.Material):  # meshcat's PointsMaterial wants a colour per point
        def lower(self, object_data: Any) -> dict[str, Any]:
            return {
                "uuid": self.uuid,
                "type": "PointsMaterial",
                "color": _rgb(rgba),
                "size": size,
                "vertexColors": False,
                "transparent": rgba[3] < 1.0,
                "opacity": rgba[3],
            }

    return meshcat.geometry.Points(meshcat.geometry.PointsGeometry(points.T.astype(np.float32)), Material())


def _rgb(rgba: tuple[float, ...]) -> int:
    return int(rgba[0] * 255) << 16 | int(rgba[1] * 255) << 8 | int(rgba[2] * 255)


def replay_html(
    problem: Any,
    path: np.ndarray | None,
    times: np.ndarray | None = None,
    *,
    geometry: Any = None,
    place: Callable[[float], None] | None = None,
    grid: Any = None,
    title: str = "planbench replay",
    info: ReplayInfo | None = None,
) -> str:
    """The replay page of ``path`` (an (N, nq) array; None or empty: the problem's start) on
    ``problem`` (module docstring) as a string. ``geometry``: the pinocchio geometry model shown
    (default: the robot and the problem's scene); ``place(t)``: puts its moving obstacles where
    they are at ``t`` [s] of the path's ``times`` (a closed-loop run's
    :class:`~planbench.reactive.checker.TickChecker` does); ``grid``: an
    :class:`~planbench.geometry.occupancy.OccupancyGrid` shown on demand; ``info``: what the
    panel says about the run (:class:`ReplayInfo`)."""
    meshcat = _meshcat()
    from pinocchio.visualize import MeshcatVisualizer

    robot = problem.robot
    if path is None or len(path) == 0:
        path, times = np.asarray(problem.start, dtype=float)[None], None
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[1] != robot.nq or not np.isfinite(path).all():
        raise PlanbenchError(f"a replay needs a finite (N, {robot.nq}) path, got shape {path.shape}")
    if geometry is None:
        geometry = CollisionChecker(robot, problem.scene).geometry_model
    if info is None:
        info = ReplayInfo()
    info = dataclasses.replace(info, problem=info.problem or str(problem.id), robot=info.robot or str(robot.name))
    timeline = _timeline(path, times, np.asarray(robot.velocity_limit, dtype=float))
    failure = _failure_at(info, path, timeline)
    hit = set(failure["pair"].split(" / ")) if failure else set()
    objects = list(geometry.geometryObjects)
    n_robot = len(robot.collision_model.geometryObjects)
    for i, g in enumerate(objects):  # the arm orange, obstacles see-through grey, the one hit red
        g.meshColor = np.array(ARM if i < n_robot else HIT_OBSTACLE if g.name in hit else OBSTACLE)
    clouds = {i for i, g in enumerate(objects) if _is_octree(g.geometry)}
    meshes = pin.GeometryModel()  # what pinocchio draws; clouds are drawn here, as points
    for i, g in enumerate(objects):
        if i not in clouds:
            meshes.addGeometryObject(g)
    marked = [i for i, g in enumerate(objects[:n_robot]) if failure and link_of(g.name) in hit]
    marks = []
    for i in marked:  # the colliding link again, red, where it was at the failure
        mark = objects[i].copy()
        mark.name, mark.meshColor = f"failure:{objects[i].name}", np.array(HIT)
        meshes.addGeometryObject(mark)
        marks.append(mark)
    with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints its server's URL: not ours to show
        vis = meshcat.Visualizer()
    try:
        viz = MeshcatVisualizer(robot.model, None, meshes)  # no hidden copy of the scene as "collisions"
        viz.initViewer(viewer=vis)
        viz.loadViewerModel(rootNodeName="planbench")
        nodes = [viz.getViewerNodeName(g, pin.GeometryType.VISUAL) for g in objects]
        for i in clouds:
            points, cell = _cloud_points(objects[i].geometry)
            color = HIT_OBSTACLE if objects[i].name in hit else OBSTACLE
            vis[nodes[i]].set_object(_points(meshcat, points, cell, (*color[:3], 0.8)))
        data, gdata = robot.model.createData(), pin.GeometryData(geometry)
        shown_t, shown_q = _frames(path, timeline)
        placements = np.empty((len(shown_t), len(objects), 4, 4))
        for k, (t, q) in enumerate(zip(shown_t, shown_q, strict=True)):
            if place is not None:
                place(float(t))
            pin.updateGeometryPlacements(robot.model, data, geometry, gdata, q)
            placements[k] = [M.homogeneous for M in gdata.oMg]
        for node, M in zip(nodes, placements[0], strict=True):  # the page opens at the path's start
            vis[node].set_transform(M)
        moving = [int(i) for i in np.flatnonzero(np.abs(placements - placements[:1]).max(axis=(0, 2, 3)) > 1e-12)]
        if len(path) > 1 and moving:
            anim = meshcat.animation.Animation(default_framerate=FPS)
            for k in range(len(shown_t)):
                with anim.at_frame(vis, k) as frame:
                    for j in moving:
                        frame[nodes[j]].set_transform(placements[k, j])
            vis.set_animation(anim, play=False)
        if failure is not None:
            if place is not None:
                place(failure["time"])
            pin.updateGeometryPlacements(robot.model, data, geometry, gdata, np.asarray(failure["configuration"]))
            for i, mark in zip(marked, marks, strict=True):
                vis[viz.getViewerNodeName(mark, pin.GeometryType.VISUAL)].set_transform(gdata.oMg[i].homogeneous)
        vis["/Cameras/default/rotated/<object>"].set_property("position", [2.2, 1.2, 1.6])  # y up in the camera
        vis["/Grid"].set_property("visible", False)  # the base frame's floor plane cuts through tables
        if grid is not None:
            centres = grid.cell_centers()[np.asarray(grid.data) > 0.5]
            if len(centres):
                vis["grid"].set_object(_points(meshcat, centres, grid.resolution, (0.9, 0.3, 0.2, 1.0)))
                vis["grid"].set_property("visible", False)
        page = vis.static_html()
    finally:
        vis.delete()
        _close(vis)
    page = page.replace("<title>MeshCat</title>", f"<title>{html.escape(title)}</title>", 1)
    data_json = {
        "title": title,
        **_json_info(info),
        "verdict": info.verdict,
        "waypoints": len(path),
        "duration": float(timeline[-1]),
        "frames": len(shown_t) if len(path) > 1 else 1,
        "start_configuration": [float(x) for x in path[0]],
        "failure_at": failure,
    }
    head, sep, tail = page.rpartition("</body>")
    return head + _panel(data_json) + sep + tail


def _json_info(info: ReplayInfo) -> dict[str, Any]:
    out = {f.name: getattr(info, f.name) for f in dataclasses.fields(info)}
    out["settings"] = _plain(dict(info.settings))
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in out.items()}


def _plain(x: Any) -> Any:
    """``x`` as strict JSON values: mappings and sequences kept, a non-finite number or any other
    object as its text (planner settings may hold either)."""
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if x is None or isinstance(x, (bool, int, str)) or (isinstance(x, float) and math.isfinite(x)):
        return x
    return str(x)


def _panel(data: dict[str, Any]) -> str:
    """The information panel (HTML, escaped here, so it shows without scripts), the page's data as
    JSON, and the script of its buttons."""

    def num(x: float | None, scale: float, unit: str, digits: int = 3) -> str:
        return "not measured" if x is None else f"{x * scale:.{digits}g} {unit}"

    rows = [("problem", data["problem"]), ("robot", data["robot"])]
    if data["planner"]:
        planner = data["planner"] + ("" if data["seed"] is None else f", seed {data['seed']}")
        rows.append(("planner", planner))
        settings = ", ".join(f"{k} = {json.dumps(v)}" for k, v in data["settings"].items())
        rows.append(("settings", settings or "the planner's defaults"))
    if data["verdict"]:
        rows.append(("verdict", data["verdict"]))
        rows.append(("path length", num(data["path_length"], 1.0, "rad (joint space)", 4)))
        rows.append(("min clearance", num(data["min_clearance"], 1000.0, "mm")))
        rows.append(("planning time", num(data["planning_time"], 1000.0, "ms", 4)))
    fail = data["failure_at"]
    if fail:
        where = (
            f"segment {fail['segment']} of {fail['segments']}, at {fail['fraction']:.3f} of its length "
            f"(t = {fail['time']:.2f} s)"
        )
        rows.append(("failed at", where))
        if fail["pair"]:
            rows.append(("colliding", fail["pair"].replace(" / ", " with ") + " (red)"))
    if data["waypoints"] == 1:
        rows.append(("shown", "the problem's start (no path)"))
    table = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}</td></tr>" for k, v in rows)
    buttons = '<button type="button" id="planbench-to-start">path start</button>'
    if fail:
        buttons += ' <button type="button" id="planbench-to-failure">show the failure</button>'
    payload = json.dumps(data, allow_nan=False).replace("<", "\\u003c").replace(">", "\\u003e")
    return f"""
<div id="planbench-panel">
<div class="planbench-title">{html.escape(data["title"])}</div>
<table>{table}</table>
<div>{buttons if data["frames"] > 1 else ""} <span id="planbench-shown"></span></div>
</div>
<script type="application/json" id="planbench-replay">{payload}</script>
<style>
#planbench-panel {{position: fixed; top: 8px; left: 8px; max-width: 40vw; max-height: 90vh; overflow: auto;
  background: rgba(255, 255, 255, 0.88); color: #222; font: 12px/1.35 sans-serif; padding: 6px 8px;
  border-radius: 4px; z-index: 10;}}
#planbench-panel .planbench-title {{font-weight: bold; margin-bottom: 4px;}}
#planbench-panel th {{text-align: left; padding-right: 8px; vertical-align: top; white-space: nowrap;}}
#planbench-panel td {{overflow-wrap: anywhere;}}
</style>
<script>
(function () {{
  const data = JSON.parse(document.getElementById("planbench-replay").textContent);
  const shown = document.getElementById("planbench-shown");
  function seek(t, what) {{  // pause, make the animation's actions apply, show time t [s]; false: not loaded yet
    const a = viewer.animator;
    if (!a.actions.length) return false;
    a.pause();
    for (const action of a.actions) action.play();
    a.seek(t);
    a.display_progress(t);
    shown.textContent = "showing " + what + " (t = " + t.toFixed(2) + " s)";
    return true;
  }}
  const start = document.getElementById("planbench-to-start");
  if (start) start.addEventListener("click", () => seek(0, "the path's start"));
  const failure = document.getElementById("planbench-to-failure");
  if (failure) failure.addEventListener("click", () => seek(data.failure_at.time, "the failure"));
  if (location.hash === "#failure" && failure) {{  // a link to page.html#failure opens there
    let tries = 0;
    const open = () => {{ if (!seek(data.failure_at.time, "the failure") && ++tries < 100) setTimeout(open, 100); }};
    open();
  }}
}})();
</script>
"""


def write_replay(
    out: str | Path, problem: Any, path: np.ndarray | None, times: np.ndarray | None = None, **kw: Any
) -> Path:
    """Write :func:`replay_html` to ``out``; returns the file."""
    target = check_output(out)
    target.write_text(replay_html(problem, path, times, **kw))
    return target


def _close(vis: Any) -> None:
    """Stop the meshcat server this replay started (its process would outlive the call)."""
    window = getattr(vis, "window", None)
    server = getattr(window, "server_proc", None)
    if server is not None:
        server.kill()
        server.wait()
