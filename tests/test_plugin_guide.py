"""Runs the plugin guide (docs/writing-a-planner.md): its planner module, its entry-point line, its
conformance check, its planner on the IK loop; and the README's ten-line plugin."""

import re
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
from test_registry import install_fake_distribution

import planbench
from planbench.conformance import CHECKS, check_planner

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "writing-a-planner.md"
README = ROOT / "README.md"


def section_blocks(path: Path, heading: str) -> list[tuple[str, str]]:
    """``(language, code)`` of every fenced block in the ``## heading`` section of ``path``."""
    text = path.read_text()
    assert f"\n{heading}\n" in text, f"{path.name} has no section {heading!r}"
    section = text.split(f"\n{heading}\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```(\w+)\n(.*?)```", section, flags=re.S)


def test_the_guide_planner_installs_by_its_entry_point_line_and_conforms(tmp_path, monkeypatch):
    blocks = section_blocks(GUIDE, "## A complete planner plugin")
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


def test_the_guide_lists_the_checkers_named_checks_as_planbench_check_prints_them():
    text = GUIDE.read_text().split("\n## A complete planner plugin\n", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"^\| `([a-z-]+)` \|", text, flags=re.M) == list(CHECKS)
    printed = next(code for lang, code in section_blocks(GUIDE, "## A complete planner plugin") if lang == "text")
    assert printed.splitlines()[1] == f"  passed: {', '.join(CHECKS)}"


def test_the_guide_planner_on_the_ik_loop_conforms_and_plans(monkeypatch):
    blocks = section_blocks(GUIDE, "## A planner on the IK loop")
    code = next(code for lang, code in blocks if lang == "python" and "IKLoopPlanner" in code)
    module = types.ModuleType("guide_ik_loop_planner")
    monkeypatch.setitem(sys.modules, module.__name__, module)
    exec(compile(code, str(GUIDE), "exec"), module.__dict__)
    planner = next(
        obj
        for obj in vars(module).values()
        if isinstance(obj, type) and issubclass(obj, planbench.Planner) and obj.__module__ == module.__name__
    )
    assert check_planner(planner) == []
    problem = planbench.load_problems("mbm:box/0001")[0]
    result = planbench.plan(problem, planner, time_limit=5.0)
    assert np.array_equal(result.path[0], problem.start)
    assert result.info["steps"] > 0
    evaluation = planbench.evaluate(problem, result)
    assert evaluation.success == (result.status is planbench.PlanStatus.SUCCESS)


def test_the_readme_ten_line_plugin_runs():
    """The README's plugin block runs as written (in a fresh interpreter: it registers a planner)."""
    text = README.read_text()
    code = next(code for code in re.findall(r"```python\n(.*?)```", text, flags=re.S) if "register_planner" in code)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "True"
