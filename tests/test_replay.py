"""3D replays: one self-contained HTML file per run, checked in a real headless browser."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

import planbench
from planbench.cli.main import main
from planbench.visual.replay import replay_html

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    problem = planbench.load_problems("mbm:table_pick/0001")[0]
    result = planbench.plan(problem, "straight-line")
    html = replay_html(problem, result.path, title="straight-line <script>alert(1)</script>")
    path = tmp_path_factory.mktemp("replay") / "replay.html"
    path.write_text(html)
    return path


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


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium to load the page in (Debian: apt-get install chromium)")
def test_the_replay_loads_in_a_headless_browser_without_errors_and_draws_something(page, tmp_path):
    shot = tmp_path / "shot.png"
    proc = subprocess.run(
        [
            CHROMIUM,
            "--headless=new",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=800,600",
            "--virtual-time-budget=5000",
            f"--screenshot={shot}",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    console = [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]
    errors = [line for line in console if "Uncaught" in line or "Error" in line]
    assert not errors, errors
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
