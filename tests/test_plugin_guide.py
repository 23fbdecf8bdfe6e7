"""Runs the README's plugin guide: its planner module, its entry-point line, its conformance check."""

import re
import sys
from pathlib import Path

from test_registry import install_fake_distribution

import planbench
from planbench.conformance import check_planner

README = Path(__file__).resolve().parents[1] / "README.md"


def guide_blocks():
    text = README.read_text()
    section = text.split("## Writing a planner plugin", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```(\w+)\n(.*?)```", section, flags=re.S)


def test_the_guide_planner_installs_by_its_entry_point_line_and_conforms(tmp_path, monkeypatch):
    blocks = guide_blocks()
    module_code = next(code for lang, code in blocks if lang == "python" and "class " in code)
    toml = next(code for lang, code in blocks if lang == "toml")
    assert '[project.entry-points."planbench.planners"]' in toml
    name, target = re.search(r'^([\w-]+) = "([\w.:]+)"$', toml, flags=re.M).groups()
    module = target.split(":")[0]
    install_fake_distribution(tmp_path, monkeypatch, "my-planner", {name: target}, {module: module_code})
    registry = planbench.Registry()
    assert name in registry.names()
    assert registry.spec(name).distribution == "my-planner"
    assert check_planner(registry.get(name)) == []
    problem = planbench.load_problems("mbm:table_pick/0001")[0]
    result = planbench.plan(problem, registry.get(name))
    assert planbench.evaluate(problem, result).success
    sys.modules.pop(module, None)
