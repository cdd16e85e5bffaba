"""Blender's own Gaussian splats (5.3+): a ``GAUSSIAN_SPLAT`` point cloud that EEVEE and
Cycles render as splats, in the layout Blender's own File > Import > PLY writes
(:func:`..core.splat_math.native_attributes`: ``rotation``, ``scale``, ``radiance:base``,
``radiance:sh_*``), so the add-on's clouds render like Blender's import and Blender's tools
open them.

Blender stores only the rounded linear values (``exp(scale)``, ``sigmoid(opacity)``, the unit
quaternion), so a cloud made here also keeps the PLY's ``opacity``, ``scale_*`` and ``rot_*``
as float point attributes (:data:`..core.splat_math.EXACT_NAMES`; Blender's splat drawing ignores
them) and Export PLY stays bit-exact. A cloud Blender imported itself has none of them and is
read back through the native values (:func:`read_arrays`).

Which path a Blender takes is a feature check (:func:`supported`), not a version number.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core import splat_math

#: Blender's own point-cloud attributes, never passed on as Gaussian attributes.
_BUILTIN = {"position", "radius", "rotation", "scale", splat_math.NATIVE_BASE}
#: Attribute type and the name of its value in ``attribute.data``, by component count.
_TYPES = {
    1: ("FLOAT", "value"),
    3: ("FLOAT_VECTOR", "vector"),
    4: ("QUATERNION", "value"),
}


def supported() -> bool:
    """Feature check: does this Blender's point cloud have the ``GAUSSIAN_SPLAT`` type (and a
    way to size a new cloud)?"""
    cloud = getattr(bpy.types, "PointCloud", None)
    prop = cloud.bl_rna.properties.get("type") if cloud is not None else None
    if prop is None or "resize" not in cloud.bl_rna.functions:
        return False
    return "GAUSSIAN_SPLAT" in {item.identifier for item in prop.enum_items}


def is_native(obj) -> bool:
    """A ``GAUSSIAN_SPLAT`` point cloud object (made here or by Blender's importers)."""
    return (
        obj is not None
        and obj.type == "POINTCLOUD"
        and getattr(obj.data, "type", "") == "GAUSSIAN_SPLAT"
        and splat_math.NATIVE_BASE in obj.data.attributes
    )


def _set(attrs, name: str, values: np.ndarray, kind: str | None = None) -> None:
    flat = np.ascontiguousarray(values, dtype=np.float32)
    width = 1 if flat.ndim == 1 else flat.shape[1]
    kind_, field = ("FLOAT4", "vector") if kind == "FLOAT4" else _TYPES[width]
    attr = attrs.get(name) or attrs.new(name, kind_, "POINT")
    attr.data.foreach_set(field, flat.ravel())


def create_object(name: str, arrays: dict[str, np.ndarray], collection):
    """A new ``GAUSSIAN_SPLAT`` point cloud object in ``collection`` from our point attributes
    (all or nothing: on any error the half-built cloud is removed before the error goes on).
    The caller sets the object's ProSplat properties and render visibility."""
    native = splat_math.native_attributes(arrays)
    n = native["position"].shape[0]
    cloud = bpy.data.pointclouds.new(name)
    obj = None
    try:
        cloud.resize(n)
        cloud.type = "GAUSSIAN_SPLAT"
        attrs = cloud.attributes
        for key, values in native.items():
            _set(attrs, key, values, "FLOAT4" if key == splat_math.NATIVE_BASE else None)
        for key, values in arrays.items():  # the exact PLY values and extras (prosplat_view)
            if key in native or key == "color" or key.startswith(("f_dc_", "f_rest_")):
                continue
            values = np.asarray(values, dtype=np.float32).reshape(-1)
            if values.shape[0] != n:
                raise ValueError(f"attribute '{key}' has {values.shape[0]} values for {n} points")
            _set(attrs, key, values)
        cloud.update_tag()
        obj = bpy.data.objects.new(name, cloud)
        collection.objects.link(obj)
    except BaseException:
        if obj is not None:
            bpy.data.objects.remove(obj)
        bpy.data.pointclouds.remove(cloud)
        raise
    return obj


def _get(attr, n: int, width: int) -> np.ndarray:
    field = "value" if attr.data_type in ("FLOAT", "QUATERNION") else "vector"
    out = np.empty(n * width, dtype=np.float32)
    attr.data.foreach_get(field, out)
    return out.reshape(n, width) if width > 1 else out


def read_arrays(obj) -> dict[str, np.ndarray]:
    """Our point attributes (PLY encodings, object space) of a ``GAUSSIAN_SPLAT`` cloud: exact
    for one made here, decoded from Blender's values for one Blender imported (PLY, SPZ,
    glTF). Other float point attributes (``prosplat_view``) are passed on as they are."""
    attrs = obj.data.attributes
    n = len(obj.data.points)
    missing = [k for k in ("rotation", "scale") if k not in attrs]
    if missing:
        raise ValueError(f"'{obj.name}' is a Gaussian splat cloud without {', '.join(missing)}")
    native = {
        "position": _get(attrs["position"], n, 3),
        "rotation": _get(attrs["rotation"], n, 4),
        "scale": _get(attrs["scale"], n, 3),
        splat_math.NATIVE_BASE: _get(attrs[splat_math.NATIVE_BASE], n, 4),
    }
    for j in range(splat_math.native_sh_count(attrs.keys())):
        native[splat_math.native_sh_name(j)] = _get(attrs[splat_math.native_sh_name(j)], n, 3)
    extra = {
        a.name: _get(a, n, 1)
        for a in attrs
        if a.domain == "POINT" and a.data_type == "FLOAT" and not a.name.startswith(".")
        and a.name not in _BUILTIN
    }  # fmt: skip
    out = splat_math.ply_attributes(native, extra)
    for key, values in extra.items():
        out.setdefault(key, values)
    return out
