"""Mesh primitives built straight into ``bpy.data`` (curves: ``shapes``, lights: ``lights``).

Everything goes through ``bmesh`` / ``bpy.data`` instead of ``bpy.ops``: no context or
selection state is involved, so building is fast, works the same headless and in the UI,
and the result depends only on the arguments (the determinism the builders promise).
Sizes are baked into the mesh (object scale stays 1) so that *Object* texture
coordinates are in metres on every object and textures have the same scale everywhere.

Every object gets a role in ``obj["prosplat_role"]``:

* ``"structure"``: walls, floors, ground; never removed to clear the camera path.
* ``"prop"``: furniture and objects; may be removed if the camera path passes too close.
* ``"shell"``: geometry meant to enclose the cameras (its bounding box contains them).
* ``"sky"``: a backdrop dome, left out of the scene bounds (no builder makes one yet).
* ``"light"``: light objects.
"""

from __future__ import annotations

import random
from collections.abc import Sequence

import bmesh
import bpy
import numpy as np
from mathutils import Matrix, Vector

ROLE_KEY = "prosplat_role"
Vec3 = Sequence[float]


def link(obj: bpy.types.Object, role: str = "prop") -> bpy.types.Object:
    """Link ``obj`` into the current scene and tag its role."""
    bpy.context.scene.collection.objects.link(obj)
    obj[ROLE_KEY] = role
    return obj


def _finish(
    name: str,
    bm: bmesh.types.BMesh,
    material: bpy.types.Material | None,
    location: Vec3,
    rotation: Vec3,
    smooth: bool,
    role: str,
) -> bpy.types.Object:
    me = bpy.data.meshes.new(name)
    bm.to_mesh(me)
    bm.free()
    return mesh_object(name, me, material, location, rotation, smooth, role)


def mesh_object(
    name: str,
    me: bpy.types.Mesh,
    material: bpy.types.Material | None,
    location: Vec3,
    rotation: Vec3,
    smooth: bool,
    role: str,
) -> bpy.types.Object:
    """An object for mesh ``me``: shading, material, placement and role tag, linked."""
    if smooth:
        me.shade_smooth()
    if material is not None:
        me.materials.append(material)
    obj = bpy.data.objects.new(name, me)
    obj.location = tuple(location)
    obj.rotation_euler = tuple(rotation)
    return link(obj, role)


def modifier(obj: bpy.types.Object, kind: str, **props: object) -> bpy.types.Modifier:
    """Add a modifier of type ``kind`` (e.g. ``"BEVEL"``) and set its properties."""
    mod = obj.modifiers.new(kind.lower(), kind)
    for key, value in props.items():
        setattr(mod, key, value)
    return mod


def bevel(obj: bpy.types.Object, width: float, segments: int = 2) -> bpy.types.Modifier:
    """Rounded edges: cheap realism that breaks up the flat box silhouettes."""
    return modifier(obj, "BEVEL", width=width, segments=segments, limit_method="ANGLE")


def box(
    name: str,
    size: Vec3,
    location: Vec3,
    material: bpy.types.Material | None,
    rotation: Vec3 = (0.0, 0.0, 0.0),
    role: str = "prop",
) -> bpy.types.Object:
    """Axis-aligned (in its own frame) box of full ``size``, centred at ``location``."""
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0, matrix=Matrix.Diagonal((*size, 1.0)))
    return _finish(name, bm, material, location, rotation, False, role)


def box_between(
    name: str, lo: Vec3, hi: Vec3, material: bpy.types.Material | None, role: str = "prop"
) -> bpy.types.Object:
    """Box spanning the world-space corners ``lo`` .. ``hi`` (walls, slabs)."""
    size = [h - l for l, h in zip(lo, hi)]
    centre = [(h + l) / 2 for l, h in zip(lo, hi)]
    return box(name, size, centre, material, role=role)


def cylinder(
    name: str,
    radius: float,
    depth: float,
    location: Vec3,
    material: bpy.types.Material | None,
    rotation: Vec3 = (0.0, 0.0, 0.0),
    segments: int = 24,
    radius_top: float | None = None,
    smooth: bool = True,
    role: str = "prop",
) -> bpy.types.Object:
    """Capped cylinder (or frustum / cone with ``radius_top``) along local Z, centred."""
    bm = bmesh.new()
    top = radius if radius_top is None else radius_top
    bmesh.ops.create_cone(
        bm, cap_ends=True, segments=segments, radius1=radius, radius2=top, depth=depth
    )
    return _finish(name, bm, material, location, rotation, smooth, role)


def rod(
    name: str,
    p0: Vec3,
    p1: Vec3,
    radius: float,
    material: bpy.types.Material | None,
    segments: int = 8,
    role: str = "prop",
) -> bpy.types.Object:
    """Thin cylinder from ``p0`` to ``p1`` (posts, rails, legs, spokes)."""
    a, b = Vector(p0), Vector(p1)
    axis = b - a
    rot = axis.to_track_quat("Z", "Y").to_euler()
    return cylinder(
        name, radius, axis.length, (a + b) / 2, material, rot, segments, smooth=True, role=role
    )


def uv_sphere(
    name: str,
    radius: float,
    location: Vec3,
    material: bpy.types.Material | None,
    segments: int = 24,
    rings: int = 12,
    scale: Vec3 = (1.0, 1.0, 1.0),
    role: str = "prop",
    cut_below: float | None = None,
) -> bpy.types.Object:
    """Smooth UV sphere; ``scale`` (baked into the mesh) makes ellipsoids such as hills,
    ``cut_below`` removes the part below that local height."""
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(
        bm,
        u_segments=segments,
        v_segments=rings,
        radius=radius,
        matrix=Matrix.Diagonal((*scale, 1)),
    )
    if cut_below is not None:  # drop what would be buried (keeps scene bounds tight)
        geom = bm.verts[:] + bm.edges[:] + bm.faces[:]
        bmesh.ops.bisect_plane(
            bm, geom=geom, plane_co=(0, 0, cut_below), plane_no=(0, 0, 1), clear_inner=True
        )
    return _finish(name, bm, material, location, (0, 0, 0), True, role)


def ico_sphere(
    name: str,
    radius: float,
    location: Vec3,
    material: bpy.types.Material | None,
    subdivisions: int = 2,
    jitter: float = 0.0,
    rng: np.random.Generator | None = None,
    scale: Vec3 = (1.0, 1.0, 1.0),
    smooth: bool = False,
    role: str = "prop",
) -> bpy.types.Object:
    """Icosphere, optionally with seeded radial vertex jitter (rocks, bushes, crowns)."""
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=subdivisions, radius=radius)
    if jitter > 0.0 and rng is not None:
        noise = rng.uniform(1.0 - jitter, 1.0 + jitter, len(bm.verts))
        for v, f in zip(bm.verts, noise):
            v.co *= float(f)
    for v in bm.verts:
        v.co = Vector((v.co.x * scale[0], v.co.y * scale[1], v.co.z * scale[2]))
    return _finish(name, bm, material, location, (0, 0, 0), smooth, role)


def monkey(
    name: str,
    size: float,
    location: Vec3,
    material: bpy.types.Material | None,
    rotation: Vec3 = (0.0, 0.0, 0.0),
    role: str = "prop",
) -> bpy.types.Object:
    """Suzanne, ``size`` metres wide, with one level of subdivision."""
    bm = bmesh.new()
    bmesh.ops.create_monkey(bm, matrix=Matrix.Scale(size / 2.7, 4))
    obj = _finish(name, bm, material, location, rotation, True, role)
    modifier(obj, "SUBSURF", levels=1, render_levels=1)
    return obj


def np_rng(rng: random.Random) -> np.random.Generator:
    """A numpy generator drawn from the layout stream (for per-vertex jitter)."""
    return np.random.default_rng(rng.getrandbits(32))
