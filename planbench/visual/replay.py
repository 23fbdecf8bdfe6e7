"""A 3D replay of a path in one self-contained HTML file: open it in any browser, offline, no server.

Built on pinocchio's meshcat integration (``pinocchio.visualize.MeshcatVisualizer``) and meshcat's
static HTML export (``Visualizer.static_html``): the robot's collision meshes and the obstacles
(the same geometry the certified checker uses), the path as a meshcat animation (play, pause and a
time slider in the page's "Animations" controls), moving obstacles of a scenario moving with it,
and the occupancy grid the matrix field sees (scene tree "grid", hidden until switched on). No
hand-written WebGL; the page holds meshcat's own viewer and the scene as data.

Frames: at most :data:`MAX_FRAMES`, in real time: the path's own time stamps when it has them (a
closed-loop run, a timed planner), else each segment at the joints' velocity limits.
"""

from __future__ import annotations

import contextlib
import html
import io
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.checking.collision import CollisionChecker
from planbench.errors import PlanbenchError
from planbench.files.outputs import check_output

__all__ = ["MAX_FRAMES", "replay_html", "write_replay"]

MAX_FRAMES = 600
FPS = 30


def _meshcat() -> Any:
    try:
        import meshcat
        import meshcat.animation
        import meshcat.geometry
    except ModuleNotFoundError:
        raise PlanbenchError("a replay needs meshcat: pip install meshcat") from None
    return meshcat


def _frames(path: np.ndarray, times: np.ndarray | None, vmax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time stamps [s] of the path's states, and the (at most MAX_FRAMES) states shown, 30 a second."""
    if times is None or len(times) != len(path):
        seg = (np.abs(np.diff(path, axis=0)) / vmax).max(axis=1) if len(path) > 1 else np.zeros(0)
        times = np.concatenate([[0.0], np.cumsum(seg)])
    duration = float(times[-1]) if len(times) else 0.0
    n = int(min(MAX_FRAMES, max(2, np.ceil(duration * FPS) + 1)))
    shown = np.linspace(0.0, duration, n)
    q = np.stack([np.interp(shown, times, path[:, j]) for j in range(path.shape[1])], axis=1)
    return shown, q


def replay_html(
    problem: Any,
    path: np.ndarray,
    times: np.ndarray | None = None,
    *,
    geometry: Any = None,
    place: Callable[[float], None] | None = None,
    grid: Any = None,
    title: str = "planbench replay",
) -> str:
    """The replay page of ``path`` (an (N, nq) array) on ``problem`` (module docstring) as a
    string. ``geometry``: the pinocchio geometry model shown (default: the robot and the problem's
    scene); ``place(t)``: puts its moving obstacles where they are at ``t`` [s] of the path's
    ``times`` (a closed-loop run's :class:`~planbench.reactive.checker.TickChecker` does);
    ``grid``: an :class:`~planbench.geometry.occupancy.OccupancyGrid` shown on demand."""
    meshcat = _meshcat()
    from pinocchio.visualize import MeshcatVisualizer

    path = np.asarray(path, dtype=float)
    robot = problem.robot
    if path.ndim != 2 or path.shape[1] != robot.nq or len(path) == 0 or not np.isfinite(path).all():
        raise PlanbenchError(f"a replay needs a finite (N, {robot.nq}) path, got shape {path.shape}")
    if geometry is None:
        geometry = CollisionChecker(robot, problem.scene).geometry_model
    n_robot = len(robot.collision_model.geometryObjects)
    for i, g in enumerate(geometry.geometryObjects):  # the arm orange, obstacles see-through grey
        g.meshColor = np.array([0.95, 0.55, 0.15, 1.0]) if i < n_robot else np.array([0.55, 0.6, 0.7, 0.45])
    with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints its server's URL: not ours to show
        vis = meshcat.Visualizer()
    try:
        viz = MeshcatVisualizer(robot.model, geometry, geometry)
        viz.initViewer(viewer=vis)
        viz.loadViewerModel(rootNodeName="planbench")
        data, gdata = robot.model.createData(), pin.GeometryData(geometry)
        nodes = [viz.getViewerNodeName(g, pin.GeometryType.VISUAL) for g in geometry.geometryObjects]
        shown_t, shown_q = _frames(path, times, np.asarray(robot.velocity_limit, dtype=float))
        anim = meshcat.animation.Animation(default_framerate=FPS)
        for k, (t, q) in enumerate(zip(shown_t, shown_q, strict=True)):
            if place is not None:
                place(float(t))
            pin.updateGeometryPlacements(robot.model, data, geometry, gdata, q)
            with anim.at_frame(vis, k) as frame:
                for node, M in zip(nodes, gdata.oMg, strict=True):
                    frame[node].set_transform(M.homogeneous)
        vis.set_animation(anim, play=False)
        vis["/Cameras/default/rotated/<object>"].set_property("position", [2.2, 1.2, 1.6])  # y up in the camera
        vis["/Grid"].set_property("visible", False)  # the base frame's floor plane cuts through tables
        if grid is not None:
            centres = grid.cell_centers()[np.asarray(grid.data) > 0.5]
            if len(centres):
                position = centres.T.astype(np.float32)
                color = np.tile(np.array([[0.9], [0.3], [0.2]], dtype=np.float32), (1, position.shape[1]))
                cloud = meshcat.geometry.PointCloud(position=position, color=color, size=grid.resolution)
                vis["grid"].set_object(cloud)
                vis["grid"].set_property("visible", False)
        page = vis.static_html()
    finally:
        vis.delete()
        _close(vis)
    return page.replace("<title>MeshCat</title>", f"<title>{html.escape(title)}</title>", 1)


def write_replay(out: str | Path, problem: Any, path: np.ndarray, times: np.ndarray | None = None, **kw: Any) -> Path:
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
