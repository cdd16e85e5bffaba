"""The package's layers, checked: no import cycle, and no import against the layers.

Every ``import`` in ``prosplat/``, ``addon/`` and ``scenes/`` is read with ``ast``, those inside
functions included (a function-level import hides a cycle from Python's import machinery,
not from the design). A cycle between modules, or a module importing a higher layer, fails
with the offending imports named.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: ``prosplat``'s subpackages from the bottom up: a module may import its own subpackage and
#: any lower layer, never a higher one. The root ``prosplat/__init__.py`` (the public API)
#: sits above all of them, and nothing inside the package imports it.
LAYERS: list[set[str]] = [
    {"core"},
    {"metrics", "render"},
    {"convert", "data"},
    {"geometry", "poses"},
    {"generator", "improve"},
    {"pipeline"},
    {"eval"},
    {"train", "worker"},
    {"cli"},
    {"__main__"},
]
RANK = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def _modules(package: str) -> dict[str, Path]:
    mods = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


MODULES = {**_modules("prosplat"), **_modules("addon"), **_modules("scenes")}


def _resolve(name: str) -> str | None:
    """The module of ours that ``name`` (a module or a name inside one) lives in."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str) -> set[str]:
    """Modules of ours that ``module`` imports anywhere in its file."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, up level - 1
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            names = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        else:
            continue
        found |= {m for n in names if (m := _resolve(n)) and m != module}
    return found


GRAPH = {m: _imports(m) for m in MODULES}


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in GRAPH:
        if start in index:
            continue
        work = [(start, iter(sorted(GRAPH[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(GRAPH[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    comp.append(m)
                    if m == node:
                        break
                if len(comp) > 1:
                    found.append(sorted(comp))
    return found


def _subpackage(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "<root>"


def test_no_import_cycle():
    cycles = _cycles()
    detail = [
        f"{c}: " + ", ".join(f"{a} -> {b}" for a in c for b in sorted(GRAPH[a]) if b in c)
        for c in cycles
    ]
    assert not cycles, "import cycles:\n" + "\n".join(detail)


def test_every_subpackage_has_a_layer():
    subs = {_subpackage(m) for m in MODULES if m.startswith("prosplat.")}
    assert subs <= set(RANK), f"put these in LAYERS: {sorted(subs - set(RANK))}"


def test_imports_follow_the_layers():
    wrong = []
    for module, targets in GRAPH.items():
        if module.startswith("prosplat."):
            for target in targets:
                if target == "prosplat":
                    wrong.append(f"{module} imports the root package (import the defining module)")
                elif (
                    target.startswith("prosplat.")
                    and RANK[_subpackage(target)] > RANK[_subpackage(module)]
                ):
                    wrong.append(f"{module} -> {target}")
        elif module.split(".")[0] in ("addon", "scenes"):
            # the add-on and the scene scripts use the library; the library never uses them
            pass
    lib_to_app = [
        f"{m} -> {t}"
        for m, ts in GRAPH.items()
        if m.split(".")[0] == "prosplat"
        for t in ts
        if t.split(".")[0] in ("addon", "scenes")
    ]
    assert not wrong + lib_to_app, "imports against the layers:\n" + "\n".join(wrong + lib_to_app)


def test_the_checker_sees_function_level_and_relative_imports(tmp_path):
    """The walk must see what Python only meets at call time, or it could pass a cycle."""
    src = "import os\n\ndef f():\n    from prosplat.core import camera\n    from . import paths\n"
    tree = ast.parse(src)
    inner = [n for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert [n.module for n in inner] == ["prosplat.core", None] and inner[1].level == 1
    assert "prosplat.core.camera" in MODULES and _resolve("prosplat.core.camera.Camera") == (
        "prosplat.core.camera"
    )
    assert "prosplat.core.camera" in GRAPH["prosplat.render.reference"]


def test_the_camera_is_a_leaf():
    """Everything speaks the camera; it imports nothing of ours, so it is never half-made
    (a cycle through it once was)."""
    assert GRAPH["prosplat.core.camera"] == set()
