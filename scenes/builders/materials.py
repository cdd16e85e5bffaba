"""Seeded materials: procedural node textures, drawn images, glossy, metal and emissive.

Textures use *Object* coordinates (metres, since sizes are baked into meshes), so nothing
needs UV unwrapping and texture scale is comparable across objects. Socket lookups use the
names that both Blender 4.2 and 5.0 accept (5.0 renamed the displayed "Fac" to "Factor"
but still resolves the identifier "Fac"); the Mix node is avoided for the same reason.
"""

from __future__ import annotations

import colorsys
import random

import bpy
import numpy as np

from . import images

PROCEDURAL: tuple[str, ...] = ("noise", "voronoi", "brick", "checker", "wave", "magic", "gradient")


def srgb_to_linear(c: tuple[float, float, float]) -> tuple[float, float, float, float]:
    """Shader colours are scene-linear; pick colours perceptually, then linearise."""
    return (*(float(x) ** 2.2 for x in c), 1.0)


def color(
    rng: random.Random, hue: float | None = None, sat=(0.25, 0.8), val=(0.3, 0.9)
) -> tuple[float, float, float, float]:
    """A random linear RGBA colour; ``hue`` pins the hue for coordinated palettes."""
    h = rng.random() if hue is None else (hue + rng.gauss(0, 0.04)) % 1.0
    return srgb_to_linear(colorsys.hsv_to_rgb(h, rng.uniform(*sat), rng.uniform(*val)))


def new_material(name: str) -> tuple[bpy.types.Material, bpy.types.NodeTree, bpy.types.Node]:
    """Empty node material with one Principled BSDF wired to the output."""
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True  # always on (and deprecated) from 5.0
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat, nt, bsdf


def plain(
    name: str,
    base: tuple[float, ...],
    roughness: float = 0.6,
    metallic: float = 0.0,
    coat: float = 0.0,
) -> bpy.types.Material:
    """Uniform colour: the textureless case, glossy plastics and metals."""
    mat, _, bsdf = new_material(name)
    bsdf.inputs["Base Color"].default_value = base
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Coat Weight"].default_value = coat
    mat.diffuse_color = base  # viewport colour
    return mat


def metal(name: str, rng: random.Random, roughness: tuple[float, float] = (0.1, 0.4)):
    """Steel, gold, copper or tinted metal."""
    tint = rng.choice([(0.9, 0.9, 0.92), (1.0, 0.78, 0.34), (0.95, 0.64, 0.54), (0.7, 0.75, 0.8)])
    return plain(name, (*tint, 1.0), rng.uniform(*roughness), metallic=1.0)


def emissive(
    name: str, base: tuple[float, ...], strength: float, gradient: bool = False
) -> bpy.types.Material:
    """Light-emitting surface (lamp shades, screens, the sky behind a window)."""
    mat, nt, bsdf = new_material(name)
    bsdf.inputs["Base Color"].default_value = (0.05, 0.05, 0.05, 1.0)
    bsdf.inputs["Emission Color"].default_value = base
    bsdf.inputs["Emission Strength"].default_value = strength
    if gradient:  # brighter towards the top, like sky seen through a window
        tc = nt.nodes.new("ShaderNodeTexCoord")
        sep = nt.nodes.new("ShaderNodeSeparateXYZ")
        ramp = nt.nodes.new("ShaderNodeValToRGB")
        nt.links.new(tc.outputs["Generated"], sep.inputs["Vector"])
        nt.links.new(sep.outputs["Z"], ramp.inputs["Fac"])
        ramp.color_ramp.elements[0].color = tuple(0.6 * c for c in base[:3]) + (1.0,)
        ramp.color_ramp.elements[1].color = base
        nt.links.new(ramp.outputs["Color"], bsdf.inputs["Emission Color"])
    return mat


def _mapping(
    nt: bpy.types.NodeTree, rng: random.Random, scale: float, rotate: bool = True
) -> bpy.types.Node:
    tc = nt.nodes.new("ShaderNodeTexCoord")
    mp = nt.nodes.new("ShaderNodeMapping")
    nt.links.new(tc.outputs["Object"], mp.inputs["Vector"])
    mp.inputs["Scale"].default_value = (scale, scale, scale)
    mp.inputs["Rotation"].default_value = (0.0, 0.0, rng.uniform(0, 3.1416) if rotate else 0.0)
    mp.inputs["Location"].default_value = (rng.uniform(0, 10), rng.uniform(0, 10), 0.0)
    return mp


def _math(nt: bpy.types.NodeTree, op: str, *inputs) -> bpy.types.NodeSocket:
    """A Math node; each input is a socket (linked) or a number (set)."""
    node = nt.nodes.new("ShaderNodeMath")
    node.operation = op
    for sock, value in zip(node.inputs, inputs):
        if isinstance(value, (int, float)):
            sock.default_value = value
        else:
            nt.links.new(value, sock)
    return node.outputs["Value"]


def _planar(nt: bpy.types.NodeTree, vector: bpy.types.NodeSocket) -> bpy.types.NodeSocket:
    """Coordinates in the plane of each face for 2D textures (Brick ignores z).

    Horizontal faces get (x, y); vertical faces (x, z) or (y, z) depending on which way
    they face (object-space normal), so bricks lie the right way on every wall.
    """
    tc = nt.nodes.new("ShaderNodeTexCoord")
    pos, nrm = nt.nodes.new("ShaderNodeSeparateXYZ"), nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(vector, pos.inputs["Vector"])
    nt.links.new(tc.outputs["Normal"], nrm.inputs["Vector"])
    x, y, z = pos.outputs["X"], pos.outputs["Y"], pos.outputs["Z"]
    ax, ay, az = (_math(nt, "ABSOLUTE", nrm.outputs[c]) for c in "XYZ")
    faces_x = _math(nt, "GREATER_THAN", ax, ay)  # wall facing +-x: use y along it
    flat = _math(nt, "GREATER_THAN", az, 0.5)  # floor / ceiling / top
    u_wall = _math(nt, "MULTIPLY_ADD", faces_x, _math(nt, "SUBTRACT", y, x), x)
    u = _math(nt, "MULTIPLY_ADD", flat, _math(nt, "SUBTRACT", x, u_wall), u_wall)
    v = _math(nt, "MULTIPLY_ADD", flat, _math(nt, "SUBTRACT", y, z), z)
    out = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(u, out.inputs["X"])
    nt.links.new(v, out.inputs["Y"])
    return out.outputs["Vector"]


def _ramp(nt, rng: random.Random, cols: list[tuple[float, ...]]) -> bpy.types.Node:
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    els = ramp.color_ramp.elements
    while len(els) < len(cols):
        els.new(0.5)
    stops = sorted(rng.uniform(0.05, 0.95) for _ in cols)
    for el, pos, c in zip(els, stops, cols):
        el.position, el.color = pos, c
    return ramp


def procedural(
    name: str,
    rng: random.Random,
    kind: str | None = None,
    cols: list[tuple[float, ...]] | None = None,
    scale: float | None = None,
    roughness: float | None = None,
    metallic: float = 0.0,
    bump: bool = True,
) -> bpy.types.Material:
    """A Blender procedural texture (``PROCEDURAL``) driving base colour (and bump).

    ``scale`` is the feature frequency in 1/metre; colours default to a random
    harmonious set. Fac-style outputs go through a Color Ramp.
    """
    kind = kind or rng.choice(PROCEDURAL)
    hue = rng.random()
    cols = cols or [color(rng, hue) for _ in range(3)]
    scale = scale or rng.uniform(1.5, 8.0)
    mat, nt, bsdf = new_material(name)
    mp = _mapping(nt, rng, 1.0, rotate=kind != "brick")
    vector = mp.outputs["Vector"]
    fac = None
    if kind == "brick":
        vector = _planar(nt, vector)
        tex = nt.nodes.new("ShaderNodeTexBrick")
        tex.inputs["Color1"].default_value, tex.inputs["Color2"].default_value = cols[0], cols[1]
        tex.inputs["Mortar"].default_value = cols[2]
        tex.inputs["Scale"].default_value = scale * 0.6
        tex.inputs["Mortar Size"].default_value = rng.uniform(0.01, 0.04)
        tex.offset = rng.choice([0.5, 0.25, 0.0])
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        fac = tex.outputs["Fac"]
    elif kind == "checker":
        tex = nt.nodes.new("ShaderNodeTexChecker")
        tex.inputs["Color1"].default_value, tex.inputs["Color2"].default_value = cols[0], cols[1]
        tex.inputs["Scale"].default_value = scale
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        if kind == "noise":
            tex = nt.nodes.new("ShaderNodeTexNoise")
            tex.inputs["Detail"].default_value = rng.uniform(2.0, 6.0)
            tex.inputs["Roughness"].default_value = rng.uniform(0.4, 0.7)
            fac = tex.outputs["Fac"]
        elif kind == "voronoi":
            tex = nt.nodes.new("ShaderNodeTexVoronoi")
            tex.feature = rng.choice(["F1", "F2", "DISTANCE_TO_EDGE"])
            fac = tex.outputs["Distance"]
        elif kind == "wave":
            tex = nt.nodes.new("ShaderNodeTexWave")
            tex.wave_type = rng.choice(["BANDS", "RINGS"])
            tex.inputs["Distortion"].default_value = rng.uniform(0.0, 8.0)
            fac = tex.outputs["Fac"]
        elif kind == "magic":
            tex = nt.nodes.new("ShaderNodeTexMagic")
            tex.turbulence_depth = rng.randint(1, 4)
            fac = tex.outputs["Fac"]
        elif kind == "gradient":
            # Gradient clamps outside [0, 1]: repeat it with a fract so it tiles
            tex = nt.nodes.new("ShaderNodeTexGradient")
            tex.gradient_type = rng.choice(["LINEAR", "QUADRATIC", "DIAGONAL", "SPHERICAL"])
            mul = nt.nodes.new("ShaderNodeVectorMath")
            mul.operation = "SCALE"
            mul.inputs["Scale"].default_value = scale / 2
            fr = nt.nodes.new("ShaderNodeVectorMath")
            fr.operation = "FRACTION"
            nt.links.new(vector, mul.inputs[0])
            nt.links.new(mul.outputs["Vector"], fr.inputs[0])
            vector = fr.outputs["Vector"]
            fac = tex.outputs["Fac"]
        else:
            raise ValueError(f"unknown procedural texture {kind!r}; use one of {PROCEDURAL}")
        if "Scale" in tex.inputs and kind != "gradient":
            tex.inputs["Scale"].default_value = scale
        ramp = _ramp(nt, rng, cols)
        nt.links.new(fac, ramp.inputs["Fac"])
        nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    nt.links.new(vector, tex.inputs["Vector"])
    if bump and fac is not None:
        bp = nt.nodes.new("ShaderNodeBump")
        bp.inputs["Strength"].default_value = rng.uniform(0.05, 0.3)
        bp.inputs["Distance"].default_value = 0.02
        nt.links.new(fac, bp.inputs["Height"])
        nt.links.new(bp.outputs["Normal"], bsdf.inputs["Normal"])
    rough = rng.uniform(0.3, 0.9) if roughness is None else roughness
    bsdf.inputs["Roughness"].default_value = rough
    bsdf.inputs["Metallic"].default_value = metallic
    mat.diffuse_color = cols[0]
    return mat


def image_textured(
    name: str,
    rng: random.Random,
    nrng: np.random.Generator,
    pattern: str | None = None,
    tile: float | None = None,
    roughness: float | None = None,
) -> bpy.types.Material:
    """A drawn, packed image (``images.PATTERNS``) box-projected on Object coordinates,
    repeating every ``tile`` metres."""
    pattern = pattern or rng.choice(images.PATTERNS)
    img = images.packed_image(f"{name}_img", images.draw(pattern, nrng, rng.choice([64, 128])))
    mat, nt, bsdf = new_material(name)
    mp = _mapping(nt, rng, 1.0 / (tile or rng.uniform(0.3, 1.5)))
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.projection = "BOX"
    tex.projection_blend = 0.2
    tex.interpolation = "Linear"
    nt.links.new(mp.outputs["Vector"], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = (
        rng.uniform(0.3, 0.9) if roughness is None else roughness
    )
    return mat


def random_surface(name: str, rng: random.Random, nrng: np.random.Generator):
    """Any of the material kinds, weighted towards textured ones (what the model needs)."""
    r = rng.random()
    if r < 0.5:
        return procedural(name, rng)
    if r < 0.7:
        return image_textured(name, rng, nrng)
    if r < 0.82:
        return plain(name, color(rng), rng.uniform(0.05, 0.35), coat=rng.choice([0.0, 1.0]))
    if r < 0.95:
        return metal(name, rng)
    return emissive(name, color(rng, sat=(0.3, 0.7), val=(0.7, 1.0)), rng.uniform(2.0, 6.0))
