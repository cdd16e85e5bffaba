"""Lights and aiming helpers.

Lights are hidden from camera rays (``visible_camera = False``): the renderer's images
should contain surfaces only, and an area light seen edge-on would be a bright sliver.
"""

from __future__ import annotations

import math

import bpy
from mathutils import Euler, Vector

from .primitives import Vec3, link


def light(
    name: str,
    kind: str,
    location: Vec3,
    energy: float,
    color: Vec3 = (1.0, 1.0, 1.0),
    size: float = 0.1,
    target: Vec3 | None = None,
) -> bpy.types.Object:
    """A light; ``size`` is the area-light edge, point-light radius or sun angle (radians)."""
    data = bpy.data.lights.new(name, kind)
    data.energy = energy
    data.color = tuple(color)
    if kind == "AREA":
        data.size = size
    elif kind == "SUN":
        data.angle = size
    else:
        data.shadow_soft_size = size
    obj = bpy.data.objects.new(name, data)
    obj.location = tuple(location)
    if target is not None:
        obj.rotation_euler = look_rotation(location, target)
    obj.visible_camera = False  # lights light the scene; cameras should see only surfaces
    return link(obj, "light")


def look_rotation(src: Vec3, dst: Vec3) -> Euler:
    """Rotation that points an object's -Z (lights, cameras) from ``src`` at ``dst``."""
    return (Vector(dst) - Vector(src)).to_track_quat("-Z", "Y").to_euler()


def sun_direction(elevation: float, azimuth: float) -> Vector:
    """Unit vector pointing *towards* the sun (radians, azimuth from +X counter-clockwise)."""
    return Vector(
        (
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        )
    )
