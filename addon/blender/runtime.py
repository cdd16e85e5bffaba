"""Where the heavy work runs, and the add-on's settings, without importing torch.

Blender's bundled Python has numpy but usually not torch. The add-on imports ``prosplat``
only inside jobs (never at register time), so it registers, imports posed images through an
external worker, and shows its preferences whether or not torch is there. :func:`make_job`
sends a job where the preferences say (:mod:`..core.jobs`: a thread here or the external
Python). Requirements that the preferences install with pip go to a folder of the add-on's
own (added to ``sys.path`` after Blender's, so Blender's numpy stays the one in use); what
they are and whether they import is :mod:`..core.requirements`.
"""

from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import bpy

from ..core import jobs, requirements

#: The add-on's own package (``addon``, or ``bl_ext.user_default.prosplat`` when installed):
#: the parent of this ``blender`` subpackage, under which Blender keeps its preferences.
PACKAGE = (__package__ or "addon.blender").rpartition(".")[0]


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
    merge_flat: bool = False  # BENCHMARKS "Merging flat blocks": fewer points, views no faster
    refine_seconds: float = 3.0  # README, "Refinement": why this default
    distill_steps: int = 0  # README, "Consistent views": off, since it costs before frame one
    max_input_size: int = (
        512  # the size the Gaussians are made at; the generator matches at its own
    )
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


def device_name(context=None) -> str:
    return str(getattr(prefs(context), "device", "AUTO")).lower()


def weights_path(context=None, name: str = "weights_path") -> str | None:
    """A checkpoint path from the preferences (None: the weights shipped with prosplat)."""
    path = getattr(prefs(context), name, "") or ""
    return bpy.path.abspath(path) if path.strip() else None


def make_job(task: str, params: dict[str, Any], context=None) -> jobs.Job:
    """The job for ``task`` where the preferences say: the external Python if one is set,
    else a thread here. Raises :class:`~..core.jobs.JobError` when neither can run ``prosplat``."""
    params = {**params, "threads": thread_count(context)}
    python = external_python(context)
    if python:
        return jobs.ExternalJob(task, params, python, keep_worker(context))
    err = requirements.check_prosplat_import()
    if err is not None:
        raise jobs.JobError(
            "ProSplat cannot run in Blender's Python yet "
            f"({err}). In Preferences > Add-ons > ProSplat, install the requirements or set "
            "an external Python that has prosplat installed."
        )
    return jobs.ThreadJob(task, params)


def run_sync(task: str, params: dict[str, Any], context=None, timeout: float | None = None) -> dict:
    """Start ``task`` and wait for it (scripts and ``execute``)."""
    return make_job(task, params, context).start().wait(timeout)
