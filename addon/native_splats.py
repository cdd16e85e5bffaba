"""Blender's own Gaussian splats (5.3+): a point cloud with ``position``, ``rotation``,
``scale``, ``opacity`` and ``radiance:*`` attributes that EEVEE and Cycles render as splats.

UNTESTED on Blender 5.3: it was written against 5.3's release notes with Blender 5.0, where
the point cloud is built and read back (``test_addon_splat_display.py``) but not rendered as
splats. Everything else in the add-on uses the mesh + Geometry Nodes display
(:mod:`.splat_display`), which is also the fallback here if building the native object fails.

The point cloud also keeps the PLY-encoded attributes (``opacity`` as logit... see
:mod:`.pointcloud`) so export and Render View read it as they read the mesh; ``opacity`` is
that logit, so the native linear opacity is stored as ``splat_opacity`` unless 5.3 turns out to
want ``opacity`` itself (the one name the two layouts share; see :data:`OPACITY_ATTR`).
"""

from __future__ import annotations

import bpy
import numpy as np

from . import splat_math

#: First Blender with native Gaussian-splat point clouds.
MIN_VERSION = (5, 3, 0)
#: Where the linear opacity goes: the PLY's logit keeps the name ``opacity`` (exact export).
OPACITY_ATTR = "splat_opacity"
#: Attribute type and the name of its value in ``attribute.data`` by component count.
_TYPES = {1: ("FLOAT", "value"), 3: ("FLOAT_VECTOR", "vector"), 4: ("QUATERNION", "value")}


def supported() -> bool:
    """Feature check: a Blender whose point clouds render as Gaussian splats."""
    return bpy.app.version >= MIN_VERSION and hasattr(bpy.types, "PointCloud")


def _point_cloud_from_mesh(obj) -> None:
    """Turn the mesh object into a point cloud object in place (attributes kept): Blender has
    no Python API to size a new point cloud, but converting a mesh keeps every vertex."""
    with bpy.context.temp_override(
        active_object=obj, object=obj, selected_objects=[obj], selected_editable_objects=[obj]
    ):
        bpy.ops.object.convert(target="POINTCLOUD")


def create_object(name: str, arrays: dict[str, np.ndarray], collection, show_in_renders=False):
    """A native Gaussian-splat point cloud in ``collection`` (all or nothing)."""
    from . import pointcloud  # the mesh builder; imported here to keep the modules acyclic

    obj = pointcloud.create_mesh_object(name, arrays, collection, show_in_renders, False)
    try:
        _point_cloud_from_mesh(obj)
        if obj.type != "POINTCLOUD":
            raise RuntimeError("converting the mesh to a point cloud failed")
        attrs = obj.data.attributes
        for key, values in splat_math.native_attributes(arrays).items():
            if key == "position":
                continue
            flat = np.ascontiguousarray(values, dtype=np.float32)
            width = 1 if flat.ndim == 1 else flat.shape[1]
            name_ = OPACITY_ATTR if key == "opacity" else key
            kind, field = _TYPES[width]
            attr = attrs.get(name_) or attrs.new(name_, kind, "POINT")
            attr.data.foreach_set(field, flat.ravel())
        obj.data.update_tag()
    except BaseException:
        data = obj.data
        bpy.data.objects.remove(obj)
        if isinstance(data, bpy.types.Mesh):
            bpy.data.meshes.remove(data)
        elif data is not None:
            bpy.data.pointclouds.remove(data)
        raise
    return obj
