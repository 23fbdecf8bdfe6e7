"""The package's layers, as docs/architecture.md draws them: each module imports only from its own
layer and the layers below, and no two modules import each other in a circle.

Every import counts, at the top of a module or inside a function, except those under
``if TYPE_CHECKING:`` (annotations only). The imports are read with ``ast``; nothing is imported.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"planbench": ROOT / "planbench", "planbench_plugins": ROOT / "plugins", "planbench_robots": ROOT / "robots"}

LAYERS: list[tuple[str, set[str]]] = [
    ("foundation", {"errors", "settings", "files", "runtime", "planbench_robots"}),
    ("model", {"robot", "scene", "problem", "geometry", "checking", "metrics", "planner"}),
    ("field", {"field"}),
    ("planning", {"registry", "harness", "validate", "conformance", "problems"}),
    ("visual", {"visual"}),
    ("reactive", {"reactive"}),
    ("plugins", {"planbench_plugins"}),
    ("bench", {"bench"}),
    ("api", {"planbench"}),
    ("cli", {"cli"}),
]
"""Bottom to top. A part is a top-level module or subpackage of ``planbench`` (``planbench`` itself:
its ``__init__``, the public API), or another package; a layer may import its own and lower ones."""

LEVEL = {part: i for i, (_, parts) in enumerate(LAYERS) for part in parts}


@cache
def modules() -> dict[str, Path]:
    out = {}
    for package, root in PACKAGES.items():
        for path in root.rglob("*.py"):
            parts = [package, *path.relative_to(root).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _resolve(name: str) -> str | None:
    """The module of ours that ``name`` (a module, or a name in one) is, if any."""
    while name and name not in modules():
        name = name.rpartition(".")[0]
    return name or None


def _type_only(tree: ast.AST) -> set[int]:
    """ids of the nodes under ``if TYPE_CHECKING:``."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return out


@cache
def imports(module: str) -> tuple[tuple[int, str], ...]:
    """(line, module of ours) for every import of ``module`` that runs."""
    path = modules()[module]
    tree = ast.parse(path.read_text())
    skip = _type_only(tree)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            subs = [f"{base}.{alias.name}" for alias in node.names]
            names = [s for s in subs if s in modules()]
            if len(names) < len(subs):  # a name defined in the module itself
                names.append(base)
        else:
            continue
        for name in names:
            target = _resolve(name)
            if target is not None and target != module:
                out.append((node.lineno, target))
    return tuple(out)


def part_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if parts[0] == "planbench" and len(parts) > 1 else parts[0]


def test_every_part_has_a_layer() -> None:
    parts = {part_of(m) for m in modules()}
    assert parts - set(LEVEL) == set(), "add the new part to LAYERS and to docs/architecture.md"
    assert set(LEVEL) - parts == set(), "LAYERS names a part that does not exist"


@pytest.mark.parametrize("module", sorted(modules()))
def test_a_module_imports_only_its_layer_and_below(module: str) -> None:
    mine = LEVEL[part_of(module)]
    bad = [
        f"{modules()[module].relative_to(ROOT)}:{line} imports {target} (layer {LAYERS[LEVEL[part_of(target)]][0]})"
        for line, target in imports(module)
        if LEVEL[part_of(target)] > mine
    ]
    assert not bad, f"{module} is in layer {LAYERS[mine][0]}:\n" + "\n".join(bad)


def test_no_circle_of_imports() -> None:
    """Tarjan's strongly connected components of the import graph: every one is a single module."""
    graph = {m: sorted({t for _, t in imports(m)}) for m in modules()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert not circles, "modules that import each other: " + "; ".join(" <-> ".join(c) for c in circles)


PUBLIC_UNDERSCORE = {"_exit", "_fields", "_replace", "_asdict", "_make"}
"""Underscore names that are public API: ``os._exit`` and namedtuples' methods."""


def test_no_private_state_across_modules() -> None:
    """A module reads no underscore attribute of another object (only of ``self`` and ``cls``),
    and imports no underscore name from another part: what a module keeps private stays there."""
    bad = []
    for module, path in sorted(modules().items()):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                receiver = node.value
                if isinstance(receiver, ast.Name) and receiver.id in ("self", "cls"):
                    continue
                if node.attr not in PUBLIC_UNDERSCORE:
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno} reads {ast.unparse(node)}")
            elif isinstance(node, ast.ImportFrom) and node.module:
                for alias in node.names:
                    name = alias.name
                    private = name.startswith("_") and not name.startswith("__")
                    if private and part_of(node.module) != part_of(module):
                        bad.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {node.module}.{name}")
    assert not bad, "\n".join(bad)


def test_the_top_level_stays_small() -> None:
    top = sorted(p.name for p in PACKAGES["planbench"].glob("*.py"))
    assert len(top) <= 12, f"{len(top)} modules at the top of planbench/ (at most 12; put the new one in a subpackage)"


def test_the_checker_finds_what_it_checks(tmp_path: Path) -> None:
    """The rules fire: a made-up upward import and a made-up circle are found."""
    assert LEVEL[part_of("planbench.bench.runner")] > LEVEL[part_of("planbench.reactive.runner")]
    assert ("planbench.bench.runner", "planbench.reactive.isolation") in {
        ("planbench.bench.runner", t) for _, t in imports("planbench.bench.runner")
    }
    assert part_of("planbench.cli.main") == "cli" and part_of("planbench") == "planbench"
    assert part_of("planbench_plugins.ik_loop.loop") == "planbench_plugins"
