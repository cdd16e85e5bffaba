"""Questions about the built scene answered from evaluated geometry (after modifiers).

``scene_bounds`` fills ``SceneInfo.bounds_*`` (the renderer derives near/far from it),
``clear_path`` keeps the camera path away from props, and ``scene_fingerprint`` hashes
geometry and material settings so tests (and render caches) can tell scenes apart.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence

import bpy
import numpy as np

from .primitives import ROLE_KEY

GEOMETRY_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "META", "FONT"})
# anything larger than this is a sky dome / backdrop and would make near/far useless
HUGE = 5000.0


def object_aabbs(
    scene: bpy.types.Scene | None = None,
) -> list[tuple[bpy.types.Object, np.ndarray, np.ndarray]]:
    """World-space axis-aligned boxes ``(obj, lo, hi)`` of all geometry objects, evaluated."""
    scene = scene or bpy.context.scene
    depsgraph = bpy.context.evaluated_depsgraph_get()
    boxes = []
    for obj in scene.objects:
        if obj.type not in GEOMETRY_TYPES:
            continue
        co = world_vertices(obj.evaluated_get(depsgraph))
        if len(co):
            boxes.append((obj, co.min(axis=0), co.max(axis=0)))
    return boxes


def world_vertices(ev: bpy.types.Object) -> np.ndarray:
    """World-space vertices ``[N, 3]`` of an evaluated object's final mesh.

    Read from the mesh rather than ``bound_box``: in Blender 5.0 the evaluated ``bound_box``
    of a curve object is not its geometry's (a bevelled poly curve from x=0 to 1 reported
    -1..2), while the vertices are exact for every type.
    """
    me = ev.to_mesh()
    try:
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    co = co.reshape(-1, 3).astype(np.float64)
    mw = np.array(ev.matrix_world)
    return co @ mw[:3, :3].T + mw[:3, 3]


def scene_bounds(
    scene: bpy.types.Scene | None = None,
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Bounds ``(min, max)`` of all geometry, skipping sky domes (``role == "sky"`` or
    more than ``HUGE`` metres across). Raises ``ValueError`` on an empty scene."""
    los, his = [], []
    for obj, lo, hi in object_aabbs(scene):
        if obj.get(ROLE_KEY) == "sky" or float(np.max(hi - lo)) > HUGE:
            continue
        los.append(lo)
        his.append(hi)
    if not los:
        raise ValueError("scene_bounds: the scene has no geometry; build a scene first")
    lo, hi = np.min(los, axis=0), np.max(his, axis=0)
    return tuple(float(x) for x in lo), tuple(float(x) for x in hi)


def box_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Euclidean distance from points ``p [N, 3]`` to a box (0 inside)."""
    d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    return np.linalg.norm(d, axis=-1)


def clear_path(eyes: Sequence[Sequence[float]], margin: float) -> list[str]:
    """Remove props whose bounding box comes within ``margin`` of any eye.

    Layouts are designed to keep the path clear; this is the guarantee for the seeds where
    random placement still ends up too close. Structure (walls, ground) is never removed:
    if it is too close, the builder is wrong and this raises ``RuntimeError``.
    """
    p = np.asarray(eyes, dtype=np.float64)
    removed = []
    for obj, lo, hi in object_aabbs():
        if obj.get(ROLE_KEY) == "shell" or box_distance(p, lo, hi).min() >= margin:
            continue
        if obj.get(ROLE_KEY) != "prop":
            raise RuntimeError(f"camera path runs within {margin} m of structure {obj.name!r}")
        removed.append(obj.name)
        bpy.data.objects.remove(obj)
    return removed


def _hash_values(h: hashlib._Hash, values: Iterable[object]) -> None:
    for v in values:
        if isinstance(v, float):
            v = round(v, 5)
        elif hasattr(v, "__len__") and not isinstance(v, str):
            v = tuple(round(float(x), 5) for x in v)
        h.update(repr(v).encode())


def _hash_node_tree(h: hashlib._Hash, nt: bpy.types.NodeTree) -> None:
    skip = {"location", "location_absolute", "width", "height", "dimensions", "select"}
    for node in sorted(nt.nodes, key=lambda n: n.name):
        _hash_values(h, [node.bl_idname, node.name])
        for prop in node.bl_rna.properties:
            if prop.identifier in skip or prop.type not in {"ENUM", "FLOAT", "INT", "BOOLEAN"}:
                continue
            if prop.is_readonly or getattr(prop, "is_array", False):
                continue
            _hash_values(h, [prop.identifier, getattr(node, prop.identifier)])
        for sock in node.inputs:
            if hasattr(sock, "default_value") and not sock.is_linked:
                val = sock.default_value
                _hash_values(
                    h,
                    [
                        sock.identifier,
                        val
                        if isinstance(val, float)
                        else tuple(val)
                        if hasattr(val, "__len__")
                        else val,
                    ],
                )
        ramp = getattr(node, "color_ramp", None)
        if ramp is not None:
            for el in ramp.elements:
                _hash_values(h, [el.position, tuple(el.color)])
        image = getattr(node, "image", None)
        if image is not None:
            px = np.empty(len(image.pixels), np.float32)
            image.pixels.foreach_get(px)
            h.update(np.round(px, 3).tobytes())
    for link in nt.links:
        _hash_values(
            h,
            [
                link.from_node.name,
                link.from_socket.identifier,
                link.to_node.name,
                link.to_socket.identifier,
            ],
        )


def scene_fingerprint(scene: bpy.types.Scene | None = None) -> str:
    """SHA-256 of evaluated world-space vertices, lights, materials and world nodes."""
    scene = scene or bpy.context.scene
    depsgraph = bpy.context.evaluated_depsgraph_get()
    h = hashlib.sha256()
    for obj in sorted(scene.objects, key=lambda o: o.name):
        _hash_values(h, [obj.name, obj.type, *[tuple(r) for r in obj.matrix_world]])
        if obj.type in GEOMETRY_TYPES:
            ev = obj.evaluated_get(depsgraph)
            h.update(np.round(world_vertices(ev), 4).tobytes())
            _hash_values(h, [s.material.name for s in ev.material_slots if s.material is not None])
        elif obj.type == "LIGHT":
            d = obj.data
            _hash_values(h, [d.type, d.energy, tuple(d.color)])
    for mat in sorted(bpy.data.materials, key=lambda m: m.name):
        _hash_values(h, [mat.name])
        if mat.node_tree is not None:
            _hash_node_tree(h, mat.node_tree)
    if scene.world is not None and scene.world.node_tree is not None:
        _hash_node_tree(h, scene.world.node_tree)
    return h.hexdigest()
