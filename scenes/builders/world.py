"""World (background) shaders: a gradient sky for outdoor scenes, a dim fill indoors.

The sky is a vertical colour gradient rather than the Sky Texture node because the latter's
models differ between Blender versions (5.0 replaced "Nishita" with single/multiple
scattering) and its physical intensities need exposure tuning; a gradient renders the same
everywhere and is cheap. Below the horizon it turns to a ground colour, so the rare ray that
misses the finite ground plane still sees something plausible.
"""

from __future__ import annotations

import bpy


def _world(name: str) -> tuple[bpy.types.World, bpy.types.NodeTree, bpy.types.Node]:
    world = bpy.data.worlds.new(name)
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True  # always on (and deprecated) from 5.0
    nt = world.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    bg = nt.nodes.new("ShaderNodeBackground")
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    bpy.context.scene.world = world
    return world, nt, bg


def uniform_world(rgb: tuple[float, float, float], strength: float) -> bpy.types.World:
    """Constant dim environment light (indoor fill so shadows are not pitch black)."""
    _, _, bg = _world("fill")
    bg.inputs["Color"].default_value = (*rgb, 1.0)
    bg.inputs["Strength"].default_value = strength
    return bpy.context.scene.world


def gradient_sky(
    zenith: tuple[float, float, float],
    horizon: tuple[float, float, float],
    ground: tuple[float, float, float],
    strength: float = 1.0,
) -> bpy.types.World:
    """Sky whose colour depends on the elevation of the view ray (linear RGB colours)."""
    _, nt, bg = _world("sky")
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    remap = nt.nodes.new("ShaderNodeMath")  # z in [-1, 1] -> [0, 1]
    remap.operation = "MULTIPLY_ADD"
    remap.inputs[1].default_value = 0.5
    remap.inputs[2].default_value = 0.5
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    els = ramp.color_ramp.elements
    els.new(0.5)
    for el, pos, col in zip(els, (0.46, 0.5, 0.8), (ground, horizon, zenith)):
        el.position, el.color = pos, (*col, 1.0)
    nt.links.new(tc.outputs["Generated"], sep.inputs["Vector"])
    nt.links.new(sep.outputs["Z"], remap.inputs[0])
    nt.links.new(remap.outputs["Value"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = strength
    return bpy.context.scene.world
