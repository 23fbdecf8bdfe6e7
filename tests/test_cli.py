import json

from planbench.cli import main


def test_plan_prints_validated_metrics_and_writes_json(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["plan", "--problem", "mbm:table_pick/0001", "--planner", "straight-line", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "success (validated)" in text and "1/1 solved" in text
    rows = json.loads(out.read_text())
    assert rows[0]["problem"] == "mbm:table_pick/0001" and rows[0]["success"] is True
    assert rows[0]["min_clearance"] > 0


def test_plan_reports_failures_with_their_reason(capsys):
    assert main(["plan", "--problem", "mbm:box/0001-0002", "--set", "timed=false"]) == 0
    text = capsys.readouterr().out
    assert "mbm:box/0001 failed: collision" in text and "0/2 solved" in text


def test_user_errors_exit_2_with_a_message(capsys):
    assert main(["plan", "--problem", "mbm:boxx"]) == 2
    assert "Did you mean 'box'" in capsys.readouterr().err
    assert main(["plan", "--problem", "mbm:box/0001", "--planner", "rrt"]) == 2
    assert main(["plan", "--problem", "mbm:box/0001", "--set", "nope=1"]) == 2
    assert "timed" in capsys.readouterr().err


def test_list_shows_planners_robots_and_sets(capsys):
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    assert "straight-line" in text and "panda" in text and "ur5" in text and "mbm" in text


def test_plot_needs_a_planner_with_a_figure(capsys):
    assert main(["plan", "--problem", "mbm:box/0001", "--plot", "x.png"]) == 2
    assert "'straight-line' has none" in capsys.readouterr().err
