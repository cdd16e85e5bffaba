"""ProSplat for Blender: posed images -> 3D Gaussians -> enhanced renders for any camera.

A Blender extension (``blender_manifest.toml``, Blender >= 4.2) and thin glue over the
``prosplat`` library: operators and a sidebar panel (3D Viewport > N > ProSplat), Gaussians
shown as a point cloud, and a headless API (:mod:`.blender.api`). The heavy work runs in
:mod:`prosplat.worker`, in Blender's Python or an external one, so registering never needs
torch.

Two layers: :mod:`.core` never imports ``bpy`` or ``mathutils`` (maths, pins, jobs, the
worker process, pip; tested in plain Python), and :mod:`.blender` is everything that does.
``api`` is imported here so scripts keep ``from addon import api`` (or
``from bl_ext.user_default.prosplat import api``).
"""

from __future__ import annotations

import bpy

from .blender import (
    api,  # noqa: F401 - the headless API, as ``addon.api`` for scripts
    operators,
    preferences,
    properties,
    runtime,
    ui,
)
from .core import jobs

bl_info = {  # read only by Blender's legacy add-on loader; extensions use the manifest
    "name": "ProSplat",
    "blender": (4, 2, 0),
    "category": "3D View",
    "location": "3D Viewport > Sidebar > ProSplat",
    "description": "Posed images to 3D Gaussians and enhanced renders for any camera",
}

_CLASSES = (*preferences.CLASSES, *properties.CLASSES, *operators.CLASSES, *ui.CLASSES)


def register() -> None:
    runtime.add_deps_to_path()
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    properties.register_props()
    bpy.types.TOPBAR_MT_file_import.append(ui.menu_import)
    bpy.types.TOPBAR_MT_file_export.append(ui.menu_export)


def unregister() -> None:
    jobs.shutdown_workers()  # the session's external worker (atexit covers Blender's exit)
    bpy.types.TOPBAR_MT_file_export.remove(ui.menu_export)
    bpy.types.TOPBAR_MT_file_import.remove(ui.menu_import)
    properties.unregister_props()
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
