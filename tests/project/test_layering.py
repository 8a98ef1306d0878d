"""The package's layout: imports point down the layers, and no module imports itself in a cycle.

The imports are read with ``ast`` (nothing is executed), including imports inside functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from locations import ROOT

PACKAGE = ROOT / "ltmstore"

# What each part of the package may import (besides itself). Top-level modules are parts too.
ALLOWED: dict[str, set[str]] = {
    "core": set(),
    "capture": {"core"},
    "solve": {"core"},
    "stages": {"core", "capture", "solve"},
    "synthetic": {"core", "capture", "solve", "stages"},
    "judge": {"core", "capture", "solve", "stages", "synthetic"},
    "share": {"core", "solve", "stages"},
    "archive": {"core", "capture", "solve", "stages", "judge"},
    "cli": {"core", "capture", "solve", "stages", "synthetic", "judge", "share", "archive"},
}
TOP_LEVEL_MODULES_MAX = 5  # besides the subpackages


def module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path, root: Path) -> set[str]:
    """Every ltmstore module ``path`` imports (absolute or relative, at any depth)."""
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            # "from ltmstore.solve import cs" imports the module ltmstore.solve.cs
            found |= {f"{base}.{a.name}" for a in node.names} | {base}
    return {m for m in found if m == root.name or m.startswith(root.name + ".")}


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    modules = {module_name(p, root): p for p in root.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        targets = set()
        for m in imports_of(path, root):
            while m not in modules and "." in m:  # an imported name, not a module
                m = m.rpartition(".")[0]
            if m in modules and m != name:
                targets.add(m)
        graph[name] = targets
    return graph


def part(module: str) -> str | None:
    """The layer a module belongs to (``None`` for the package's own ``__init__``)."""
    pieces = module.split(".")
    return pieces[1] if len(pieces) > 1 else None


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for source, targets in graph.items():
        layer = part(source)
        if layer is None:
            continue  # ltmstore/__init__.py re-exports public names from any layer
        for target in targets:
            other = part(target)
            if other != layer and other not in ALLOWED[layer]:
                bad.append(f"{source} -> {target} ({layer} may not import {other})")
    return sorted(bad)


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules, or ``None``; package ``__init__`` files that
    re-export from their own submodules are not edges back to the package."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if node.startswith(nxt + "."):
                continue  # a module importing its own package's __init__
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start)):
            return found
    return None


def test_every_part_is_known():
    parts = {part(m) for m in import_graph()} - {None}
    assert parts <= set(ALLOWED), f"parts without a layer rule: {parts - set(ALLOWED)}"


def test_imports_point_down():
    assert upward_imports(import_graph()) == []


def test_no_import_cycles():
    assert find_cycle(import_graph()) is None


def test_top_level_is_small():
    modules = [p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py"]
    assert len(modules) <= TOP_LEVEL_MODULES_MAX, modules


def test_every_subpackage_says_what_it_holds():
    for init in PACKAGE.glob("*/__init__.py"):
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and "import" in doc, f"{init} needs a docstring saying what it may import"


@pytest.fixture
def tree_with(tmp_path):
    """A copy of the package's import structure with one extra module written into it."""
    import shutil

    def build(relpath: str, source: str) -> Path:
        root = tmp_path / "ltmstore"
        shutil.copytree(PACKAGE, root, ignore=shutil.ignore_patterns("__pycache__"))
        (root / relpath).write_text(source)
        return root
    return build


def test_a_deliberate_cycle_is_caught(tree_with):
    root = tree_with("core/errors.py", "from ltmstore.core.dims import Lattice\n")
    cycle = find_cycle(import_graph(root))
    assert cycle is not None and "ltmstore.core.errors" in cycle and "ltmstore.core.dims" in cycle


def test_a_deliberate_upward_import_is_caught(tree_with):
    root = tree_with("solve/extra.py", "from ltmstore.stages.relight import relight\n")
    assert upward_imports(import_graph(root)) == [
        "ltmstore.solve.extra -> ltmstore.stages.relight (solve may not import stages)"]
