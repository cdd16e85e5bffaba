"""Shapes with no bmesh operator: meshes from explicit vertices (tori, roofs) and
bevelled curves (cables, coils). Same conventions as ``primitives``: sizes baked in, a role
tag on every object."""

from __future__ import annotations

from collections.abc import Sequence

import bpy
import numpy as np

from .primitives import Vec3, link, mesh_object


def from_pydata(
    name: str,
    verts: np.ndarray | Sequence[Vec3],
    faces: Sequence[Sequence[int]],
    location: Vec3,
    material: bpy.types.Material | None,
    rotation: Vec3 = (0.0, 0.0, 0.0),
    smooth: bool = False,
    role: str = "prop",
) -> bpy.types.Object:
    """Mesh object from explicit vertices and faces (roofs, tori)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(f) for f in faces])
    me.validate()
    return mesh_object(name, me, material, location, rotation, smooth, role)


def torus(
    name: str,
    major: float,
    minor: float,
    location: Vec3,
    material: bpy.types.Material | None,
    rotation: Vec3 = (0.0, 0.0, 0.0),
    segments: int = 32,
    ring: int = 12,
    role: str = "prop",
) -> bpy.types.Object:
    """Torus in the local XY plane (bmesh has no torus operator, so built from numpy)."""
    u = np.linspace(0, 2 * np.pi, segments, endpoint=False)[:, None]
    v = np.linspace(0, 2 * np.pi, ring, endpoint=False)[None, :]
    rad = major + minor * np.cos(v)
    verts = np.stack(
        [
            rad * np.cos(u),
            rad * np.sin(u) + 0 * u,
            np.broadcast_to(minor * np.sin(v), (segments, ring)),
        ],
        -1,
    ).reshape(-1, 3)
    faces = [
        (
            i * ring + j,
            ((i + 1) % segments) * ring + j,
            ((i + 1) % segments) * ring + (j + 1) % ring,
            i * ring + (j + 1) % ring,
        )
        for i in range(segments)
        for j in range(ring)
    ]
    return from_pydata(name, verts, faces, location, material, rotation, True, role)


def prism_roof(
    name: str,
    width: float,
    depth: float,
    height: float,
    location: Vec3,
    material,
    rotation_z: float,
) -> bpy.types.Object:
    """Gable roof: a triangular prism, ridge along local X, base centred at ``location``."""
    w, d = width / 2, depth / 2
    verts = [(-w, -d, 0), (w, -d, 0), (w, d, 0), (-w, d, 0), (-w, 0, height), (w, 0, height)]
    faces = [(0, 1, 2, 3), (0, 4, 5, 1), (3, 2, 5, 4), (0, 3, 4), (1, 5, 2)]
    return from_pydata(name, verts, faces, location, material, (0, 0, rotation_z))


def cable(
    name: str,
    points: np.ndarray | Sequence[Vec3],
    radius: float,
    material: bpy.types.Material | None,
    role: str = "prop",
) -> bpy.types.Object:
    """Poly curve through ``points`` with a round bevel: cables, wires, coils."""
    cu = bpy.data.curves.new(name, "CURVE")
    cu.dimensions = "3D"
    cu.bevel_depth = radius
    cu.bevel_resolution = 1
    cu.use_fill_caps = True
    spline = cu.splines.new("POLY")
    pts = np.asarray(points, dtype=np.float64)
    spline.points.add(len(pts) - 1)
    co = np.concatenate([pts, np.ones((len(pts), 1))], axis=1).astype(np.float32)
    spline.points.foreach_set("co", co.ravel())
    if material is not None:
        cu.materials.append(material)
    return link(bpy.data.objects.new(name, cu), role)


def catenary(p0: Vec3, p1: Vec3, sag: float, n: int = 16) -> np.ndarray:
    """Points of a hanging cable from ``p0`` to ``p1`` sagging ``sag`` metres mid-span."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = (1 - t) * np.asarray(p0, float) + t * np.asarray(p1, float)
    pts[:, 2] -= sag * 4 * t[:, 0] * (1 - t[:, 0])
    return pts
