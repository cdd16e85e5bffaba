"""How a Gaussian object looks: oriented, semi-transparent ellipsoids from Geometry Nodes.

The Gaussian mesh keeps the PLY's numbers untouched (the PLY round trip stays exact); this
modifier only draws them. Per Gaussian it makes one instance of a low-poly sphere

* at the mean, rotated by the quaternion ``rot_0..3`` (w, x, y, z, as the 3DGS PLY and
  DESIGN.md store it; normalised here, as the rasterizer does),
* scaled to semi-axes ``Sigma * exp(scale_i)``, each clamped to ``Max Size`` so a far ground
  splat cannot cover the scene (the default comes from the cloud,
  :func:`..core.splat_math.default_max_size`),
* carrying the colour and opacity as the instance attribute ``splat_color``.

Only the instanced points are made (a ``Points`` node sampling the mesh by index), so the 60
SH attributes of a degree-3 cloud are not copied onto a million instances.

In the viewport (``Is Viewport``) at most ``Viewport Points`` splats are kept, evenly spread
over the file's order, so a million-splat cloud stays interactive; final renders draw them all.

The material is emission (the splats' colours are radiance, already lit) mixed with
transparency by ``alpha = opacity * exp(-1/2 (Sigma r)^2)``: ``r`` is how close the view ray
passes to the splat's centre in the instance's own unit-sphere space, so the falloff is the
Gaussian's own footprint, ellipse and all, in Material Preview, EEVEE and Cycles. Back faces
are transparent, so each splat is counted once. Its emission does not light the scene
(``emission_sampling = NONE``): a million tiny lights would only slow Cycles down.

Names are versioned (:data:`VERSION`): a file made by an older add-on keeps its own node group
and material, and new objects get the current ones.
"""

from __future__ import annotations

from collections.abc import Mapping

import bpy
import numpy as np

from ..core.splat_math import DEFAULT_SIGMA, DEFAULT_VIEWPORT_POINTS, default_max_size

VERSION = 2
NODE_GROUP = "ProSplat Splats"
MATERIAL = "ProSplat Splat"
MODIFIER = "ProSplat Splats"
#: Display colour attribute (linear RGB, alpha = opacity), on the mesh and on the instances.
COLOR_ATTR = "splat_color"
#: Per-instance copy of the modifier's Sigma, for the material's falloff.
SIGMA_ATTR = "splat_sigma"
SIGMA_SOCKET = "Sigma"
MAX_SIZE_SOCKET = "Max Size"
VIEWPORT_SOCKET = "Viewport Points"
#: The modifier inputs the panel shows, in order.
SOCKETS = (SIGMA_SOCKET, MAX_SIZE_SOCKET, VIEWPORT_SOCKET)
_VERSION_PROP = "prosplat_display_version"
_SPHERE_SUBDIVISIONS = 2  # 80 triangles: round enough at 2 sigma, light enough for 200K


# ---- node helpers -------------------------------------------------------------------------------
class _Builder:
    """Terse node creation for one tree (positions are only for a readable layout)."""

    def __init__(self, tree) -> None:
        self.tree, self.nodes, self.links = tree, tree.nodes, tree.links

    def node(self, kind: str, x: float, y: float, **props):
        node = self.nodes.new(kind)
        node.location = (x, y)
        for key, value in props.items():
            setattr(node, key, value)
        return node

    def link(self, out, inp) -> None:
        self.links.new(out, inp)

    def math(self, op: str, x: float, y: float, a=None, b=None):
        """A Math node; ``a``/``b`` are sockets to link or numbers to set."""
        node = self.node("ShaderNodeMath", x, y, operation=op)
        for i, v in enumerate((a, b)):
            if v is None:
                continue
            if isinstance(v, (int, float)):
                node.inputs[i].default_value = float(v)
            else:
                self.link(v, node.inputs[i])
        return node.outputs[0]


def _named(b: _Builder, name: str, x: float, y: float, data_type: str = "FLOAT"):
    node = b.node("GeometryNodeInputNamedAttribute", x, y, data_type=data_type)
    node.inputs["Name"].default_value = name
    return node.outputs["Attribute"]


def _sample(b: _Builder, geometry, value, index, data_type: str, x: float, y: float):
    """``value`` (a field on the Gaussian mesh's points) at point ``index``."""
    node = b.node("GeometryNodeSampleIndex", x, y, data_type=data_type, domain="POINT")
    b.link(geometry, node.inputs["Geometry"])
    b.link(value, node.inputs["Value"])
    b.link(index, node.inputs["Index"])
    return node.outputs[0]


def _input_socket(tree, name: str, socket_type: str, default, minimum=None, maximum=None):
    sock = tree.interface.new_socket(name=name, in_out="INPUT", socket_type=socket_type)
    sock.default_value = default
    if minimum is not None:
        sock.min_value = minimum
    if maximum is not None:
        sock.max_value = maximum
    return sock


# ---- the node group ------------------------------------------------------------------------------
def build_node_group():
    """The display node group (see the module docstring). Built only with nodes and sockets
    present in Blender 4.2 through 5.0."""
    tree = bpy.data.node_groups.new(NODE_GROUP, "GeometryNodeTree")
    tree[_VERSION_PROP] = VERSION
    tree.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    sigma_sock = _input_socket(tree, SIGMA_SOCKET, "NodeSocketFloat", DEFAULT_SIGMA, 0.1, 5.0)
    sigma_sock.description = "Semi-axes drawn, in standard deviations of each Gaussian"
    size_sock = _input_socket(tree, MAX_SIZE_SOCKET, "NodeSocketFloat", 1.0, 0.0)
    size_sock.description = "Largest semi-axis drawn (scene units), so far splats stay small"
    vp_sock = _input_socket(tree, VIEWPORT_SOCKET, "NodeSocketInt", DEFAULT_VIEWPORT_POINTS, 0)
    vp_sock.description = "Most splats the viewport shows (0: all); renders show all"
    tree.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")

    b = _Builder(tree)
    gin = b.node("NodeGroupInput", -1600, 0)
    gout = b.node("NodeGroupOutput", 900, 0)
    mesh = gin.outputs["Geometry"]

    # keep ratio: 1 in renders; min(1, budget / N) in the viewport (budget 0: all)
    count = b.node("GeometryNodeAttributeDomainSize", -1400, 300)
    b.link(mesh, count.inputs["Geometry"])
    n = count.outputs["Point Count"]
    budget = gin.outputs[VIEWPORT_SOCKET]
    ratio = b.math("DIVIDE", -1200, 300, budget, n)
    unlimited = b.math("LESS_THAN", -1200, 450, budget, 0.5)
    keep_vp = b.math("MINIMUM", -1000, 300, b.math("ADD", -1050, 450, ratio, unlimited), 1.0)
    is_vp = b.node("GeometryNodeIsViewport", -1000, 500).outputs[0]
    drop = b.math("MULTIPLY", -800, 400, is_vp, b.math("SUBTRACT", -850, 300, 1.0, keep_vp))
    keep = b.math("SUBTRACT", -650, 400, 1.0, drop)

    # one light point per Gaussian, remembering its vertex index, then the viewport subset
    index = b.node("GeometryNodeInputIndex", -1400, -100).outputs[0]
    position = b.node("GeometryNodeInputPosition", -1400, -200).outputs[0]
    points = b.node("GeometryNodePoints", -1000, 0)
    b.link(n, points.inputs["Count"])
    b.link(_sample(b, mesh, position, index, "FLOAT_VECTOR", -1200, -150),
           points.inputs["Position"])  # fmt: skip
    store_src = b.node("GeometryNodeStoreNamedAttribute", -800, 0, data_type="INT", domain="POINT")
    store_src.inputs["Name"].default_value = ".splat_src"
    b.link(points.outputs[0], store_src.inputs["Geometry"])
    b.link(index, store_src.inputs["Value"])
    # point i is kept where floor((i+1) k) > floor(i k): exactly floor(N k) points, evenly
    # spread over the file's order (a generator writes each view's pixels in order, so this
    # thins every view alike); the two floors of neighbours are the same float ops, so the
    # sum telescopes exactly and the budget is a hard bound.
    after = b.math("FLOOR", -500, 250, b.math("MULTIPLY", -600, 250,
                   b.math("ADD", -700, 250, index, 1.0), keep))  # fmt: skip
    before = b.math("FLOOR", -500, 100, b.math("MULTIPLY", -600, 100, index, keep))
    dropped = b.math("LESS_THAN", -400, 200, b.math("SUBTRACT", -450, 200, after, before), 0.5)
    subset = b.node("GeometryNodeDeleteGeometry", -350, 0, domain="POINT")
    b.link(store_src.outputs[0], subset.inputs["Geometry"])
    b.link(dropped, subset.inputs["Selection"])
    src = _named(b, ".splat_src", -350, -250, "INT")

    # rotation: the normalised quaternion (w, x, y, z) of rot_0..3
    rot = [_named(b, f"rot_{i}", -1400, -400 - 90 * i) for i in range(4)]
    sq = [b.math("MULTIPLY", -1250, -400 - 90 * i, r, r) for i, r in enumerate(rot)]
    norm = b.math("SQRT", -950, -500,
                  b.math("ADD", -1050, -500, b.math("ADD", -1120, -450, sq[0], sq[1]),
                         b.math("ADD", -1120, -550, sq[2], sq[3])))  # fmt: skip
    quat = b.node("FunctionNodeQuaternionToRotation", -800, -450)
    for i, axis in enumerate("WXYZ"):
        b.link(b.math("DIVIDE", -950, -620 - 60 * i, rot[i], norm), quat.inputs[axis])
    rotation = _sample(b, mesh, quat.outputs[0], src, "QUATERNION", -200, -350)

    # scale: Sigma * exp(scale_i), each clamped to Max Size
    exps = [b.math("EXPONENT", -1250, -900 - 90 * i, _named(b, f"scale_{i}", -1400, -900 - 90 * i))
            for i in range(3)]  # fmt: skip
    xyz = b.node("ShaderNodeCombineXYZ", -1100, -950)
    for i, axis in enumerate("XYZ"):
        b.link(exps[i], xyz.inputs[axis])
    scaled = b.node("ShaderNodeVectorMath", -950, -950, operation="SCALE")
    b.link(xyz.outputs[0], scaled.inputs[0])
    b.link(gin.outputs[SIGMA_SOCKET], scaled.inputs["Scale"])
    limit = b.node("ShaderNodeCombineXYZ", -950, -1150)
    for axis in "XYZ":
        b.link(gin.outputs[MAX_SIZE_SOCKET], limit.inputs[axis])
    clamped = b.node("ShaderNodeVectorMath", -800, -1000, operation="MINIMUM")
    b.link(scaled.outputs[0], clamped.inputs[0])
    b.link(limit.outputs[0], clamped.inputs[1])
    scale = _sample(b, mesh, clamped.outputs[0], src, "FLOAT_VECTOR", -200, -550)

    # the instanced sphere, with the material and the Sigma the falloff needs
    sphere = b.node("GeometryNodeMeshIcoSphere", -350, 300)
    sphere.inputs["Radius"].default_value = 1.0
    sphere.inputs["Subdivisions"].default_value = _SPHERE_SUBDIVISIONS
    smooth = b.node("GeometryNodeSetShadeSmooth", -200, 300)
    b.link(sphere.outputs["Mesh"], smooth.inputs[0])
    store_sigma = b.node("GeometryNodeStoreNamedAttribute", -50, 300,
                         data_type="FLOAT", domain="POINT")  # fmt: skip
    store_sigma.inputs["Name"].default_value = SIGMA_ATTR
    b.link(smooth.outputs[0], store_sigma.inputs["Geometry"])
    b.link(gin.outputs[SIGMA_SOCKET], store_sigma.inputs["Value"])
    set_mat = b.node("GeometryNodeSetMaterial", 100, 300)
    set_mat.inputs["Material"].default_value = material()
    b.link(store_sigma.outputs[0], set_mat.inputs["Geometry"])

    inst = b.node("GeometryNodeInstanceOnPoints", 250, 0)
    b.link(subset.outputs[0], inst.inputs["Points"])
    b.link(set_mat.outputs[0], inst.inputs["Instance"])
    b.link(rotation, inst.inputs["Rotation"])
    b.link(scale, inst.inputs["Scale"])
    colour = _sample(b, mesh, _named(b, COLOR_ATTR, -400, -800, "FLOAT_COLOR"), src,
                     "FLOAT_COLOR", -200, -750)  # fmt: skip
    store_col = b.node("GeometryNodeStoreNamedAttribute", 450, 0,
                       data_type="FLOAT_COLOR", domain="INSTANCE")  # fmt: skip
    store_col.inputs["Name"].default_value = COLOR_ATTR
    b.link(inst.outputs[0], store_col.inputs["Geometry"])
    b.link(colour, store_col.inputs["Value"])
    b.link(store_col.outputs[0], gout.inputs["Geometry"])
    return tree


def node_group():
    """The shared node group, rebuilt if missing, broken by a user or from an older add-on."""
    tree = bpy.data.node_groups.get(NODE_GROUP)
    if (
        tree is None
        or tree.bl_idname != "GeometryNodeTree"
        or tree.get(_VERSION_PROP) != VERSION
        or "Instance on Points" not in tree.nodes
    ):
        if tree is not None:
            tree.name = f"{NODE_GROUP} (old)"  # keep it for objects that use it
        tree = build_node_group()
    return tree


# ---- the material --------------------------------------------------------------------------------
def material():
    """Emission x Gaussian falloff over transparency (see the module docstring)."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None and mat.get(_VERSION_PROP) == VERSION:
        return mat
    if mat is not None:
        mat.name = f"{MATERIAL} (old)"
    mat = bpy.data.materials.new(MATERIAL)
    mat[_VERSION_PROP] = VERSION
    if bpy.app.version < (5, 0, 0):  # always node-based from 5.0 (the flag is deprecated)
        mat.use_nodes = True
    _build_material_nodes(mat.node_tree)
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    mat.use_backface_culling = True  # EEVEE: each splat drawn once (Cycles: Backfacing below)
    if hasattr(mat, "surface_render_method"):  # EEVEE Next (4.2+): order-independent
        mat.surface_render_method = "DITHERED"
    else:  # pragma: no cover - EEVEE Legacy
        mat.blend_method = "HASHED"
    if hasattr(mat, "cycles"):
        mat.cycles.emission_sampling = "NONE"
    return mat


def _build_material_nodes(tree) -> None:
    """alpha = opacity * exp(-1/2 (sigma r)^2) * (not backfacing); r^2 = |p|^2 - (p.d)^2 with
    p the shading point and d the unit view direction, both in the instance's unit-sphere
    space (an affine map keeps lines lines, so this is the ray's closest approach there)."""
    b = _Builder(tree)
    tree.nodes.clear()
    attr = b.node("ShaderNodeAttribute", -900, 300, attribute_type="INSTANCER",
                  attribute_name=COLOR_ATTR)  # fmt: skip
    sigma = b.node("ShaderNodeAttribute", -900, 0, attribute_type="GEOMETRY",
                   attribute_name=SIGMA_ATTR)  # fmt: skip
    coords = b.node("ShaderNodeTexCoord", -1100, -200)
    geom = b.node("ShaderNodeNewGeometry", -1100, -450)
    to_local = b.node("ShaderNodeVectorTransform", -900, -400, vector_type="VECTOR",
                      convert_from="WORLD", convert_to="OBJECT")  # fmt: skip
    b.link(geom.outputs["Incoming"], to_local.inputs[0])
    d = b.node("ShaderNodeVectorMath", -750, -400, operation="NORMALIZE")
    b.link(to_local.outputs[0], d.inputs[0])
    pd = b.node("ShaderNodeVectorMath", -600, -300, operation="DOT_PRODUCT")
    b.link(coords.outputs["Object"], pd.inputs[0])
    b.link(d.outputs[0], pd.inputs[1])
    pp = b.node("ShaderNodeVectorMath", -600, -150, operation="DOT_PRODUCT")
    b.link(coords.outputs["Object"], pp.inputs[0])
    b.link(coords.outputs["Object"], pp.inputs[1])
    r2 = b.math("MAXIMUM", -300, -200,
                b.math("SUBTRACT", -450, -200, pp.outputs["Value"],
                       b.math("POWER", -450, -350, pd.outputs["Value"], 2.0)), 0.0)  # fmt: skip
    s2 = b.math("MULTIPLY", -450, 0, sigma.outputs["Fac"], sigma.outputs["Fac"])
    falloff = b.math("EXPONENT", -150, -100, b.math("MULTIPLY", -300, -50,
                     b.math("MULTIPLY", -300, 50, s2, r2), -0.5))  # fmt: skip
    front = b.math("SUBTRACT", -150, -300, 1.0, geom.outputs["Backfacing"])
    alpha = b.math("MULTIPLY", 50, 0, b.math("MULTIPLY", 0, 100, attr.outputs["Alpha"], falloff),
                   front)  # fmt: skip
    emit = b.node("ShaderNodeEmission", 50, 300)
    b.link(attr.outputs["Color"], emit.inputs["Color"])
    clear = b.node("ShaderNodeBsdfTransparent", 50, 150)
    mix = b.node("ShaderNodeMixShader", 250, 200)
    b.link(alpha, mix.inputs["Fac"])
    b.link(clear.outputs[0], mix.inputs[1])
    b.link(emit.outputs[0], mix.inputs[2])
    out = b.node("ShaderNodeOutputMaterial", 450, 200)
    b.link(mix.outputs[0], out.inputs["Surface"])


# ---- the modifier --------------------------------------------------------------------------------
def socket_identifier(group, name: str) -> str:
    """The modifier key of the node group input ``name``."""
    return next(
        s.identifier for s in group.interface.items_tree
        if getattr(s, "in_out", "") == "INPUT" and s.name == name
    )  # fmt: skip


def _input_values(mod):
    """Where this Blender keeps a Geometry Nodes modifier's input values: from 5.2 on, the
    ``mod.properties.inputs`` struct (``mod["Socket_1"]`` raises there); before, ID properties
    on the modifier. A feature check, not a version number."""
    return getattr(getattr(mod, "properties", None), "inputs", None)


def get_input(mod, name: str):
    """The value of a display input (``SOCKETS``) on the modifier."""
    key = socket_identifier(mod.node_group, name)
    values = _input_values(mod)
    return getattr(values, key).value if values is not None else mod[key]


def set_input(mod, name: str, value) -> None:
    """Set a display input (``SOCKETS``) on the modifier and re-evaluate."""
    key = socket_identifier(mod.node_group, name)
    values = _input_values(mod)
    if values is not None:
        getattr(values, key).value = value
    else:
        mod[key] = value
    mod.id_data.update_tag()


def add_modifier(obj, arrays: Mapping[str, np.ndarray] | None = None):
    """Add the display modifier; ``Max Size`` from ``arrays`` (position, scale_*) if given."""
    mod = obj.modifiers.new(MODIFIER, "NODES")
    mod.node_group = node_group()
    if arrays is not None and "scale_0" in arrays:
        logs = np.stack([np.asarray(arrays[f"scale_{i}"]) for i in range(3)], axis=1)
        size = default_max_size(arrays["position"], logs, DEFAULT_SIGMA)
        set_input(mod, MAX_SIZE_SOCKET, float(size))
    return mod


# ---- the panel ------------------------------------------------------------------------------------
def draw_settings(layout, obj) -> None:
    """The Gaussians panel's display rows: the modifier inputs (mesh display only; Blender
    draws its own splats without settings), the render toggle, the count."""
    mod = obj.modifiers.get(MODIFIER)
    if mod is not None and mod.node_group is not None:
        values = _input_values(mod)
        for item in mod.node_group.interface.items_tree:
            if getattr(item, "in_out", "") == "INPUT" and item.name in SOCKETS:
                if values is not None:
                    layout.prop(getattr(values, item.identifier), "value", text=item.name)
                else:
                    layout.prop(mod, f'["{item.identifier}"]', text=item.name)
    layout.prop(obj, "hide_render", text="Show in Renders", invert_checkbox=True)
    count = len(obj.data.vertices) if obj.type == "MESH" else len(obj.data.points)
    layout.label(text=f"{count:,} Gaussians", icon="INFO")
    if getattr(obj.data, "type", "") == "GAUSSIAN_SPLAT":
        layout.label(text="Drawn as Blender's own Gaussian splats")
