"""A 3D replay of a run in one self-contained HTML file: open it in any browser, offline, no server.

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
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from planbench.errors import PlanbenchError
from planbench.outputs import check_output

__all__ = ["MAX_FRAMES", "replay_html", "replay_row", "replay_run", "write_replay"]

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
    scenario: Any = None,
    grid: Any = None,
    title: str = "planbench replay",
) -> str:
    """The replay page of ``path`` (an (N, nq) array) on ``problem`` (module docstring) as a
    string. ``scenario``: a :class:`~planbench.reactive.Scenario` whose moving obstacles move with
    the path's ``times``; ``grid``: an :class:`~planbench.occupancy.OccupancyGrid` shown on demand."""
    meshcat = _meshcat()
    from pinocchio.visualize import MeshcatVisualizer

    path = np.asarray(path, dtype=float)
    robot = problem.robot
    if path.ndim != 2 or path.shape[1] != robot.nq or len(path) == 0 or not np.isfinite(path).all():
        raise PlanbenchError(f"a replay needs a finite (N, {robot.nq}) path, got shape {path.shape}")
    if scenario is not None:
        from planbench.reactive.checker import TickChecker

        checker: Any = TickChecker(scenario)
        geometry = checker.checker.geometry_model
    else:
        from planbench.collision import CollisionChecker

        checker = None
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
            if checker is not None:
                checker.place(float(t))
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


def replay_run(db_path: str | Path, run_id: int, out: str | Path) -> Path:
    """The replay of run ``run_id`` of a results file (:func:`replay_row`)."""
    from planbench.bench.db import ResultsDB

    with ResultsDB(db_path, read_only=True) as db:
        rows = [r for r in db.rows(with_arrays=True) if r["id"] == run_id]
    if not rows:
        raise PlanbenchError(f"{db_path} holds no run with id {run_id} (planbench export --format csv lists them)")
    return replay_row(rows[0], out)


def replay_row(row: dict[str, Any], out: str | Path) -> Path:
    """The replay of a results-file row read with its arrays: a planner's path on its problem, or
    a closed-loop run among its scenario's moving obstacles."""
    if row.get("path") is None:
        raise PlanbenchError(f"run {row.get('id')} ({row['planner']} on {row['problem']}) has no path to replay")
    verdict = "success" if row["success"] else str(row["failure"])
    title = f"{row['planner']} on {row['problem']}, seed {row['seed']}: {verdict}"
    if row.get("deadline_misses") is not None:  # a closed-loop run: its scenario, moving obstacles and all
        from planbench.reactive.sets import load_scenario

        scenario = load_scenario(row["problem"])
        return write_replay(out, scenario.problem, row["path"], row["times"], scenario=scenario, title=title)
    from planbench.datasets import load_problem

    return write_replay(out, load_problem(row["problem"]), row["path"], row["times"], title=title)


def _close(vis: Any) -> None:
    """Stop the meshcat server this replay started (its process would outlive the call)."""
    window = getattr(vis, "window", None)
    server = getattr(window, "server_proc", None)
    if server is not None:
        server.kill()
        server.wait()
