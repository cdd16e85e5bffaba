"""Seeded procedural Blender scenes for training and testing sparse-view reconstruction.

``build_scene(name_or_family, seed)`` clears the current bpy scene, builds a scene of one
family ("room", "tabletop", "open"), a hard variant (``HARD_SCENES``) or a capture-like scene
(``CAPTURE_SCENES``: object-centric photo sets' set-ups) into it (geometry, materials, lights,
world; no camera, no render settings) and returns a ``SceneInfo`` with a smooth camera
trajectory, a suggested lens and the scene bounds.

Determinism: all randomness comes from ``random.Random`` / ``numpy.random.default_rng``
seeded from ``seed``; layout and materials use separate streams, so a hard variant that
only swaps the palette (``textureless``) keeps the layout of the plain family scene with
the same seed.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

import bpy
import numpy as np

from prosplat.data.splits import FAMILIES, family_for_seed

from . import hard, house, object_ring, open_scene, paths, room, tabletop
from .palette import Palette
from .query import clear_path, object_aabbs, scene_bounds, scene_fingerprint

__all__ = [
    "CAPTURE_SCENES",
    "CLEARANCE",
    "FAMILIES",
    "HARD_SCENES",
    "SceneInfo",
    "build_scene",
    "clear_path",
    "family_for_seed",
    "object_aabbs",
    "scene_bounds",
    "scene_fingerprint",
]

Vec3 = tuple[float, float, float]
CLEARANCE = 0.3  # metres between any camera eye and any object's bounding box


@dataclass(frozen=True)
class SceneInfo:
    """What the renderer needs to know about a built scene."""

    name: str  # "room", "tabletop", "open", a hard-scene or a capture-scene name
    family: str  # "room" | "tabletop" | "open"
    seed: int
    trajectory: list[tuple[Vec3, Vec3]]  # (eye, look_at), world coords (Z up), smooth, ordered
    lens_mm: float  # focal length for a 36 mm wide sensor
    bounds_min: Vec3  # axis-aligned bounds of all geometry (world)
    bounds_max: Vec3
    tags: tuple[str, ...]  # the hard or capture scene's name, e.g. ("textureless",)


HARD_SCENES: tuple[str, ...] = (
    "textureless",
    "thin_structures",
    "repeated_pattern",
    "specular",
    "near_far",
    "inside_outside",
)
#: Scenes set up like real object-centric photo sets (a ring of cameras round objects on a
#: plain background). Kept apart from ``HARD_SCENES``, which drives ``prosplat bench hard``.
CAPTURE_SCENES: tuple[str, ...] = ("object_ring",)

Builder = Callable[..., paths.Built]  # (layout rng, palette), and the seed for CAPTURE_SCENES
# name -> (family, palette style, builder)
_SCENES: dict[str, tuple[str, str, Builder]] = {
    "room": ("room", "varied", lambda r, p: room.build(r, p)[0]),
    "tabletop": ("tabletop", "varied", lambda r, p: tabletop.build(r, p)[0]),
    "open": ("open", "varied", open_scene.build),
    "textureless": ("room", "plain", hard.textureless),
    "thin_structures": ("tabletop", "varied", hard.thin_structures),
    "repeated_pattern": ("room", "repeated", hard.repeated_pattern),
    "specular": ("tabletop", "specular", hard.specular),
    "near_far": ("open", "varied", hard.near_far),
    "inside_outside": ("open", "varied", house.inside_outside),
    "object_ring": ("tabletop", "varied", object_ring.build),
}


def clear_scene() -> None:
    """Start from an empty scene with factory settings (no leftovers from earlier builds)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)


def build_scene(name_or_family: str, seed: int) -> SceneInfo:
    """Clear the current scene and build ``name_or_family`` with ``seed`` into it.

    Raises ``ValueError`` for an unknown name (the message lists the valid ones).
    """
    if name_or_family not in _SCENES:
        raise ValueError(
            f"unknown scene {name_or_family!r}; use a family {FAMILIES}, a hard scene "
            f"{HARD_SCENES} or a capture scene {CAPTURE_SCENES}"
        )
    family, style, builder = _SCENES[name_or_family]
    seed = int(seed)
    clear_scene()
    # textureless shares the room's layout stream: same room, only the palette differs
    layout_key = "room" if name_or_family == "textureless" else name_or_family
    layout_rng = random.Random(f"{layout_key}/layout/{seed}")
    palette = Palette(random.Random(f"materials/{seed}"), np.random.default_rng([seed, 1]), style)
    if name_or_family in CAPTURE_SCENES:  # their lens has a stream of its own, keyed by seed
        built = builder(layout_rng, palette, seed)
    else:
        built = builder(layout_rng, palette)
    clear_path(built.eyes, CLEARANCE)
    lo, hi = scene_bounds()
    tags = (name_or_family,) if name_or_family in HARD_SCENES + CAPTURE_SCENES else ()
    return SceneInfo(
        name=name_or_family,
        family=family,
        seed=seed,
        trajectory=built.trajectory(),
        lens_mm=float(built.lens_mm),
        bounds_min=lo,
        bounds_max=hi,
        tags=tags + tuple(t for t in built.tags if t not in tags),
    )
