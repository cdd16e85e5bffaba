"""Which material each kind of surface gets, per scene style.

Builders ask for a *role* ("wall", "floor", "object", ...) instead of a material, so a hard
scene can reuse a family's layout and only swap the style: ``plain`` makes everything
uniform (textureless), ``repeated`` shares one tiling material per role (repeated
pattern), ``specular`` turns objects and floor into mirrors and gloss.
"""

from __future__ import annotations

import random

import bpy
import numpy as np

from . import materials as M

STYLES: tuple[str, ...] = ("varied", "plain", "repeated", "specular")

# (hue, saturation range, value range) per role, in display space
_TONES: dict[str, tuple[float | None, tuple[float, float], tuple[float, float]]] = {
    "wall": (None, (0.03, 0.3), (0.6, 0.95)),
    "ceiling": (None, (0.0, 0.08), (0.8, 0.95)),
    "floor": (0.08, (0.3, 0.6), (0.3, 0.7)),
    "wood": (0.07, (0.4, 0.7), (0.25, 0.65)),
    "ground": (0.22, (0.35, 0.7), (0.25, 0.55)),
    "path": (0.09, (0.1, 0.3), (0.4, 0.65)),
    "stone": (0.1, (0.0, 0.12), (0.35, 0.7)),
    "foliage": (0.28, (0.45, 0.8), (0.2, 0.5)),
    "bark": (0.06, (0.35, 0.6), (0.15, 0.35)),
    "building": (None, (0.05, 0.35), (0.45, 0.85)),
    "roof": (0.02, (0.4, 0.7), (0.25, 0.5)),
}


class Palette:
    """Hands out materials by role, seeded, in the scene's style."""

    def __init__(self, rng: random.Random, nrng: np.random.Generator, style: str = "varied"):
        if style not in STYLES:
            raise ValueError(f"unknown style {style!r}; use one of {STYLES}")
        self.rng, self.nrng, self.style = rng, nrng, style
        self._cache: dict[str, bpy.types.Material] = {}
        self._count = 0

    def tone(self, role: str) -> tuple[float, float, float, float]:
        """A random colour typical for ``role`` (brown wood, green foliage, ...)."""
        hue, sat, val = _TONES.get(role, (None, (0.25, 0.8), (0.3, 0.9)))
        return M.color(self.rng, hue, sat, val)

    def shared(self, role: str) -> bpy.types.Material:
        """One material per role for the whole scene (all walls alike, ...)."""
        if role not in self._cache:
            self._cache[role] = self.get(role)
        return self._cache[role]

    def get(self, role: str) -> bpy.types.Material:
        """A new material for a surface of kind ``role``."""
        self._count += 1
        name = f"{role}_{self._count:03d}"
        if self.style == "plain":
            return self._plain(name, role)
        if self.style == "repeated" and role not in ("emissive", "sky_panel"):
            key = f"_rep_{role}_{self.rng.randrange(2)}"
            if key not in self._cache:
                self._cache[key] = self._repeated(name, role)
            return self._cache[key]
        if self.style == "specular" and role in ("object", "metal", "floor", "wood", "fabric"):
            return self._specular(name, role)
        return self._varied(name, role)

    def _plain(self, name: str, role: str) -> bpy.types.Material:
        if role == "emissive":
            return M.emissive(name, (1.0, 0.85, 0.65, 1.0), self.rng.uniform(3.0, 6.0))
        if role == "sky_panel":
            return M.emissive(name, (0.8, 0.9, 1.0, 1.0), self.rng.uniform(0.9, 1.3))
        if role == "metal":
            return M.plain(name, (0.8, 0.8, 0.82, 1.0), self.rng.uniform(0.3, 0.5), 1.0)
        return M.plain(name, self.tone(role), self.rng.uniform(0.5, 0.9))

    def _repeated(self, name: str, role: str) -> bpy.types.Material:
        rng = self.rng
        cols = [self.tone(role), self.tone(role), M.color(rng, None, (0, 0.1), (0.7, 0.9))]
        if role in ("wall", "building"):  # clay-coloured bricks, light mortar: high contrast
            bricks = [
                M.color(rng, 0.04, (0.4, 0.7), (0.35, 0.65)),
                M.color(rng, 0.07, (0.3, 0.6), (0.3, 0.55)),
            ]
            return M.procedural(
                name, rng, "brick", [*bricks, cols[2]], rng.uniform(3.0, 6.0), bump=True
            )
        if role in ("picture", "fabric"):
            return M.image_textured(name, rng, self.nrng, rng.choice(["tiles", "dots"]), 0.25)
        if role == "metal":
            return M.metal(name, rng)
        kind = "checker" if role in ("floor", "ceiling", "ground", "path") else None
        kind = kind or rng.choice(["checker", "brick"])
        return M.procedural(name, rng, kind, cols, rng.uniform(2.0, 6.0))

    def _specular(self, name: str, role: str) -> bpy.types.Material:
        rng = self.rng
        if role == "floor":
            cols = [
                self.tone("stone"),
                M.color(rng, None, (0, 0.2), (0.05, 0.2)),
                self.tone("wood"),
            ]
            return M.procedural(name, rng, "checker", cols, rng.uniform(1.0, 3.0), 0.04, bump=False)
        if role == "fabric" or (role == "object" and rng.random() < 0.35):
            return M.plain(name, M.color(rng), rng.uniform(0.02, 0.1), coat=1.0)
        return M.metal(name, rng, (0.0, 0.08))

    def _varied(self, name: str, role: str) -> bpy.types.Material:
        rng, nrng = self.rng, self.nrng
        cols = [self.tone(role) for _ in range(3)]
        r = rng.random()
        if role in ("emissive", "sky_panel"):
            warm = (1.0, 0.85, 0.65, 1.0) if role == "emissive" else (0.75, 0.87, 1.0, 1.0)
            strength = rng.uniform(3.0, 6.0) if role == "emissive" else rng.uniform(0.9, 1.3)
            return M.emissive(name, warm, strength, gradient=role == "sky_panel")
        if role == "object":
            return M.random_surface(name, rng, nrng)
        if role == "metal":
            return M.metal(name, rng)
        if role == "picture":
            pattern = rng.choice(["blocks", "dots", "stripes", "glyphs", "blobs"])
            return M.image_textured(name, rng, nrng, pattern, rng.uniform(0.5, 1.2), 0.5)
        if role == "wall":
            if r < 0.4:
                return M.procedural(name, rng, "noise", cols, rng.uniform(2, 8), 0.85)
            if r < 0.65:
                pattern = rng.choice(["stripes", "dots", "tiles", "blobs"])
                return M.image_textured(name, rng, nrng, pattern, rng.uniform(0.4, 1.0), 0.8)
            if r < 0.8:
                return M.procedural(name, rng, "brick", cols, rng.uniform(2.5, 5.0), 0.85)
            return M.procedural(name, rng, "wave", cols, rng.uniform(0.5, 2.0), 0.85)
        if role in ("floor", "wood"):
            if r < 0.45 or role == "wood":
                return M.procedural(name, rng, "wave", cols, rng.uniform(1.0, 4.0), None)
            if r < 0.65:
                return M.procedural(name, rng, "checker", cols, rng.uniform(1.5, 4.0), 0.3)
            if r < 0.8:
                return M.image_textured(name, rng, nrng, "tiles", rng.uniform(0.6, 1.5))
            return M.procedural(name, rng, "voronoi", cols, rng.uniform(2.0, 6.0))
        if role in ("ground", "foliage", "stone", "path", "bark"):
            kind = {"ground": "noise", "foliage": "noise", "stone": "voronoi", "path": "voronoi"}
            scale = {"ground": 0.8, "foliage": 3.0, "stone": 2.0, "path": 4.0, "bark": 6.0}[role]
            return M.procedural(
                name, rng, kind.get(role, "wave"), cols, scale * rng.uniform(0.6, 1.6)
            )
        if role == "building":
            if r < 0.5:
                return M.image_textured(name, rng, nrng, "tiles", rng.uniform(2.0, 5.0))
            return M.procedural(
                name, rng, rng.choice(["brick", "checker"]), cols, rng.uniform(0.3, 1.0)
            )
        if role == "roof":
            return M.procedural(
                name, rng, rng.choice(["brick", "wave"]), cols, rng.uniform(1.0, 3.0)
            )
        if role == "ceiling":
            return M.procedural(name, rng, "noise", cols, rng.uniform(1.0, 4.0), 0.9, bump=False)
        return M.random_surface(name, rng, nrng)  # fabric and anything else
