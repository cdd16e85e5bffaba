"""Scene "object_ring": one to three objects on a plain support before a plain background,
captured by a ring of cameras all round them (family "tabletop").

Why: object-centric photo sets (DTU, the Middlebury temple and dino rings) show a small
group of objects on a turntable or plinth against a dark, grey, white or coloured studio
backdrop, photographed from a ring at one distance, while the other families always fill
the frame with a room, a table or a landscape. Here the background is the world colour (no
geometry: the depth there is 0, as for the open scenes' sky), the support is a plinth, a
thin disc or nothing, and the ring's distance makes the objects fill about 40-70 % of the
frame at the scene's lens.

Randomness: geometry, the ring and the lights come from the layout stream ``rng``; the
support's and the background's colours from the palette's stream, as materials do.
"""

from __future__ import annotations

import math
import random

import numpy as np

from prosplat.data.rigs import draw_lens

from . import furniture, paths, world
from . import lights as L
from . import materials as M
from . import primitives as P
from .palette import Palette
from .query import box_distance, object_aabbs
from .tabletop import OBJECTS

#: Gap kept between the ring's eyes and any object's or the support's bounding box: above
#: ``scenes.builders.CLEARANCE`` (0.3 m), so ``clear_path`` never has to remove anything.
GAP = 0.4
#: The scene's lens (mm, 36 mm sensor), drawn log-uniformly by ``draw_lens(seed, LENS_MM)``:
#: the renderer's ``--lens-range A-B`` redraws the lens by that same function of the seed
#: while the ring stays, so with ``--lens-range 24-85`` (the ``photo128`` set) it draws this
#: very lens and the framing holds; another range scales the objects by the lenses' ratio.
LENS_MM = (24.0, 85.0)
#: Fraction of the frame's width the objects span (``object_extent``) at the scene's lens.
FILL = (0.4, 0.7)
#: Ring elevation above the objects' centre (degrees) and the wobble's amplitude.
ELEVATION_DEG = (10.0, 50.0)
WOBBLE_DEG = (2.0, 7.0)
BACKGROUNDS = ("dark", "grey", "white", "colour")


def _plant(n: str, r: float, p, pal: Palette, rng: random.Random) -> None:
    """A potted plant (the furniture builder's) standing at ``p`` with pot radius ``r``."""
    frame = furniture.Frame(p[0], p[1] - r - 0.02, 0.0, p[2])
    furniture.plant(frame, 0.0, 2 * r + 0.04, pal, rng, n, max_h=6 * r)


MAKERS = {**OBJECTS, "plant": _plant}


def place(rng: random.Random, pal: Palette, count: int) -> int:
    """``count`` objects standing on ``z = 0`` round the origin without overlaps: the first
    near the middle, the others beside it (rejection sampling). Returns how many fit."""
    placed: list[tuple[float, float, float]] = []
    kinds = tuple(MAKERS)
    for k in range(count):
        for _ in range(40):
            r = rng.uniform(0.12, 0.28) if k == 0 else rng.uniform(0.08, 0.2)
            reach = 0.0 if k == 0 else rng.uniform(0.2, 0.45)
            a = rng.uniform(0, 2 * math.pi)
            x, y = reach * math.cos(a), reach * math.sin(a)
            if all(math.hypot(x - u, y - v) > r + w + 0.04 for u, v, w in placed):
                placed.append((x, y, r))
                kind = rng.choice(kinds)
                MAKERS[kind](f"obj{k}_{kind}", r, (x, y, 0.0), pal, rng)
                break
    return len(placed)


def object_extent() -> tuple[np.ndarray, float, float]:
    """The centre of the bounding box of everything built so far, its apparent size (its
    largest side: about as wide as the objects look from a ring round them) and how far
    (horizontally) any object's box corner reaches from the centre."""
    boxes = object_aabbs()
    lo = np.min([b[1] for b in boxes], axis=0)
    hi = np.max([b[2] for b in boxes], axis=0)
    centre = (lo + hi) / 2
    reach = max(
        float(np.hypot(x - centre[0], y - centre[1]))
        for _, blo, bhi in boxes
        for x in (blo[0], bhi[0])
        for y in (blo[1], bhi[1])
    )
    return centre, float(np.max(hi - lo)), reach


def ring_trajectory(
    rng: random.Random, centre: np.ndarray, size: float, lens: float
) -> paths.Built:
    """The ring of eyes round ``centre`` looking at it, at the distance where objects of
    apparent ``size`` fill a drawn fraction of the frame at ``lens`` mm, moved out (5 % a
    step) until every eye is ``GAP`` from every bounding box built so far (objects and
    support: what ``clear_path`` checks), so nothing is ever removed."""
    fill = rng.uniform(*FILL)
    elevation = math.radians(rng.uniform(*ELEVATION_DEG))
    wobble = math.radians(rng.uniform(*WOBBLE_DEG)) if rng.random() < 0.5 else 0.0
    wobble = min(wobble, elevation - math.radians(5.0))  # stay above the objects' centre
    phase, direction = rng.uniform(0, 2 * math.pi), rng.choice([-1, 1])
    # ``size`` at distance d spans size / d * fx of the W px image, fx = lens / 36 * W
    distance = size * lens / (36.0 * fill)
    boxes = [(lo, hi) for _, lo, hi in object_aabbs()]
    while True:
        eyes = paths.ring(centre, distance, elevation, phase, wobble, direction=direction)
        if min(box_distance(eyes, lo, hi).min() for lo, hi in boxes) >= GAP:
            break
        distance *= 1.05
    targets = np.repeat(centre[None], len(eyes), axis=0)
    return paths.Built(eyes, targets, lens)


def draw_support(rng: random.Random, reach: float) -> tuple[str, float]:
    """The support's kind ("plinth", "disc" or "none") and half width: just wider than the
    objects' ``reach``, so they all stand on it."""
    kind = rng.choice(["plinth", "plinth", "disc", "disc", "none"])
    return kind, 0.0 if kind == "none" else reach + rng.uniform(0.03, 0.15)


def support(rng: random.Random, pal: Palette, kind: str, half: float, centre: np.ndarray) -> None:
    """A round or square plinth (0.3-0.9 m tall) or a thin round disc of half width ``half``
    under ``centre``, top at ``z = 0``; nothing for kind "none"."""
    if kind == "none":
        return
    if pal.rng.random() < 0.6:  # plain, as studio supports are
        tone = M.color(pal.rng, None, (0.0, 0.3), (0.15, 0.9))
        mat = M.plain(f"support_{kind}", tone, pal.rng.uniform(0.3, 0.9))
    else:
        mat = pal.get(pal.rng.choice(["wood", "stone", "fabric"]))
    x, y = float(centre[0]), float(centre[1])
    if kind == "disc":
        depth = rng.uniform(0.015, 0.05)
        P.cylinder(
            "support_disc", half, depth, (x, y, -depth / 2), mat, segments=64, role="structure"
        )
        return
    height = rng.uniform(0.3, 0.9)
    if rng.random() < 0.5:
        P.cylinder(
            "support_plinth", half, height, (x, y, -height / 2), mat, segments=48, role="structure"
        )
    else:
        box = P.box(
            "support_plinth",
            (2 * half, 2 * half, height),
            (x, y, -height / 2),
            mat,
            role="structure",
        )
        P.bevel(box, 0.01)


def background(pal: Palette) -> float:
    """A uniform world in one of :data:`BACKGROUNDS`; returns its luminance (linear). The
    world both fills the background and lights the objects, like a light tent or a dark
    studio: reflections show the same colour as the backdrop."""
    rng = pal.rng
    kind = rng.choice(BACKGROUNDS)
    if kind == "dark":
        grey = rng.uniform(0.0, 0.006)
        rgb = (grey, grey, grey * rng.uniform(0.9, 1.1))
    elif kind == "grey":
        grey = rng.uniform(0.08, 0.25)
        rgb = (grey, grey, grey)
    elif kind == "white":
        grey = rng.uniform(0.55, 0.9)
        rgb = (grey, grey * rng.uniform(0.97, 1.0), grey * rng.uniform(0.95, 1.03))
    else:
        rgb = M.color(rng, None, (0.3, 0.75), (0.35, 0.85))[:3]
    world.uniform_world(rgb, 1.0)
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]


def studio_lights(rng: random.Random, centre: np.ndarray, distance: float, ambient: float) -> None:
    """Two or three area or spot lights round the objects, aimed at ``centre``: a key, a
    dimmer fill on the other side and sometimes a rim light from behind and above. Power
    grows with the square of their distance (the same light on the objects whatever the
    scene's scale) and drops in a bright world, which lights the objects itself."""
    key_az = rng.uniform(0, 2 * math.pi)
    roles = [("key", 0.0, (35, 65), (25, 50)), ("fill", math.pi, (15, 45), (6, 18))]
    if rng.random() < 0.5:
        roles.append(("rim", rng.choice([-1, 1]) * rng.uniform(2.0, 2.6), (50, 75), (12, 30)))
    for name, turn, elevation, power in roles:
        el = math.radians(rng.uniform(*elevation))
        az = key_az + turn + rng.uniform(-0.4, 0.4)
        d = distance * rng.uniform(1.1, 1.8)
        pos = centre + d * np.array(
            [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
        )
        energy = d * d * rng.uniform(*power) * (1.0 - 0.6 * min(ambient, 1.0))
        kind = rng.choice(["AREA", "AREA", "SPOT"])
        size = rng.uniform(0.3, 1.0) * distance if kind == "AREA" else 0.05 * distance
        tint = (1.0, rng.uniform(0.9, 1.0), rng.uniform(0.8, 1.0))
        obj = L.light(name, kind, tuple(pos), energy, tint, size, tuple(centre))
        if kind == "SPOT":
            obj.data.spot_size = math.radians(rng.uniform(40, 70))
            obj.data.spot_blend = rng.uniform(0.2, 0.6)


def build(rng: random.Random, pal: Palette, seed: int) -> paths.Built:
    """Objects, their support, the ring round them, background and lights; ``seed`` keys
    the lens's own stream (:data:`LENS_MM`)."""
    place(rng, pal, rng.choice([1, 1, 2, 3]))
    centre, size, reach = object_extent()
    support(rng, pal, *draw_support(rng, reach), centre)
    built = ring_trajectory(rng, centre, size, draw_lens(seed, LENS_MM))
    ambient = background(pal)
    studio_lights(rng, centre, float(np.linalg.norm(built.eyes[0] - centre)), ambient)
    return built
