"""Furniture made of primitives and modifiers, placed against a wall.

Each piece is built in a wall *frame*: ``u`` along the wall, ``v`` out from the wall into the
room, ``z`` up. Depth (``v`` extent) never exceeds ``MAX_DEPTH`` so that room builders can
keep a free central zone for the camera path. Modifiers (bevel, array, solidify,
wireframe) add detail and repetition without many objects.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass

from . import lights as L
from . import primitives as P
from .palette import Palette

MAX_DEPTH = 0.9


@dataclass(frozen=True)
class Frame:
    """A wall-aligned frame: origin on the wall's inner face at floor level."""

    x: float
    y: float
    angle: float  # rotation about Z; local +u = (cos, sin), local +v = (-sin, cos)
    z: float = 0.0

    def at(self, u: float, v: float, z: float) -> tuple[float, float, float]:
        c, s = math.cos(self.angle), math.sin(self.angle)
        return (self.x + c * u - s * v, self.y + s * u + c * v, self.z + z)

    def box(self, name, size, u, v, z, mat, bevel: float = 0.0, role: str = "prop"):
        """Box of local ``size`` whose centre is at local ``(u, v, z)``."""
        obj = P.box(name, size, self.at(u, v, z), mat, (0.0, 0.0, self.angle), role)
        if bevel > 0:
            P.bevel(obj, bevel)
        return obj

    def cyl(self, name, radius, depth, u, v, z, mat, radius_top=None, segments=20):
        return P.cylinder(
            name, radius, depth, self.at(u, v, z), mat, (0, 0, self.angle), segments, radius_top
        )


@dataclass(frozen=True)
class Piece:
    """A placed piece: its footprint along the wall and height (for pictures above)."""

    u0: float
    u1: float
    depth: float
    height: float


def sofa(f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str) -> Piece:
    mat = pal.get("fabric")
    d, seat = rng.uniform(0.75, 0.88), rng.uniform(0.4, 0.48)
    f.box(f"{n}_base", (w, d, seat), u, d / 2, seat / 2, mat, 0.04)
    f.box(f"{n}_back", (w, 0.2, 0.45), u, 0.1, seat + 0.22, mat, 0.05)
    for side in (-1, 1):
        f.box(f"{n}_arm{side}", (0.18, d, 0.25), u + side * (w / 2 - 0.09), d / 2, seat + 0.1, mat)
    cushion = f.box(
        f"{n}_cushion",
        (0.4, 0.12, 0.35),
        u - w / 2 + 0.45,
        0.3,
        seat + 0.2,
        pal.get("fabric"),
        0.04,
    )
    P.modifier(
        cushion, "ARRAY", count=max(1, int((w - 0.5) / 0.5)), relative_offset_displace=(1.25, 0, 0)
    )
    return Piece(u - w / 2, u + w / 2, d, seat + 0.45)


def bookshelf(f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str) -> Piece:
    wood, d, h = pal.get("wood"), 0.32, rng.uniform(1.5, 2.0)
    for side in (-1, 1):
        f.box(f"{n}_side{side}", (0.03, d, h), u + side * (w / 2 - 0.015), d / 2, h / 2, wood)
    f.box(f"{n}_back", (w, 0.02, h), u, 0.01, h / 2, wood)
    shelves = int(h / 0.38)
    step = (h - 0.03) / shelves
    board = f.box(f"{n}_board", (w - 0.06, d - 0.02, 0.025), u, d / 2, 0.0125, wood)
    P.modifier(
        board,
        "ARRAY",
        count=shelves + 1,
        use_relative_offset=False,
        use_constant_offset=True,
        constant_offset_displace=(0, 0, step),
    )
    for k in range(shelves):
        bw, bh = rng.uniform(0.025, 0.05), rng.uniform(0.18, min(0.3, step - 0.05))
        count = int(rng.uniform(0.4, 0.95) * (w - 0.08) / (bw * 1.08))
        if count < 1:
            continue
        book = f.box(
            f"{n}_books{k}",
            (bw, rng.uniform(0.15, 0.24), bh),
            u - w / 2 + 0.05 + bw / 2,
            0.13,
            k * step + 0.025 + bh / 2,
            pal.get("object"),
        )
        P.modifier(book, "ARRAY", count=count, relative_offset_displace=(1.08, 0, 0))
    return Piece(u - w / 2, u + w / 2, d, h)


def cabinet(
    f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str, max_h: float = 1.1
) -> Piece:
    d, h = rng.uniform(0.4, 0.5), min(max_h, rng.uniform(0.6, 1.0))
    f.box(f"{n}_body", (w, d, h - 0.08), u, d / 2, (h + 0.08) / 2, pal.get("wood"), 0.01)
    drawers = max(1, int(h / 0.28))
    dz = (h - 0.1) / drawers
    front = f.box(
        f"{n}_front",
        (w - 0.06, 0.02, dz - 0.03),
        u,
        d + 0.01,
        0.1 + dz / 2,
        pal.get("object"),
        0.005,
    )
    P.modifier(
        front,
        "ARRAY",
        count=drawers,
        use_relative_offset=False,
        use_constant_offset=True,
        constant_offset_displace=(0, 0, dz),
    )
    for side in (-1, 1):
        f.cyl(
            f"{n}_foot{side}",
            0.025,
            0.08,
            u + side * (w / 2 - 0.06),
            d / 2,
            0.04,
            pal.shared("metal"),
        )
    if h < max_h - 0.3:  # decoration on top
        deco = rng.choice(["vase", "ball", "monkey"])
        top = (u + rng.uniform(-w / 4, w / 4), d / 2, h)
        if deco == "vase":
            vh = rng.uniform(0.15, 0.3)
            vase = f.cyl(f"{n}_vase", 0.07, vh, top[0], top[1], h + vh / 2, pal.get("object"), 0.04)
            P.modifier(vase, "SOLIDIFY", thickness=0.01)
        elif deco == "ball":
            P.uv_sphere(f"{n}_ball", 0.08, f.at(top[0], top[1], h + 0.08), pal.get("object"))
        else:
            P.monkey(
                f"{n}_monkey",
                0.2,
                f.at(top[0], top[1], h + 0.08),
                pal.get("object"),
                (0, 0, f.angle),
            )
    return Piece(u - w / 2, u + w / 2, d + 0.02, h + 0.3)


def desk(f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str) -> Piece:
    d, h = rng.uniform(0.55, 0.7), rng.uniform(0.72, 0.78)
    f.box(f"{n}_top", (w, d, 0.04), u, d / 2, h - 0.02, pal.get("wood"), 0.01)
    leg = f.cyl(
        f"{n}_leg", 0.025, h - 0.04, u - w / 2 + 0.06, 0.06, (h - 0.04) / 2, pal.shared("metal")
    )
    P.modifier(
        leg,
        "ARRAY",
        count=2,
        use_relative_offset=False,
        use_constant_offset=True,
        constant_offset_displace=(w - 0.12, 0, 0),
    )
    P.modifier(
        leg,
        "ARRAY",
        count=2,
        use_relative_offset=False,
        use_constant_offset=True,
        constant_offset_displace=(0, d - 0.12, 0),
    )
    # chair tucked under: seat, back and one leg arrayed into four
    cu, cv, mat = u + rng.uniform(-w / 5, w / 5), d * 0.75, pal.get("object")
    f.box(f"{n}_seat", (0.42, 0.42, 0.04), cu, cv, 0.45, mat, 0.01)
    f.box(f"{n}_cback", (0.42, 0.03, 0.4), cu, cv + 0.2, 0.67, mat, 0.01)
    cleg = f.cyl(
        f"{n}_cleg", 0.015, 0.43, cu - 0.18, cv - 0.18, 0.215, pal.shared("metal"), segments=8
    )
    P.modifier(
        cleg,
        "ARRAY",
        count=2,
        use_relative_offset=False,
        use_constant_offset=True,
        constant_offset_displace=(0.36, 0, 0),
    )
    P.modifier(
        cleg,
        "ARRAY",
        count=2,
        use_relative_offset=False,
        use_constant_offset=True,
        constant_offset_displace=(0, 0.36, 0),
    )
    f.box(f"{n}_screen", (min(0.6, w * 0.5), 0.03, 0.35), u, 0.12, h + 0.25, pal.get("emissive"))
    return Piece(u - w / 2, u + w / 2, cv + 0.23, h + 0.45)


def plant(
    f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str, max_h: float = 2.0
) -> Piece:
    r = min(w / 2 - 0.02, 0.2)
    ph = min(rng.uniform(0.25, 0.45), max_h / 3)
    pot = f.cyl(f"{n}_pot", r * 0.75, ph, u, r + 0.02, ph / 2, pal.get("object"), r)
    P.modifier(pot, "BEVEL", width=0.01, segments=2)
    crown = min(rng.uniform(0.25, 0.45), max_h / 3)
    P.ico_sphere(
        f"{n}_leaves",
        crown,
        f.at(u, r + 0.02, ph + crown * 0.9),
        pal.get("foliage"),
        2,
        0.25,
        P.np_rng(rng),
        (r * 1.3 / crown, r * 1.3 / crown, 1.0),
    )
    return Piece(u - w / 2, u + w / 2, 2 * r + 0.1, ph + 2 * crown)


def floor_lamp(f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str) -> Piece:
    h = rng.uniform(1.4, 1.7)
    f.cyl(f"{n}_base", 0.15, 0.03, u, 0.2, 0.015, pal.shared("metal"))
    f.cyl(f"{n}_pole", 0.012, h, u, 0.2, h / 2, pal.shared("metal"), segments=8)
    f.cyl(f"{n}_shade", 0.18, 0.25, u, 0.2, h, pal.get("emissive"), 0.1)
    L.light(
        f"{n}_bulb", "POINT", f.at(u, 0.2, h - 0.05), rng.uniform(20, 50), (1.0, 0.85, 0.7), 0.05
    )
    return Piece(u - w / 2, u + w / 2, 0.4, h + 0.15)


def radiator(
    f: Frame, u: float, w: float, pal: Palette, rng: random.Random, n: str, max_h: float = 0.8
) -> Piece:
    h = min(max_h, 0.6)
    fin = f.box(
        f"{n}_fin", (0.04, 0.08, h), u - w / 2 + 0.02, 0.08, 0.12 + h / 2, pal.shared("metal"), 0.01
    )
    P.modifier(fin, "ARRAY", count=max(2, int(w / 0.07)), relative_offset_displace=(1.75, 0, 0))
    return Piece(u - w / 2, u + w / 2, 0.15, h + 0.12)


Builder = Callable[..., Piece]
TALL: dict[str, tuple[Builder, float, float]] = {  # name -> (builder, min width, max width)
    "sofa": (sofa, 1.4, 2.2),
    "bookshelf": (bookshelf, 0.7, 1.3),
    "cabinet": (cabinet, 0.6, 1.4),
    "desk": (desk, 1.0, 1.5),
    "plant": (plant, 0.45, 0.6),
    "floor_lamp": (floor_lamp, 0.45, 0.5),
}
LOW: dict[str, tuple[Builder, float, float]] = {  # fit under a window sill
    "cabinet": (cabinet, 0.6, 1.2),
    "radiator": (radiator, 0.6, 1.2),
    "plant": (plant, 0.45, 0.6),
}
