"""Family "open": outdoors, with a depth range from 1 m to 200 m.

A ground plane 400 m across, objects near the path (1-3 m), trees and houses in the middle
distance and buildings and hills far away (30-200 m), under a gradient sky and a sun. The
camera walks along a gently winding path panning left and right, always pitched slightly
down so that every view ray meets the ground within ~100 m; the large, data-derived depth
range is what stresses near/far handling in the model.
"""

from __future__ import annotations

import math
import random

import numpy as np

from . import lights as L
from . import paths, world
from . import primitives as P
from . import shapes as S
from .palette import Palette

GROUND_HALF = 200.0


def ground_and_sky(rng: random.Random, pal: Palette) -> None:
    """Ground slab, gradient sky and sun (elevation 25-60 degrees)."""
    g = GROUND_HALF
    P.box("ground", (2 * g, 2 * g, 0.1), (0, 0, -0.05), pal.shared("ground"), role="structure")
    hue_shift = rng.uniform(-0.05, 0.05)
    world.gradient_sky(
        (0.18 + hue_shift, 0.35, 0.85), (0.75, 0.82, 0.9), (0.25, 0.22, 0.18), rng.uniform(0.8, 1.2)
    )
    sun = L.sun_direction(math.radians(rng.uniform(25, 60)), rng.uniform(0, 2 * math.pi))
    L.light(
        "sun", "SUN", tuple(50 * sun), rng.uniform(2.5, 4.0), (1.0, 0.95, 0.88), 0.02, (0, 0, 0)
    )


def tree(rng: random.Random, pal: Palette, x: float, y: float, height: float, n: str) -> None:
    """Broadleaf (trunk + jittered icosphere crown) or conifer (trunk + cone)."""
    trunk_h = height * rng.uniform(0.3, 0.45)
    P.cylinder(
        f"{n}_trunk", height * 0.03, trunk_h, (x, y, trunk_h / 2), pal.shared("bark"), segments=10
    )
    if rng.random() < 0.5:
        r = height * rng.uniform(0.25, 0.35)
        P.ico_sphere(
            f"{n}_crown", r, (x, y, trunk_h + r * 0.8), pal.shared("foliage"), 2, 0.2, P.np_rng(rng)
        )
    else:
        ch = height - trunk_h * 0.6
        P.cylinder(
            f"{n}_crown",
            height * 0.22,
            ch,
            (x, y, trunk_h * 0.4 + ch / 2),
            pal.shared("foliage"),
            segments=12,
            radius_top=0.0,
            smooth=False,
        )


def house(rng: random.Random, pal: Palette, x: float, y: float, size: float, n: str) -> None:
    """Box with a gable roof; ``size`` is the footprint width."""
    w, d, h = size, size * rng.uniform(0.6, 1.0), size * rng.uniform(0.5, 0.8)
    a = rng.uniform(0, math.pi)
    P.box(f"{n}_walls", (w, d, h), (x, y, h / 2), pal.get("building"), (0, 0, a))
    S.prism_roof(f"{n}_roof", w * 1.05, d * 1.1, h * 0.5, (x, y, h), pal.shared("roof"), a)


def far_ring(
    rng: random.Random,
    pal: Palette,
    dist: tuple[float, float],
    count: int,
    sector: tuple[float, float] = (0.0, 2 * math.pi),
) -> None:
    """Buildings, towers and hills between ``dist`` metres, within an azimuth ``sector``."""
    for k in range(count):
        r, a = rng.uniform(*dist), rng.uniform(*sector)
        x, y = r * math.cos(a), r * math.sin(a)
        kind = rng.choice(["building", "building", "hill", "tower", "tree"])
        if kind == "building":
            w, h = rng.uniform(8, min(30, 0.4 * r)), rng.uniform(10, 50)
            P.box(
                f"far{k}_building",
                (w, w * rng.uniform(0.5, 1.0), h),
                (x, y, h / 2),
                pal.get("building"),
                (0, 0, rng.uniform(0, math.pi)),
            )
        elif kind == "hill":
            R = min(60.0, r * rng.uniform(0.2, 0.45))  # never reaches the path
            P.uv_sphere(
                f"far{k}_hill",
                R,
                (x, y, -R * 0.2),
                pal.shared("ground"),
                32,
                12,
                (1.0, rng.uniform(0.6, 1.0), rng.uniform(0.25, 0.5)),
                role="structure",
                cut_below=R * 0.2 - 0.05,
            )
        elif kind == "tower":
            h = rng.uniform(25, 70)
            P.cylinder(
                f"far{k}_tower",
                rng.uniform(1.5, 4),
                h,
                (x, y, h / 2),
                pal.get("building"),
                segments=16,
            )
            P.uv_sphere(f"far{k}_tank", rng.uniform(3, 6), (x, y, h), pal.shared("metal"), 16, 8)
        else:
            tree(rng, pal, x, y, rng.uniform(12, 25), f"far{k}")


def mid_scatter(rng: random.Random, pal: Palette, count: int, keep_out) -> None:
    """Trees and houses at 6-30 m, outside the ``keep_out(x, y)`` corridor."""
    k = 0
    for _ in range(count * 5):
        if k >= count:
            break
        r, a = rng.uniform(6, 30), rng.uniform(0, 2 * math.pi)
        x, y = r * math.cos(a), r * math.sin(a)
        is_tree, size = rng.random() < 0.7, rng.uniform(4, 8)
        if keep_out(x, y, 4.0 if is_tree else 1.0 + 0.75 * size):
            continue
        if is_tree:
            tree(rng, pal, x, y, rng.uniform(4, 10), f"mid{k}")
        else:
            house(rng, pal, x, y, size, f"mid{k}")
        k += 1


def near_object(
    rng: random.Random, pal: Palette, x: float, y: float, n: str, yaw: float = 0.0
) -> None:
    """A rock, bush, bench, crate, post or lamp post about 0.3-1 m across."""
    kind = rng.choice(["rock", "bush", "bench", "crate", "post", "lamp"])
    if kind == "rock":
        r = rng.uniform(0.25, 0.6)
        P.ico_sphere(
            n, r, (x, y, r * 0.3), pal.get("stone"), 2, 0.2, P.np_rng(rng), (1.0, 0.8, 0.6)
        )
    elif kind == "bush":
        r = rng.uniform(0.3, 0.6)
        P.ico_sphere(n, r, (x, y, r * 0.7), pal.shared("foliage"), 2, 0.3, P.np_rng(rng))
    elif kind == "bench":
        mat = pal.get("wood")
        P.bevel(P.box(n, (1.4, 0.4, 0.05), (x, y, 0.45), mat, (0, 0, yaw)), 0.01)
        back = (x + 0.2 * math.sin(yaw), y - 0.2 * math.cos(yaw), 0.7)  # local (0, -0.2) rotated
        P.box(f"{n}_back", (1.4, 0.05, 0.35), back, mat, (0, 0, yaw))
        P.box(f"{n}_legs", (1.2, 0.35, 0.43), (x, y, 0.215), pal.shared("metal"), (0, 0, yaw))
    elif kind == "crate":
        s = rng.uniform(0.4, 0.7)
        o = P.box(n, (s, s, s), (x, y, s / 2), pal.get("object"), (0, 0, rng.uniform(0, 3)))
        P.bevel(o, 0.02)
    elif kind == "post":
        h = rng.uniform(0.8, 1.3)
        P.cylinder(n, 0.08, h, (x, y, h / 2), pal.get("wood"), segments=12)
        P.box(f"{n}_sign", (0.5, 0.04, 0.3), (x, y, h), pal.get("picture"), (0, 0, yaw))
    else:
        P.cylinder(n, 0.05, 3.0, (x, y, 1.5), pal.shared("metal"), segments=10)
        P.uv_sphere(f"{n}_globe", 0.18, (x, y, 3.1), pal.get("emissive"), 16, 8)


def walk(
    rng: random.Random,
    length: float,
    sway: float,
    yaw_amp: float,
    heading: float = 0.0,
    look_dist: float = 12.0,
) -> paths.Built:
    """Eyes along ``x`` (winding by ``sway`` in ``y``), panning by ``yaw_amp`` around
    ``heading``; look targets below eye level so rays reach the ground."""
    s = np.linspace(0.0, 1.0, paths.N_POSES)
    phase = rng.uniform(0, 2 * math.pi)
    x = -length / 2 + length * s
    eyes = np.stack(
        [x, sway * np.sin(2 * math.pi * s + phase), 1.6 + 0.06 * np.sin(5 * s + phase)], axis=1
    )
    yaw = heading + yaw_amp * np.sin(2 * math.pi * rng.uniform(1.0, 1.6) * s + rng.uniform(0, 6.3))
    tz = 0.9 + 0.4 * np.sin(2 * math.pi * 1.3 * s + phase)
    targets = np.stack(
        [x + look_dist * np.cos(yaw), eyes[:, 1] + look_dist * np.sin(yaw), tz], axis=1
    )
    return paths.Built(eyes, targets, rng.uniform(24.0, 32.0))


def build(rng: random.Random, pal: Palette) -> paths.Built:
    """Ground, sky, near/mid/far objects and a walk through them."""
    ground_and_sky(rng, pal)
    length, sway = rng.uniform(10, 16), rng.uniform(0.2, 0.8)
    P.box("path", (length + 30, 2.4 + 2 * sway, 0.01), (0, 0, 0.005), pal.get("path"))
    half = length / 2 + 8

    def keep_out(x: float, y: float, pad: float) -> bool:
        return abs(x) < half + pad and abs(y) < sway + pad

    for k in range(rng.randint(10, 16)):
        x = rng.uniform(-half, half)
        y = rng.choice([-1, 1]) * (sway + rng.uniform(1.6, 3.5))
        near_object(rng, pal, x, y, f"near{k}", rng.uniform(0, math.pi))
    mid_scatter(rng, pal, rng.randint(10, 18), keep_out)
    far_ring(rng, pal, (30, 100), rng.randint(6, 10), (-1.2, 1.2))  # ahead
    far_ring(rng, pal, (60, 190), rng.randint(8, 14))
    return walk(rng, length, sway, rng.uniform(0.4, 0.8))
