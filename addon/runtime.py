"""Where the heavy work can run, and the add-on's settings, without importing torch.

Blender's bundled Python has numpy but usually not torch. The add-on imports ``prosplat``
only inside jobs (never at register time), so it registers, imports posed images through an
external worker, and shows its preferences whether or not torch is there. Requirements that
the preferences install with pip go to a folder of the add-on's own (added to ``sys.path``
after Blender's, so Blender's numpy stays the one in use).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import bpy

PACKAGE = __package__ or "addon"

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


@dataclass
class Defaults:
    """The preference values used when the add-on runs without its preferences (scripts,
    tests, or registered by hand rather than enabled)."""

    device: str = "AUTO"
    weights_path: str = ""
    improve_weights_path: str = ""
    enhance: bool = True
    fill_holes: str = "RAW"  # BENCHMARKS "Raw views filled by default": why raw views only
    budget: int = 0
    refine_seconds: float = 3.0  # README, "Refinement": why this default
    distill_steps: int = 0  # README, "Consistent views": off, since it costs before frame one
    max_input_size: int = 128  # the size refinement fits; the generator runs at its own
    python_path: str = ""
    threads: int = 0  # 0: automatic, prosplat.worker.threads.auto_threads
    keep_worker: bool = True
    torch_build: str = "CPU"
    extra: dict = field(default_factory=dict)


def prefs(context=None):
    """The add-on's preferences, or :class:`Defaults` when they are not registered."""
    context = context or bpy.context
    addon = context.preferences.addons.get(PACKAGE) if context.preferences else None
    if addon is not None and addon.preferences is not None:
        return addon.preferences
    return Defaults()


def deps_dir() -> Path:
    """The folder the install button puts requirements into (created on demand)."""
    if PACKAGE.startswith("bl_ext.") and hasattr(bpy.utils, "extension_path_user"):
        return Path(bpy.utils.extension_path_user(PACKAGE, path="site-packages", create=True))
    return Path(bpy.utils.user_resource("CONFIG", path="prosplat/site-packages", create=True))


def add_deps_to_path() -> None:
    """Make installed requirements importable (appended: Blender's own modules win)."""
    d = deps_dir()
    if d.is_dir() and str(d) not in sys.path:
        sys.path.append(str(d))
        importlib.invalidate_caches()


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


def thread_count(context=None) -> int:
    """The *CPU Threads* preference (0: automatic, decided by the worker)."""
    return max(0, int(getattr(prefs(context), "threads", 0) or 0))


def keep_worker(context=None) -> bool:
    """Whether external jobs go to the session's long-lived worker (else one process each)."""
    return bool(getattr(prefs(context), "keep_worker", True))


def external_python(context=None) -> str | None:
    """The configured external interpreter, or None to run in Blender's Python."""
    path = getattr(prefs(context), "python_path", "") or ""
    return bpy.path.abspath(path) if path.strip() else None


def prosplat_source_root() -> str | None:
    """The folder holding the ``prosplat`` package this add-on found (for an external
    worker's PYTHONPATH, so both sides speak the same protocol), or None."""
    spec = importlib.util.find_spec("prosplat")
    if spec is None or not spec.submodule_search_locations:
        return None
    return os.path.dirname(list(spec.submodule_search_locations)[0])


def device_name(context=None) -> str:
    return str(getattr(prefs(context), "device", "AUTO")).lower()


def weights_path(context=None, name: str = "weights_path") -> str | None:
    """A checkpoint path from the preferences (None: the weights shipped with prosplat)."""
    path = getattr(prefs(context), name, "") or ""
    return bpy.path.abspath(path) if path.strip() else None
