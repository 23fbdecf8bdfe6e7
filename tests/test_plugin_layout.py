"""The plugins' layering: each planner family imports the core and ``ik_loop``'s public API only.

A baseline that imported the matrix-field plugin's internals would make the comparison depend on
the method it is compared against; this test reads every plugin module's imports (ast, nothing
is imported) and names the offending line. ``controllers`` is a layer above the planners (it runs
their steps closed-loop): it may import a planner family's public package, never its modules, and
no planner family imports it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"
FAMILIES = sorted(p.name for p in PLUGINS.iterdir() if p.is_dir() and (p / "__init__.py").is_file())


def imported_modules(path: Path) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
    return out


def test_every_family_is_a_folder_and_the_loop_is_one_of_them() -> None:
    assert "ik_loop" in FAMILIES
    assert {"matrix_field", "matrix_field_qp", "potential_fields", "ompl_planners", "straight_line"} <= set(FAMILIES)
    assert not [p.name for p in PLUGINS.glob("*.py") if p.name != "__init__.py"], "a plugin outside a folder"


@pytest.mark.parametrize("family", [f for f in FAMILIES if f != "ik_loop"])
def test_a_family_imports_no_other_plugin_and_only_the_loops_public_api(family: str) -> None:
    bad = []
    for path in sorted((PLUGINS / family).rglob("*.py")):
        for line, module in imported_modules(path):
            parts = module.split(".")
            if parts[0] != "planbench_plugins" or len(parts) == 1:
                continue
            if parts[1] == family or module == "planbench_plugins.ik_loop":
                continue
            if family == "controllers" and len(parts) == 2 and parts[1] != "controllers":
                continue  # a planner family's public package
            bad.append(f"{path.relative_to(PLUGINS)}:{line} imports {module}")
    assert not bad, "\n".join(bad)


def test_the_loop_imports_no_planner_family() -> None:
    bad = [
        f"{path.name}:{line} imports {module}"
        for path in sorted((PLUGINS / "ik_loop").rglob("*.py"))
        for line, module in imported_modules(path)
        if module.startswith("planbench_plugins.") and not module.startswith("planbench_plugins.ik_loop")
    ]
    assert not bad, "\n".join(bad)
