"""The package's import graph has no cycle, between modules or between packages.

Every import counts: at module level, inside functions and under ``TYPE_CHECKING`` (a
type-level cycle is still a cycle to a reader). A package is a module's parent (``pipeline.builder``
for ``pipeline.builder.run``; a top-level module such as ``mars_pairs.errors`` is its own node).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "mars_pairs"


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """The package modules ``path`` imports (``from pkg import sub`` counts as ``pkg.sub``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        else:
            continue
        for t in targets:
            while t and t not in known:  # an attribute import: its module
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    graph = {m: _imports(p, m, known) for m, p in mods.items()}
    # an __init__ that only re-exports lazily is not an edge back into its package
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _package(module: str, packages: set[str]) -> str:
    return module if module in packages else module.rpartition(".")[0]


def test_no_module_cycle() -> None:
    assert _cycles(_graph()) == []


def test_no_package_cycle() -> None:
    graph = _graph()
    packages = {_module_name(p) for p in ROOT.rglob("__init__.py")}
    top = {m for m in graph if m.count(".") == 1 and m not in packages}  # mars_pairs.errors

    def node(m: str) -> str:
        return m if m in top else _package(m, packages)

    pkg_graph: dict[str, set[str]] = {}
    for m, targets in graph.items():
        src = node(m)
        for t in targets:
            dst = node(t)
            # a package and its own subpackage: the parent holds shared modules (config) the
            # children use; a child importing its parent's module is not a cycle by itself
            if dst != src:
                pkg_graph.setdefault(src, set()).add(dst)
    assert _cycles(pkg_graph) == []


def test_sample_never_imports_build() -> None:
    graph = _graph()
    wrong = sorted(
        (m, t)
        for m, targets in graph.items()
        if m.startswith("mars_pairs.pipeline.sample")
        for t in targets
        if t.startswith("mars_pairs.pipeline.builder")
    )
    assert wrong == []


@pytest.mark.parametrize("cycle", [["mars_pairs.a", "mars_pairs.b"]])
def test_the_checker_sees_a_cycle(cycle: list[str]) -> None:
    assert _cycles({"mars_pairs.a": {"mars_pairs.b"}, "mars_pairs.b": {"mars_pairs.a"}}) == [cycle]


def _private_imports(source: str) -> list[str]:
    """``module.name`` of every ``_``-prefixed name ``source`` imports from mars_pairs."""
    return [
        f"{node.module}.{a.name}"
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mars_pairs")
        for a in node.names
        if a.name.startswith("_") and not a.name.startswith("__")
    ]


def test_no_module_imports_another_modules_private_name() -> None:
    found = {
        name: str(path.relative_to(ROOT.parent))
        for path in ROOT.rglob("*.py")
        for name in _private_imports(path.read_text())
    }
    assert found == {}


def test_the_private_name_check_sees_one() -> None:
    assert _private_imports("from mars_pairs.x import a, _b\n") == ["mars_pairs.x._b"]
