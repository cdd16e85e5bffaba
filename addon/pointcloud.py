"""Gaussians as a Blender point cloud: a mesh with one vertex per Gaussian.

The vertices are the means; every other parameter is a float point attribute named as in the
3DGS PLY (``opacity``, ``scale_0..2``, ``rot_0..3``, ``f_dc_0..2``, ``f_rest_*``, in the PLY's
encodings), plus ``color`` for display. The arrays come from
:func:`prosplat.convert.pointcloud.to_attributes` and are written with ``foreach_set`` (no
per-vertex Python), so half a million Gaussians take about a second. A Geometry Nodes
modifier turns the vertices into points whose radius follows the Gaussian's largest scale and
whose material shows the colour attribute (Material Preview / Rendered shading).
"""

from __future__ import annotations

import bpy
import numpy as np

KIND_PROP = "prosplat_kind"  # "gaussians" on objects made here
INPUTS_PROP = "prosplat_inputs"  # the input collection a reconstruction came from
NODE_GROUP = "ProSplat Gaussians"
MATERIAL = "ProSplat Gaussian"
MODIFIER = "ProSplat Points"
RADIUS_SOCKET = "Radius Scale"
_SKIP = ("position", "color")


def _scalar_names(arrays: dict[str, np.ndarray]) -> list[str]:
    return [k for k in arrays if k not in _SKIP]


def create_object(name: str, arrays: dict[str, np.ndarray], collection, radius_scale=1.0):
    """A new Gaussian point-cloud object in ``collection`` (all or nothing: on any error the
    half-built mesh is removed before the error propagates)."""
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
            col = mesh.color_attributes.new("color", "FLOAT_COLOR", "POINT")
            col.data.foreach_set("color", np.ascontiguousarray(arrays["color"], np.float32).ravel())
            mesh.color_attributes.active_color = col
            if hasattr(mesh.color_attributes, "render_color_index"):
                mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
        mesh.update()
        obj = bpy.data.objects.new(name, mesh)
        obj[KIND_PROP] = "gaussians"
        add_points_modifier(obj, radius_scale)
        collection.objects.link(obj)
    except BaseException:
        if obj is not None:
            bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)
        raise
    return obj


def is_gaussians(obj) -> bool:
    return obj is not None and obj.type == "MESH" and "opacity" in obj.data.attributes


def read_arrays(obj) -> dict[str, np.ndarray]:
    """The point attributes of a Gaussian object (positions in object space).

    Raises:
        ValueError: not a mesh, or a mesh without the Gaussian attributes.
    """
    if obj is None or obj.type != "MESH":
        raise ValueError(f"{getattr(obj, 'name', obj)!r} is not a mesh; select a Gaussian object")
    mesh = obj.data
    n = len(mesh.vertices)
    pos = np.empty(n * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", pos)
    out = {"position": pos.reshape(n, 3)}
    for attr in mesh.attributes:
        if attr.domain != "POINT" or attr.data_type != "FLOAT" or attr.name.startswith("."):
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


def world_matrix(obj) -> list[list[float]]:
    return [list(row) for row in obj.matrix_world]


# ---- Geometry Nodes ---------------------------------------------------------------------------
def _socket(tree, name: str, in_out: str, socket_type: str):
    return tree.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type)


def _named(tree, name: str, location):
    node = tree.nodes.new("GeometryNodeInputNamedAttribute")
    node.data_type = "FLOAT"
    node.inputs["Name"].default_value = name
    node.location = location
    return node


def _math(tree, op: str, location, value=None):
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = op
    node.location = location
    if value is not None:
        node.inputs[1].default_value = value
    return node


def build_node_group():
    """Mesh -> points with radius exp(max(scale_*)) x Radius Scale, material showing ``color``.

    Built with node types and sockets that exist unchanged in Blender 4.2 through 5.0.
    """
    tree = bpy.data.node_groups.new(NODE_GROUP, "GeometryNodeTree")
    _socket(tree, "Geometry", "INPUT", "NodeSocketGeometry")
    radius = _socket(tree, RADIUS_SOCKET, "INPUT", "NodeSocketFloat")
    radius.default_value, radius.min_value = 1.0, 0.0
    _socket(tree, "Geometry", "OUTPUT", "NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    group_in = nodes.new("NodeGroupInput")
    group_in.location = (-900, 0)
    group_out = nodes.new("NodeGroupOutput")
    group_out.location = (500, 0)
    scales = [_named(tree, f"scale_{i}", (-900, -200 - 160 * i)) for i in range(3)]
    max01 = _math(tree, "MAXIMUM", (-650, -250))
    max012 = _math(tree, "MAXIMUM", (-480, -300))
    exp = _math(tree, "EXPONENT", (-310, -300))
    mul = _math(tree, "MULTIPLY", (-140, -300))
    links.new(scales[0].outputs["Attribute"], max01.inputs[0])
    links.new(scales[1].outputs["Attribute"], max01.inputs[1])
    links.new(max01.outputs[0], max012.inputs[0])
    links.new(scales[2].outputs["Attribute"], max012.inputs[1])
    links.new(max012.outputs[0], exp.inputs[0])
    links.new(exp.outputs[0], mul.inputs[0])
    links.new(group_in.outputs[RADIUS_SOCKET], mul.inputs[1])
    to_points = nodes.new("GeometryNodeMeshToPoints")
    to_points.location = (60, 0)
    links.new(group_in.outputs["Geometry"], to_points.inputs["Mesh"])
    links.new(mul.outputs[0], to_points.inputs["Radius"])
    set_mat = nodes.new("GeometryNodeSetMaterial")
    set_mat.location = (280, 0)
    set_mat.inputs["Material"].default_value = material()
    links.new(to_points.outputs["Points"], set_mat.inputs["Geometry"])
    links.new(set_mat.outputs["Geometry"], group_out.inputs["Geometry"])
    return tree


def material():
    """An emission material showing the ``color`` attribute (the splat's own colour, unlit)."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(MATERIAL)
    if bpy.app.version < (5, 0, 0):  # always node-based from 5.0 (the flag is deprecated)
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = "color"
    attr.location = (-400, 0)
    emit = nodes.new("ShaderNodeEmission")
    emit.location = (-150, 0)
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (100, 0)
    links.new(attr.outputs["Color"], emit.inputs["Color"])
    links.new(emit.outputs["Emission"], out.inputs["Surface"])
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    return mat


def node_group():
    """The shared node group, rebuilt if a user deleted or broke it."""
    tree = bpy.data.node_groups.get(NODE_GROUP)
    if tree is None or tree.bl_idname != "GeometryNodeTree" or "Mesh to Points" not in tree.nodes:
        tree = build_node_group()
    return tree


def add_points_modifier(obj, radius_scale: float = 1.0):
    mod = obj.modifiers.new(MODIFIER, "NODES")
    mod.node_group = node_group()
    socket = next(
        s for s in mod.node_group.interface.items_tree
        if getattr(s, "in_out", "") == "INPUT" and s.name == RADIUS_SOCKET
    )  # fmt: skip
    mod[socket.identifier] = float(radius_scale)
    return mod
