"""3D replays: one self-contained HTML file per run, checked in a real headless browser."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess

import numpy as np
import pinocchio as pin
import pytest
import umsgpack

import planbench
from planbench.checking.collision import CollisionChecker
from planbench.cli.main import main
from planbench.planner import PlanResult, PlanStatus
from planbench.visual.replay import ReplayInfo, replay_html

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
NO_CHROMIUM = "no chromium to load the page in (Debian: apt-get install chromium)"
VISUALS = "/meshcat/planbench/visuals/"


@pytest.fixture(scope="module")
def solved():
    problem = planbench.load_problems("mbm:table_pick/0001")[0]
    return problem, planbench.plan(problem, "straight-line")


@pytest.fixture(scope="module")
def page(solved, tmp_path_factory):
    problem, result = solved
    html = replay_html(problem, result.path, title="straight-line <script>alert(1)</script>")
    path = tmp_path_factory.mktemp("replay") / "replay.html"
    path.write_text(html)
    return path


@pytest.fixture(scope="module")
def failed(tmp_path_factory):
    """A straight path through box/0001's obstacles that claims success: the validator finds where it
    collides, and the page shows it from the evaluation."""
    problem = planbench.load_problems("mbm:box/0001")[0]
    result = PlanResult(PlanStatus.SUCCESS, path=np.linspace(problem.start, problem.goal.q, 5), planning_time=0.01)
    ev = planbench.evaluate(problem, result)
    assert not ev.success and ev.collision_segment == 0 and ev.collision_pair.endswith("obstacle:side_cap")
    row = {**ev.as_dict(), "problem": problem.id, "planner": "straight-line", "seed": 3}
    info = ReplayInfo.from_row(row, settings={"step": 0.1})
    page = tmp_path_factory.mktemp("failed") / "failed.html"
    page.write_text(replay_html(problem, result.path, info=info))
    return problem, result, ev, page


def _data(html: str) -> dict:
    """The page's own record of what it shows (the JSON the panel is made from)."""
    m = re.search(r'<script type="application/json" id="planbench-replay">(.*?)</script>', html, re.S)
    assert m, "no planbench-replay data in the page"
    return json.loads(m.group(1))


def _commands(html: str) -> list[dict]:
    """meshcat's scene commands as the page holds them (msgpack, base64 in data: URLs)."""
    blobs = re.findall(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]*)"\)', html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def _transforms(html: str) -> dict[str, np.ndarray]:
    """Each scene node's placement (4x4) in the page, before any animation plays."""
    return {
        c["path"]: np.asarray(c["matrix"], dtype=float).reshape(4, 4).T  # meshcat: column-major
        for c in _commands(html)
        if c["type"] == "set_transform"
    }


def _placements(problem, q) -> dict[str, np.ndarray]:
    """Every body's placement at ``q``, as planbench's own checker places it."""
    geometry = CollisionChecker(problem.robot, problem.scene).geometry_model
    robot = problem.robot
    data, gdata = robot.model.createData(), pin.GeometryData(geometry)
    pin.updateGeometryPlacements(robot.model, data, geometry, gdata, np.asarray(q, dtype=float))
    return {g.name: gdata.oMg[i].homogeneous for i, g in enumerate(geometry.geometryObjects)}


def _robot_at(html: str, problem, q) -> None:
    shown = _transforms(html)
    expected = _placements(problem, q)
    links = [g.name for g in problem.robot.collision_model.geometryObjects]
    for name in links:
        np.testing.assert_allclose(shown[VISUALS + name], expected[name], atol=1e-5, err_msg=name)


def test_the_replay_is_one_offline_page_with_the_scene_and_an_animation(page):
    html = page.read_text()
    assert html.startswith("\n") or html.lstrip().startswith("<!DOCTYPE html>")
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=|https?://", html.split("<script>", 1)[0])  # nothing fetched
    assert "<title>straight-line &lt;script&gt;alert(1)&lt;/script&gt;</title>" in html  # untrusted text escaped
    assert "set_animation" in html and "set_object" in html


def test_replay_commands_write_pages_and_refuse_what_they_cannot_show(tmp_path, capsys):
    out = tmp_path / "plan.html"
    assert main(["plan", "--problem", "mbm:table_pick/0001", "--replay", str(out)]) == 0
    assert out.stat().st_size > 100_000 and "replay written" in capsys.readouterr().out
    assert main(["plan", "--problem", "mbm:box/0001-0002", "--replay", str(out)]) == 2
    assert "--replay needs one problem" in capsys.readouterr().err
    with pytest.raises(planbench.PlanbenchError, match="finite"):
        replay_html(planbench.load_problems("mbm:box/0001")[0], np.full((2, 7), np.nan))


HEADLESS = [
    str(CHROMIUM),
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--enable-logging=stderr",
    "--v=0",
    "--window-size=800,600",
    "--virtual-time-budget=5000",
]
"""Chromium without a screen, software WebGL, the page's console on stderr, 5 s of page time."""


def _chromium(*args: str) -> str:
    """Headless chromium on ``args`` (what to do, the page); its standard output, after checking that
    the page's console logged no error."""
    proc = subprocess.run([*HEADLESS, *args], capture_output=True, text=True, timeout=120)
    console = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]
    errors = [line for line in console if "Uncaught" in line or "Error" in line]
    assert not errors, errors
    return proc.stdout


@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_the_replay_loads_in_a_headless_browser_without_errors_and_draws_something(page, tmp_path):
    shot = tmp_path / "shot.png"
    _chromium(f"--screenshot={shot}", page.as_uri())
    import matplotlib.image

    pixels = matplotlib.image.imread(shot).reshape(-1, 3)
    assert len(np.unique(pixels, axis=0)) > 100  # the scene is drawn: not a blank or single-colour page


def test_the_html_report_links_each_run_to_its_replay(tmp_path):
    from planbench.bench.benchmark import run_benchmark
    from planbench.bench.suite import parse_suite

    suite = parse_suite(
        '[suite]\nname = "r"\nproblems = ["mbm:table_pick/0001", "mbm:box/0001"]\ntime_limit = 2.0\n'
        '[[planners]]\nplanner = "straight-line"\n',
        "r.toml",
    )
    run_benchmark(suite, tmp_path / "r.db", jobs=1)
    report = tmp_path / "report.html"
    assert main(["report", str(tmp_path / "r.db"), "--html", str(report), "--replays"]) == 0
    links = re.findall(r'href="(report_replays/run-\d+\.html)"', report.read_text())
    assert links and all((tmp_path / link).stat().st_size > 100_000 for link in links)


# -- a page that explains itself -----------------------------------------------------------------


def test_the_page_opens_at_the_paths_first_configuration(solved, page):
    problem, result = solved
    html = page.read_text()
    assert _data(html)["start_configuration"] == pytest.approx(result.path[0])
    _robot_at(html, problem, result.path[0])  # every link placed there, not folded at the base
    tracks = {a["path"]: a["clip"]["tracks"] for a in _commands(html)[0]["animations"]}  # what plays
    hand = tracks[VISUALS + "panda_hand_0"]
    first = next(t for t in hand if t["name"] == ".position")["keys"][0]
    assert first["time"] == 0 and first["value"] == pytest.approx(_transforms(html)[VISUALS + "panda_hand_0"][:3, 3])
    assert VISUALS + "obstacle:table" not in tracks  # only what moves is animated


def test_the_panel_holds_the_evaluation_and_where_the_path_failed(failed):
    problem, result, ev, page = failed
    html = page.read_text()
    data = _data(html)
    assert (data["problem"], data["robot"], data["planner"], data["seed"]) == (
        "mbm:box/0001",
        "panda",
        "straight-line",
        3,
    )
    assert data["settings"] == {"step": 0.1} and data["success"] is False
    assert data["verdict"] == ev.failure  # as the validator wrote it
    assert data["path_length"] == pytest.approx(ev.joint_path_length)
    assert data["min_clearance"] == pytest.approx(ev.min_clearance)
    assert data["planning_time"] == pytest.approx(ev.planning_time)
    at = data["failure_at"]
    assert (at["segment"], at["fraction"], at["pair"]) == (0, pytest.approx(ev.collision_fraction), ev.collision_pair)
    k, f = ev.collision_segment, ev.collision_fraction
    q = result.path[k] + f * (result.path[k + 1] - result.path[k])
    assert at["configuration"] == pytest.approx(q)
    # the colliding link drawn again where it collides
    link = ev.collision_pair.split(" / ")[0]
    shown, expected = _transforms(html), _placements(problem, q)
    marks = [name for name in expected if name.startswith(link + "_")]
    assert marks
    for name in marks:
        np.testing.assert_allclose(shown[VISUALS + f"failure:{name}"], expected[name], atol=1e-5)
    panel = html[html.index('<div id="planbench-panel">') :]
    for text in (
        "mbm:box/0001",
        "straight-line, seed 3",
        "step = 0.1",
        "segment 0 of 4",
        f"{link} with obstacle:side_cap",
    ):
        assert text in panel
    assert "show the failure" in panel
    _robot_at(html, problem, result.path[0])  # still opens at the start


def test_a_run_without_a_path_shows_the_problems_start():
    problem = planbench.load_problems("mbm:box/0001")[0]
    info = ReplayInfo(planner="x", success=False, failure="timeout: no solution in 1 s", status="timeout")
    html = replay_html(problem, None, info=info)
    data = _data(html)
    assert data["start_configuration"] == pytest.approx(problem.start) and data["failure_at"] is None
    assert data["verdict"] == "timeout: no solution in 1 s"
    _robot_at(html, problem, problem.start)
    assert not any(c["type"] == "set_animation" for c in _commands(html))
    assert "the problem&#x27;s start (no path)" in html


def test_results_file_replays_carry_the_rows_verdict_even_without_a_path(tmp_path):
    from planbench.bench.benchmark import run_benchmark
    from planbench.bench.suite import parse_suite

    suite = parse_suite(
        '[suite]\nname = "r"\nproblems = ["mbm:box/0001"]\ntime_limit = 2.0\n[[planners]]\nplanner = "straight-line"\n',
        "r.toml",
    )
    run_benchmark(suite, tmp_path / "r.db", jobs=1)
    row = planbench.load_results(tmp_path / "r.db").iloc[0]
    assert not row["success"] and row["path"] is None
    out = tmp_path / "run.html"
    assert main(["replay", str(tmp_path / "r.db"), "--run", "1", "--out", str(out)]) == 0
    data = _data(out.read_text())
    assert (data["planner"], data["seed"], data["verdict"]) == ("straight-line", int(row["seed"]), row["failure"])
    assert data["start_configuration"] == pytest.approx(planbench.load_problems("mbm:box/0001")[0].start)


def test_planner_settings_from_a_results_file_are_read_as_json():
    info = ReplayInfo.from_row({"planner_settings": '{"range": 0.2}', "success": 1, "collision_segment": None})
    assert info.settings == {"range": 0.2} and info.verdict == "success (validated)" and info.collision_segment == -1
    assert ReplayInfo().verdict == ""  # no verdict given: none shown
    odd = ReplayInfo.from_row({"planner_settings": '{"limit": NaN, "goal": [1, Infinity]}', "planner": "p"})
    problem = planbench.load_problems("mbm:box/0001")[0]
    data = _data(replay_html(problem, None, info=odd))  # strict JSON, readable by the page's JSON.parse
    assert data["settings"] == {"limit": "nan", "goal": [1, "inf"]}


def test_the_point_cloud_example_replays_as_points_in_at_most_5_mb(tmp_path, capsys):
    pytest.importorskip("ompl")
    out = tmp_path / "cloud.html"
    args = ["plan", "--problem", "examples:depth_camera_table", "--planner", "ompl-rrtconnect", "--replay", str(out)]
    assert main(args) == 0
    assert out.stat().st_size <= 5_000_000  # was 32 MB with a mesh of cubes
    html = out.read_text()
    data = _data(html)
    assert (data["problem"], data["planner"], data["verdict"]) == (
        "examples:depth_camera_table",
        "ompl-rrtconnect",
        "success (validated)",
    )
    problem = planbench.load_problems("examples:depth_camera_table")[0]
    cloud = [c for c in _commands(html) if c["type"] == "set_object" and c["path"] == VISUALS + "obstacle:camera-cloud"]
    assert len(cloud) == 1 and cloud[0]["object"]["object"]["type"] == "Points"
    position = cloud[0]["object"]["geometries"][0]["data"]["attributes"]["position"]
    centres = np.frombuffer(position["array"].data, dtype=np.float32).reshape(-1, 3)
    voxels = problem.scene.obstacles[0].cloud()
    assert len(centres) == len(voxels)  # a point per occupied cube, at its centre
    np.testing.assert_allclose(
        np.unique(centres, axis=0), np.unique(voxels.centres.astype(np.float32), axis=0), atol=1e-6
    )
    _robot_at(html, problem, problem.start)


@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_the_failure_page_shows_its_panel_and_opens_at_the_failure_in_a_browser(failed):
    """Headless chromium runs the page's scripts and prints the DOM: the panel's text is there, and
    page.html#failure moved the animation to the failure, with no JS error on the way."""
    *_, ev, page = failed
    dom = _chromium("--dump-dom", page.as_uri() + "#failure")
    panel = dom[dom.index('<div id="planbench-panel">') :]
    panel_text = re.sub(r"<[^>]+>", " ", panel[: panel.index("</table>")])
    for text in ("mbm:box/0001", "straight-line", "collision on segment 0", "min clearance", "planning time"):
        assert text in panel_text
    at = _data(page.read_text())["failure_at"]["time"]
    assert f"showing the failure (t = {at:.2f} s)" in dom
