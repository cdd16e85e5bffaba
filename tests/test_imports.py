"""The import graph of ``prosplat`` points one way: low modules never import the CLI, and the
camera never imports its converters (each cycle here once made a module half-initialised)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "prosplat"


def _imports(path: Path) -> set[str]:
    """Every ``prosplat...`` module ``path`` imports, at top level or inside functions."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
    return {m for m in found if m.split(".")[0] == "prosplat"}


def test_only_the_entry_points_import_the_cli():
    users = {
        str(p.relative_to(PACKAGE))
        for p in PACKAGE.rglob("*.py")
        if any(m in ("prosplat.cli", "prosplat.cli.improve") for m in _imports(p))
    }
    assert users == {"__main__.py", "cli.py"}


def test_camera_imports_nothing_of_prosplat():
    assert _imports(PACKAGE / "camera.py") == set()
