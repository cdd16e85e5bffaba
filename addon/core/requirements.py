"""What ``prosplat`` needs at run time, and whether this Python has it, without importing
torch (until asked) and without ``bpy``.

Blender's bundled Python has numpy but usually not torch. The add-on imports ``prosplat``
only inside jobs (never at register time), so it registers and shows its preferences whether
or not torch is there; :func:`check_prosplat_import` imports it for real (*Check
Requirements*, and before the first job in Blender's Python). The preferences, and where a
job runs by them, are :mod:`..blender.runtime`.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import sys

#: (import name, distribution name) of what ``prosplat`` needs at run time.
REQUIREMENTS = (
    ("torch", "torch"),
    ("numpy", "numpy"),
    ("plyfile", "plyfile"),
    ("safetensors", "safetensors"),
    ("OpenImageIO", "OpenImageIO"),
    ("tqdm", "tqdm"),
    ("diffusers", "diffusers"),
)
# What the install button asks pip for is the pinned, tested set in :mod:`.pins` (numpy is
# left to Blender, which ships one); :mod:`.install` builds the pip commands.


def requirement_versions() -> dict[str, str | None]:
    """``{name: installed version or None}`` without importing anything (cheap, for the UI)."""
    out: dict[str, str | None] = {}
    for module, dist in (("prosplat", "prosplat"), *REQUIREMENTS):
        if importlib.util.find_spec(module) is None:
            out[module] = None
            continue
        try:
            out[module] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[module] = "found"
    return out


_IMPORT_CHECK: dict[str, str | None] = {}


def check_prosplat_import() -> str | None:
    """Import ``prosplat`` for real (loads torch: seconds); None if it works, else the error.
    Cached, as a failed torch import is not retried cheaply; :func:`reset_import_check` clears."""
    if "result" not in _IMPORT_CHECK:
        prefer_passive_wait()  # this import may be the one that loads torch (and OpenMP)
        try:
            import prosplat.worker.tasks  # noqa: F401
        except Exception as e:  # noqa: BLE001 - any import failure means "not usable here"
            _IMPORT_CHECK["result"] = f"{type(e).__name__}: {e}"
        else:
            _IMPORT_CHECK["result"] = None
    return _IMPORT_CHECK["result"]


def reset_import_check() -> None:
    _IMPORT_CHECK.clear()


def prefer_passive_wait() -> None:
    """Idle OpenMP threads sleep instead of spinning (a busy CPU made torch's spinning
    threads 10x slower; :mod:`prosplat.worker.threads`). Only works before torch loads, so
    it is set before the first in-process job imports it, and not at all if something else
    loaded torch first (the worker then picks fewer threads); a user's own setting wins."""
    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def prosplat_source_root() -> str | None:
    """The folder holding the ``prosplat`` package this add-on found (for an external
    worker's PYTHONPATH, so both sides speak the same protocol), or None."""
    spec = importlib.util.find_spec("prosplat")
    if spec is None or not spec.submodule_search_locations:
        return None
    return os.path.dirname(list(spec.submodule_search_locations)[0])
