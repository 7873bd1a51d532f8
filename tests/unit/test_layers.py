"""Layers only point down, and no two packages import each other.

core (and ``zdrone.crashes``) < fleet (fleet files, router config, key expressions) < net / vehicle < nodes (the drone node,
the ``gs`` package) < sil / bench / report / view (the web view's server) < cli (``zdrone.cli``, ``zdrone.commands``). A module may
import its own layer or a lower one; within a layer, packages must not form a cycle. Imports are
read with ``ast`` (top-level and inside functions alike), so a lazy import counts too.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LAYERS: dict[str, int] = {
    "zdrone.core": 0, "zdrone.crashes": 0,  # stacks on a crash: every entry point and launcher uses it
    "zdrone.fleet": 1,
    "zdrone.net": 2, "zdrone.vehicle": 2,
    "zdrone.nodes": 3, "gs": 3,
    "zdrone.sil": 4, "zdrone.bench": 4, "zdrone.check": 4, "zdrone.report": 4, "zdrone.view": 4,
    "zdrone.cli": 5, "zdrone.commands": 5, "zdrone.harness": 5, "zdrone.__main__": 5, "zdrone": 5,
}


def _unit(module: str) -> str:
    """The layer unit a module belongs to: its longest prefix in ``LAYERS``."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in LAYERS:
            return ".".join(parts[:n])
    raise AssertionError(f"{module}: in no layer")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in ("zdrone", "gs"):
        for p in (ROOT / pkg).rglob("*.py"):
            rel = p.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _imports(module: str, path: Path) -> set[str]:
    is_pkg = path.name == "__init__.py"
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                target = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.add(target)
            found |= {f"{target}.{a.name}" for a in node.names}  # `from pkg import module`
    mods = _modules()
    return {m for m in found if m in mods and m != module}


def _graph() -> dict[str, set[str]]:
    return {m: _imports(m, p) for m, p in _modules().items()}


def test_every_import_points_down_or_sideways():
    up = []
    for m, targets in _graph().items():
        for t in targets:
            if LAYERS[_unit(t)] > LAYERS[_unit(m)]:
                up.append(f"{m} -> {t}")
    assert not up, "imports that point up:\n" + "\n".join(sorted(up))


def test_no_package_cycles():
    edges: dict[str, set[str]] = {}
    for m, targets in _graph().items():
        for t in targets:
            a, b = _unit(m), _unit(t)
            if a != b:
                edges.setdefault(a, set()).add(b)
    cycles = []
    for a, bs in edges.items():
        for b in bs:
            stack, seen = [b], set()
            while stack:
                x = stack.pop()
                if x == a:
                    cycles.append(f"{a} -> {b} -> ... -> {a}")
                    break
                if x not in seen:
                    seen.add(x)
                    stack += edges.get(x, ())
    assert not cycles, "package cycles:\n" + "\n".join(sorted(cycles))


def _module_cycles() -> list[list[str]]:
    """Every strongly connected set of two or more modules in the import graph (Tarjan's algorithm);
    a package's import of one of its own modules (``from . import x`` in ``__init__``) counts as any other."""
    graph = {m: {t.rsplit(".", 1)[0] if t not in _modules() else t for t in ts} for m, ts in _graph().items()}
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
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for m in sorted(graph):
        if m not in index:
            visit(m)
    return out


def test_no_module_cycles():
    """No two modules import each other, however far round (lazy imports inside functions count)."""
    cycles = _module_cycles()
    assert not cycles, "module cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_every_import_of_the_project_names_one_of_its_modules():
    """A relative import, or one of ``zdrone`` or ``gs``, names a module that exists: lazy imports (inside
    a function) too, which nothing runs before that function does (a module moved into a package must
    take them along)."""
    mods, missing = _modules(), []
    for module, path in mods.items():
        base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                target = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in ("zdrone", "gs"):
                target = node.module or ""
            else:
                continue
            if target not in mods:
                missing.append(f"{path.relative_to(ROOT)}:{node.lineno}: {target}")
    assert not missing, "imports of modules that do not exist:\n" + "\n".join(missing)


def test_one_import_style_absolute_everywhere():
    """The product and the testbed import by absolute name (``from zdrone.core import wire``), never
    relative (``from ..core import wire``): a reader sees where a name comes from without counting dots."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    relative = [f"{p.relative_to(root)}:{n}" for pkg in ("zdrone", "gs") for p in sorted((root / pkg).rglob("*.py"))
                for n, line in enumerate(p.read_text().splitlines(), 1) if re.match(r"\s*from \.", line)]
    assert not relative, relative
