"""Every ``from X import name`` in the package resolves, those inside functions too: a bench imports
its helpers lazily, and a name moved away (``bench view``'s fleet part once imported a CPU reader
that had moved to ``zdrone.bench.stallwatch``) otherwise fails only when that part runs."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted(p for d in ("zdrone", "gs") for p in (ROOT / d).rglob("*.py"))


def _module_of(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_name_imported_from_our_own_modules_exists(path: Path) -> None:
    here = _module_of(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    missing = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.ImportFrom):
            continue
        target = importlib.util.resolve_name("." * node.level + (node.module or ""), package) if node.level else node.module
        if not target or target.split(".")[0] not in ("zdrone", "gs"):
            continue
        module = importlib.import_module(target)
        for alias in node.names:
            if alias.name != "*" and not hasattr(module, alias.name):
                try:
                    importlib.import_module(f"{target}.{alias.name}")  # a submodule
                except ImportError:
                    missing.append(f"line {node.lineno}: {target}.{alias.name}")
    assert not missing, missing
