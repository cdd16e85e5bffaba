"""Family "tabletop": a handful of objects on a table (or the floor), orbited at 1-3 m.

Object-centric captures are the common case for feed-forward reconstruction; the objects
mix primitives and modifier-made shapes (bevel, twist, array, wireframe, subdivision) and
materials of every kind. The camera circles outside the table's footprint with a margin,
always looking at the table, so every view ray lands on the table, objects or floor.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import lights as L
from . import paths, world
from . import primitives as P
from . import shapes as S
from .palette import Palette


@dataclass(frozen=True)
class Table:
    """Where things stand: table-top centre ``(x, y)``, its height and half extents."""

    x: float
    y: float
    top: float
    half: tuple[float, float]


def _cube(n, r, p, pal, rng):
    o = P.box(
        n,
        (1.4 * r, 1.4 * r, 1.4 * r),
        (p[0], p[1], p[2] + 0.7 * r),
        pal.get("object"),
        (0, 0, rng.uniform(0, math.pi)),
    )
    P.bevel(o, 0.1 * r, 3)


def _sphere(n, r, p, pal, rng):
    P.uv_sphere(n, r, (p[0], p[1], p[2] + r), pal.get("object"))


def _cylinder(n, r, p, pal, rng):
    h = rng.uniform(1.0, 3.0) * r
    P.cylinder(
        n,
        r,
        h,
        (p[0], p[1], p[2] + h / 2),
        pal.get("object"),
        radius_top=r * rng.choice([1.0, 0.0, 0.6]),
    )


def _torus(n, r, p, pal, rng):
    minor = r * rng.uniform(0.2, 0.35)
    if rng.random() < 0.5:
        S.torus(n, r - minor, minor, (p[0], p[1], p[2] + minor), pal.get("object"))
    else:
        S.torus(
            n,
            r - minor,
            minor,
            (p[0], p[1], p[2] + r),
            pal.get("object"),
            (math.pi / 2, 0, rng.uniform(0, 3)),
        )


def _monkey(n, r, p, pal, rng):
    P.monkey(
        n,
        2 * r,
        (p[0], p[1], p[2] + 0.7 * r),
        pal.get("object"),
        (0, 0, rng.uniform(0, 2 * math.pi)),
    )


def _twisted(n, r, p, pal, rng):
    h = rng.uniform(2.0, 3.5) * r
    o = P.box(
        n, (r, r, h), (p[0], p[1], p[2] + h / 2), pal.get("object"), (0, 0, rng.uniform(0, 3))
    )
    P.modifier(o, "SUBSURF", subdivision_type="SIMPLE", levels=3, render_levels=3)
    P.modifier(
        o, "SIMPLE_DEFORM", deform_method="TWIST", angle=rng.uniform(1.0, 3.0), deform_axis="Z"
    )


def _stack(n, r, p, pal, rng):
    s = 0.9 * r
    o = P.box(
        n,
        (s, s, s * 0.6),
        (p[0], p[1], p[2] + 0.3 * s),
        pal.get("object"),
        (0, 0, rng.uniform(0, 3)),
    )
    P.bevel(o, 0.05 * s)
    P.modifier(o, "ARRAY", count=rng.randint(2, 4), relative_offset_displace=(0, 0, 1.05))


def _wire(n, r, p, pal, rng):
    o = P.ico_sphere(n, r, (p[0], p[1], p[2] + r), pal.get("metal"), rng.randint(1, 2))
    P.modifier(o, "WIREFRAME", thickness=0.08 * r, use_replace=True)


def _mug(n, r, p, pal, rng):
    h, mat = rng.uniform(1.2, 2.0) * r, pal.get("object")
    o = P.cylinder(n, 0.8 * r, h, (p[0], p[1], p[2] + h / 2), mat)
    P.bevel(o, 0.01)
    S.torus(
        f"{n}_handle",
        0.3 * h,
        0.06 * h,
        (p[0] + 0.8 * r, p[1], p[2] + h / 2),
        mat,
        (math.pi / 2, 0, 0),
        16,
        6,
    )


def _bottle(n, r, p, pal, rng):
    h, mat = rng.uniform(2.5, 4.0) * r, pal.get("object")
    P.cylinder(n, 0.6 * r, 0.6 * h, (p[0], p[1], p[2] + 0.3 * h), mat)
    P.cylinder(
        f"{n}_shoulder", 0.6 * r, 0.15 * h, (p[0], p[1], p[2] + 0.675 * h), mat, radius_top=0.2 * r
    )
    P.cylinder(f"{n}_neck", 0.2 * r, 0.25 * h, (p[0], p[1], p[2] + 0.875 * h), mat)


OBJECTS: dict[str, Callable[..., None]] = {
    "cube": _cube,
    "sphere": _sphere,
    "cylinder": _cylinder,
    "torus": _torus,
    "monkey": _monkey,
    "twisted": _twisted,
    "stack": _stack,
    "wire": _wire,
    "mug": _mug,
    "bottle": _bottle,
}


def table(rng: random.Random, pal: Palette, kind: str | None = None) -> Table:
    """A rectangular or round table, or none (objects on the floor): returns the top."""
    kind = kind or rng.choice(["rect", "rect", "round", "floor"])
    if kind == "floor":
        P.box("mat", (1.4, 1.4, 0.01), (0, 0, 0.005), pal.get("fabric"))
        return Table(0.0, 0.0, 0.01, (0.7, 0.7))
    h, metal, wood = rng.uniform(0.7, 0.8), pal.shared("metal"), pal.get("wood")
    if kind == "round":
        r = rng.uniform(0.5, 0.7)
        P.bevel(P.cylinder("table_top", r, 0.04, (0, 0, h - 0.02), wood, segments=48), 0.01)
        P.cylinder("table_post", 0.05, h - 0.04, (0, 0, (h - 0.04) / 2), metal)
        P.cylinder("table_foot", 0.3, 0.03, (0, 0, 0.015), metal)
        return Table(0.0, 0.0, h, (r * 0.72, r * 0.72))
    tw, td = rng.uniform(1.0, 1.5), rng.uniform(0.7, 1.0)
    P.bevel(P.box("table_top", (tw, td, 0.04), (0, 0, h - 0.02), wood), 0.01)
    leg = P.cylinder(
        "table_leg", 0.03, h - 0.04, (-tw / 2 + 0.08, -td / 2 + 0.08, (h - 0.04) / 2), metal
    )
    for axis, off in ((0, tw - 0.16), (1, td - 0.16)):
        disp = [0.0, 0.0, 0.0]
        disp[axis] = off
        P.modifier(
            leg,
            "ARRAY",
            count=2,
            use_relative_offset=False,
            use_constant_offset=True,
            constant_offset_displace=disp,
        )
    return Table(0.0, 0.0, h, (tw / 2, td / 2))


def place_objects(
    rng: random.Random,
    pal: Palette,
    t: Table,
    kinds: tuple[str, ...],
    count: int,
    size: tuple[float, float] = (0.07, 0.17),
    makers: dict | None = None,
) -> int:
    """Scatter ``count`` objects over the table top without overlaps (rejection sampling);
    ``makers`` maps kind names to builders (default ``OBJECTS``)."""
    makers = makers or OBJECTS
    placed: list[tuple[float, float, float]] = []
    for k in range(count):
        for _ in range(40):
            r = rng.uniform(*size)
            x = t.x + rng.uniform(-t.half[0] + r + 0.03, t.half[0] - r - 0.03)
            y = t.y + rng.uniform(-t.half[1] + r + 0.03, t.half[1] - r - 0.03)
            if all(math.hypot(x - a, y - b) > r + c + 0.03 for a, b, c in placed):
                placed.append((x, y, r))
                kind = rng.choice(kinds)
                makers[kind](f"obj{k}_{kind}", r, (x, y, t.top), pal, rng)
                break
    return len(placed)


def surroundings(rng: random.Random, pal: Palette, clear_radius: float) -> None:
    """Floor, optional backdrop walls beyond the camera orbit, lights and world."""
    P.box("floor", (24.0, 24.0, 0.1), (0, 0, -0.05), pal.shared("floor"), role="structure")
    if rng.random() < 0.7:
        dist = clear_radius + rng.uniform(1.0, 2.5)
        start = rng.randrange(4)
        for k in range(rng.randint(2, 4)):
            a = (start + k) * math.pi / 2
            c = (dist * math.cos(a), dist * math.sin(a), 1.5)
            P.box(
                f"backdrop{k}",
                (0.1, 2 * dist + 0.1, 3.0),
                c,
                pal.shared("wall"),
                (0, 0, a),
                "structure",
            )
        world.uniform_world((0.8, 0.85, 1.0), rng.uniform(0.15, 0.3))
    else:
        world.gradient_sky(
            (0.25, 0.4, 0.8), (0.8, 0.85, 0.9), (0.2, 0.18, 0.15), rng.uniform(0.6, 1.0)
        )
    key_a, key_e = rng.uniform(0, 2 * math.pi), rng.uniform(0.6, 1.2)
    key = (
        2.5 * math.cos(key_a) * math.cos(key_e),
        2.5 * math.sin(key_a) * math.cos(key_e),
        2.5 * math.sin(key_e) + 0.8,
    )
    L.light("key", "AREA", key, rng.uniform(150, 350), (1.0, 0.95, 0.9), 1.0, (0, 0, 0.8))
    fill = (-key[0], -key[1], rng.uniform(1.2, 2.0))
    L.light("fill", "POINT", fill, rng.uniform(40, 100), (0.85, 0.9, 1.0), 0.2)


def orbit_trajectory(
    rng: random.Random, t: Table, radius: tuple[float, float] = (1.1, 2.0)
) -> paths.Built:
    """Wobbly loop round the table outside its footprint, looking at its top."""
    half_diag = math.hypot(*t.half)
    r0 = max(rng.uniform(*radius), (half_diag + 0.45) / 0.85)
    lo = t.top + 0.3 if t.top > 0.1 else 0.5
    eyes = paths.orbit(
        np.array([t.x, t.y]),
        r0,
        (lo, lo + rng.uniform(0.6, 1.0)),
        rng.uniform(0, 6.3),
        0.15,
        direction=rng.choice([-1, 1]),
    )
    a = paths.loop_parameter(len(eyes))
    wander = 0.25 * min(t.half) * np.stack([np.sin(2 * a), np.cos(3 * a), 0 * a], axis=1)
    targets = np.array([t.x, t.y, t.top + 0.1]) + wander
    return paths.Built(eyes, targets, rng.uniform(30.0, 42.0))


def build(
    rng: random.Random,
    pal: Palette,
    kinds: tuple[str, ...] | None = None,
    table_kind: str | None = None,
) -> tuple[paths.Built, Table]:
    """Table, objects, surroundings and the orbit."""
    t = table(rng, pal, table_kind)
    place_objects(rng, pal, t, kinds or tuple(OBJECTS), rng.randint(5, 9))
    built = orbit_trajectory(rng, t)
    surroundings(rng, pal, float(np.max(np.linalg.norm(built.eyes[:, :2], axis=1))))
    return built, t
