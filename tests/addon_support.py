"""Shared helpers for the add-on's bpy tests (imported after ``pytest.importorskip("bpy")``)."""

from __future__ import annotations

import sys
from pathlib import Path

import bpy

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import addon  # noqa: E402


def ensure_registered() -> None:
    if not hasattr(bpy.types.Scene, "prosplat"):
        addon.register()


def reset_scene():
    """An empty factory scene with the add-on registered (each test file's ``blank``
    fixture); returns the scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    return bpy.context.scene


def run_op(op, **kwargs) -> tuple[set, str | None]:
    """Call an operator as a script would (EXEC); returns (result, error message or None).

    In background mode Blender turns an operator's ERROR report into a RuntimeError after the
    operator returned CANCELLED; that message is what a user would see in the status bar.
    """
    try:
        return op("EXEC_DEFAULT", **kwargs), None
    except RuntimeError as e:
        return {"CANCELLED"}, str(e)


def data_counts() -> dict[str, int]:
    """How many of each kind of data-block exist (to prove nothing half-made was left)."""
    kinds = ("objects", "meshes", "pointclouds", "cameras", "collections", "images", "node_groups",
             "materials")  # fmt: skip
    return {k: len(getattr(bpy.data, k)) for k in kinds}


def evaluated_instances(obj) -> list:
    """World matrices (4x4 numpy) of the instances the display modifier makes from ``obj``,
    in the viewport's depsgraph (where ``Is Viewport`` is true)."""
    import numpy as np

    depsgraph = bpy.context.evaluated_depsgraph_get()
    return [
        np.array(inst.matrix_world)
        for inst in depsgraph.object_instances
        if inst.is_instance and inst.parent is not None and inst.parent.original == obj
    ]
