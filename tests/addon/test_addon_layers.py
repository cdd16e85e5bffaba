"""The add-on's two layers: ``addon/core`` is bpy-free, ``addon/blender`` holds the rest.

Every import in ``addon/core/*.py`` (inside functions too) is read with ``ast``: none may name
``bpy``, ``mathutils`` or ``bpy_extras``, the add-on's root package (its ``__init__`` imports
``bpy``) or its Blender layer. Then each core module is imported for real in a plain Python
where those modules cannot be imported at all, as a package of its own, so a stray import
fails here without Blender. No ``bpy`` needed: this runs in the default suite.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "addon" / "core"
BLENDER_MODULES = ("bpy", "mathutils", "bpy_extras", "addon_utils", "bl_ui", "bmesh", "gpu")


def _core_modules() -> list[Path]:
    return sorted(CORE.glob("*.py"))


def _bad_imports(path: Path) -> list[str]:
    """Imports in ``path`` (anywhere in the file) that the bpy-free layer must not make."""
    bad = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level >= 2:  # from .. (the add-on root, or ..blender)
                bad.append(f"line {node.lineno}: from {'.' * node.level}{node.module or ''}")
                continue
            if node.level == 1:
                names = [node.module] if node.module else [a.name for a in node.names]
                bad += [
                    f"line {node.lineno}: from .{n}" for n in names if n.split(".")[0] == "blender"
                ]
                continue
            names = [node.module or ""]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            if top in BLENDER_MODULES or top == "addon":
                bad.append(f"line {node.lineno}: import {name}")
    return bad


def test_core_never_imports_blender() -> None:
    modules = _core_modules()
    assert len(modules) >= 5, f"addon/core looks empty: {modules}"
    bad = {p.name: b for p in modules if (b := _bad_imports(p))}
    assert not bad, f"addon/core must stay bpy-free: {bad}"


def test_the_checker_sees_what_it_must(tmp_path: Path) -> None:
    src = (
        "import os\nfrom . import pins\n\ndef f():\n    import bpy\n"
        "    from ..blender import steps\n    from .blender import ui\n    from mathutils import Matrix\n"
    )
    path = tmp_path / "m.py"
    path.write_text(src)
    assert _bad_imports(path) == [
        "line 5: import bpy",
        "line 6: from ..blender",
        "line 7: from .blender",
        "line 8: import mathutils",
    ]


_IMPORT_ALL = """
import importlib, importlib.util, json, sys
for name in {blocked!r}:
    sys.modules[name] = None  # `import bpy` now raises ImportError, even where bpy is installed
spec = importlib.util.spec_from_file_location(
    "prosplat_addon_core", {init!r}, submodule_search_locations=[{core!r}])
pkg = importlib.util.module_from_spec(spec)
sys.modules["prosplat_addon_core"] = pkg
spec.loader.exec_module(pkg)
for name in {names!r}:
    importlib.import_module("prosplat_addon_core." + name)
print(json.dumps(sorted(m for m in ("torch", "prosplat") if m in sys.modules)))
"""


def test_core_imports_in_plain_python() -> None:
    """Each core module imports with ``bpy`` and friends unimportable, and without loading
    torch or prosplat (the add-on must register in a Blender without them)."""
    names = [p.stem for p in _core_modules() if p.stem != "__init__"]
    code = _IMPORT_ALL.format(
        blocked=BLENDER_MODULES, init=str(CORE / "__init__.py"), core=str(CORE), names=names
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=str(ROOT), timeout=120)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout.strip().splitlines()[-1]) == []
