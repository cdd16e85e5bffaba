"""Gaussians as a Blender point cloud: a mesh with one vertex per Gaussian.

The vertices are the means; every other parameter is a float point attribute named as in the
3DGS PLY (``opacity``, ``scale_0..2``, ``rot_0..3``, ``f_dc_0..2``, ``f_rest_*``, in the PLY's
encodings), plus the colour attribute :data:`COLOR_ATTR` for display. The arrays come from
:func:`prosplat.convert.pointcloud.to_attributes` and are written with ``foreach_set`` (no
per-vertex Python), so half a million Gaussians take about a second. The display (oriented
ellipsoids, opacity, viewport point budget) is :mod:`.splat_display`.

The colour attribute is not called ``color``: Cycles maps the attribute name ``color`` to its
built-in volume-colour attribute (``ATTR_STD_VOLUME_COLOR``, as ``density``, ``flame``,
``temperature``...), so an Attribute node asking for ``color`` never found the splats'
colours and Cycles rendered them black, fresh or reloaded (``tests/addon/test_addon_splat_display.py``).

New objects are hidden from final renders (``hide_render``): the cloud is a reference for
placing cameras, and the artist's F12 render should not contain it unless asked.

On a Blender with native Gaussian splats (5.3+, a feature check) new objects are
``GAUSSIAN_SPLAT`` point clouds instead (:mod:`.native_splats`); this mesh and its Geometry
Nodes display are the fallback. Both kinds, and Blender's own splat imports, read back
through :func:`read_arrays`.
"""

from __future__ import annotations

import bpy
import numpy as np

from . import native_splats, splat_display

KIND_PROP = "prosplat_kind"  # "gaussians" on objects made here
INPUTS_PROP = "prosplat_inputs"  # the input collection a reconstruction came from
#: The display colour (linear RGB, alpha = opacity); see the module docstring for the name.
COLOR_ATTR = splat_display.COLOR_ATTR
MODIFIER = splat_display.MODIFIER
_SKIP = ("position", "color")


def _scalar_names(arrays: dict[str, np.ndarray]) -> list[str]:
    return [k for k in arrays if k not in _SKIP]


def create_object(
    name: str,
    arrays: dict[str, np.ndarray],
    collection,
    show_in_renders=False,
    native: bool | None = None,
):
    """The Gaussian object for ``arrays``, hidden from final renders unless
    ``show_in_renders``: Blender's own ``GAUSSIAN_SPLAT`` cloud where it has them
    (``native=None``: the feature check :func:`.native_splats.supported`; the mesh if building
    it fails), else the mesh with the Geometry Nodes display."""
    if native_splats.supported() if native is None else native:
        try:
            obj = native_splats.create_object(name, arrays, collection)
        except (RuntimeError, ValueError, KeyError, TypeError, AttributeError) as e:
            print(f"ProSplat: native Gaussian splats failed ({e}); using the mesh display")
        else:
            obj[KIND_PROP] = "gaussians"
            obj.hide_render = not show_in_renders
            return obj
    return create_mesh_object(name, arrays, collection, show_in_renders)


def create_mesh_object(
    name: str,
    arrays: dict[str, np.ndarray],
    collection,
    show_in_renders=False,
    display: bool = True,
):
    """A new Gaussian mesh object in ``collection`` (all or nothing: on any error the
    half-built mesh is removed before the error propagates), hidden from final renders unless
    ``show_in_renders``, with the splat display modifier if ``display``."""
    pos = np.ascontiguousarray(arrays["position"], dtype=np.float32).reshape(-1, 3)
    n = pos.shape[0]
    mesh = bpy.data.meshes.new(name)
    obj = None
    try:
        mesh.vertices.add(n)
        mesh.vertices.foreach_set("co", pos.ravel())
        for key in _scalar_names(arrays):
            values = np.ascontiguousarray(arrays[key], dtype=np.float32).reshape(-1)
            if values.shape[0] != n:
                raise ValueError(f"attribute '{key}' has {values.shape[0]} values for {n} points")
            mesh.attributes.new(key, "FLOAT", "POINT").data.foreach_set("value", values)
        if "color" in arrays:
            col = mesh.color_attributes.new(COLOR_ATTR, "FLOAT_COLOR", "POINT")
            col.data.foreach_set("color", np.ascontiguousarray(arrays["color"], np.float32).ravel())
            mesh.color_attributes.active_color = col
            if hasattr(mesh.color_attributes, "render_color_index"):
                mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
        mesh.update()
        obj = bpy.data.objects.new(name, mesh)
        obj[KIND_PROP] = "gaussians"
        obj.hide_render = not show_in_renders
        if display:
            splat_display.add_modifier(obj, arrays)
        collection.objects.link(obj)
    except BaseException:
        if obj is not None:
            bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)
        raise
    return obj


def is_gaussians(obj) -> bool:
    """A mesh or point cloud holding the Gaussian point attributes, or any of Blender's own
    ``GAUSSIAN_SPLAT`` clouds (its PLY, SPZ or glTF import)."""
    if obj is None or obj.type not in ("MESH", "POINTCLOUD"):
        return False
    return "opacity" in obj.data.attributes or native_splats.is_native(obj)


def read_arrays(obj) -> dict[str, np.ndarray]:
    """The point attributes of a Gaussian object (positions in object space), in the PLY's
    encodings (:func:`prosplat.convert.pointcloud.from_attributes` reads them).

    Raises:
        ValueError: not a mesh (or point cloud), or one without the Gaussian attributes.
    """
    if obj is None or obj.type not in ("MESH", "POINTCLOUD"):
        raise ValueError(f"{getattr(obj, 'name', obj)!r} is not a mesh; select a Gaussian object")
    if native_splats.is_native(obj):
        return native_splats.read_arrays(obj)
    mesh = obj.data
    n = point_count(obj)
    pos = np.empty(n * 3, dtype=np.float32)
    if obj.type == "MESH":
        mesh.vertices.foreach_get("co", pos)
    else:
        mesh.attributes["position"].data.foreach_get("vector", pos)
    out = {"position": pos.reshape(n, 3)}
    for attr in mesh.attributes:
        if attr.domain != "POINT" or attr.data_type != "FLOAT" or attr.name.startswith("."):
            continue
        if obj.type == "POINTCLOUD" and attr.name == "radius":  # Blender's own, not a Gaussian's
            continue
        values = np.empty(n, dtype=np.float32)
        attr.data.foreach_get("value", values)
        out[attr.name] = values
    if "opacity" not in out or "scale_0" not in out:
        raise ValueError(
            f"'{obj.name}' is not a Gaussian point cloud (its mesh has no 'opacity'/'scale_*' "
            "point attributes); import a 3DGS PLY or reconstruct one"
        )
    return out


def point_count(obj) -> int:
    return len(obj.data.vertices) if obj.type == "MESH" else len(obj.data.points)


def world_matrix(obj) -> list[list[float]]:
    return [list(row) for row in obj.matrix_world]
