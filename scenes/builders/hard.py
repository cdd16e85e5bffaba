"""Hard scenes: family layouts with one difficulty turned up, named by ``SceneInfo.tags``.

Each is deterministic in the seed and built from the family builders, so the difficulty is
the only thing that changes: ``textureless`` is a room whose palette is plain colours,
``repeated_pattern`` a room of bricks, checkers and arrays, ``specular`` a tabletop of
mirrors, ``thin_structures`` a tabletop behind a railing and cables, ``near_far`` a walk past
things 0.5 m away with buildings 100 m behind, ``inside_outside`` a walk into a house.
"""

from __future__ import annotations

import math
import random

import numpy as np

from . import lights as L
from . import open_scene, paths, room, tabletop
from . import primitives as P
from . import shapes as S
from .palette import Palette


def textureless(rng: random.Random, pal: Palette) -> paths.Built:
    return room.build(rng, pal)[0]


def repeated_pattern(rng: random.Random, pal: Palette) -> paths.Built:
    """Brick walls, checker floor, identical shelves and cabinets, a lattice of identical
    stools (low enough for the camera to pass over) and a row of identical frames."""
    built, rm = room.build(
        rng, pal, ("bookshelf", "cabinet"), with_pictures=False, centrepiece=False
    )
    seat, s = pal.get("object"), rng.uniform(0.3, 0.4)
    step = 1.0
    nx, ny = max(1, int((rm.width - 2.4) / step)), max(1, int((rm.depth - 2.4) / step))
    stool = P.box("stool", (s, s, 0.42), (-(nx - 1) * step / 2, -(ny - 1) * step / 2, 0.21), seat)
    P.bevel(stool, 0.03)
    for axis, count in ((0, nx), (1, ny)):
        disp = [0.0, 0.0, 0.0]
        disp[axis] = step
        P.modifier(
            stool,
            "ARRAY",
            count=count,
            use_relative_offset=False,
            use_constant_offset=True,
            constant_offset_displace=disp,
        )
    frame_z = min(2.25, rm.height - 0.3)
    for i, wall in enumerate(rm.walls):
        count = int((wall.u_range[1] - wall.u_range[0]) / 0.7)
        if count < 2:
            continue
        frame = wall.frame.box(
            f"frames{i}",
            (0.4, 0.03, 0.3),
            wall.u_range[0] + 0.35,
            0.02,
            frame_z,
            pal.shared("picture"),
        )
        P.modifier(
            frame,
            "ARRAY",
            count=count,
            use_relative_offset=False,
            use_constant_offset=True,
            constant_offset_displace=(0.7, 0, 0),
        )
    return built


def specular(rng: random.Random, pal: Palette) -> paths.Built:
    """Mirror-like metals and a glossy floor, lit by small strong lamps (sharp highlights)."""
    kinds = ("sphere", "torus", "monkey", "cube", "cylinder", "mug", "bottle", "twisted")
    built, t = tabletop.build(rng, pal, kinds, rng.choice(["rect", "round"]))
    for k in range(2):
        a = rng.uniform(0, 2 * math.pi)
        L.light(
            f"spot{k}",
            "POINT",
            (1.2 * math.cos(a), 1.2 * math.sin(a), t.top + rng.uniform(1.0, 1.8)),
            rng.uniform(30, 80),
            (1.0, 1.0, 1.0),
            0.02,
        )
    return built


def _spring(n, r, p, pal, rng):
    s = np.linspace(0, 1, 120)
    turns, h = rng.uniform(4, 8), rng.uniform(2.0, 3.0) * r
    a = 2 * math.pi * turns * s
    pts = np.stack([p[0] + 0.6 * r * np.cos(a), p[1] + 0.6 * r * np.sin(a), p[2] + 0.01 + h * s], 1)
    S.cable(n, pts, 0.003, pal.shared("metal"))


def _mast(n, r, p, pal, rng):
    h, mat = rng.uniform(3.0, 4.5) * r, pal.shared("metal")
    P.rod(n, p, (p[0], p[1], p[2] + h), 0.003, mat)
    for k in range(3):
        z, w = p[2] + h * (0.5 + 0.15 * k), r * (1.0 - 0.25 * k)
        P.rod(f"{n}_bar{k}", (p[0] - w, p[1], z), (p[0] + w, p[1], z), 0.002, mat, 6)
    P.uv_sphere(f"{n}_tip", 0.01, (p[0], p[1], p[2] + h), pal.get("object"), 8, 4)


def _lattice(n, r, p, pal, rng):
    h = rng.uniform(2.5, 4.0) * r
    o = P.cylinder(
        n, 0.6 * r, h, (p[0], p[1], p[2] + h / 2), pal.get("object"), segments=6, smooth=False
    )
    P.modifier(o, "WIREFRAME", thickness=0.006, use_replace=True)


def _wire_cube(n, r, p, pal, rng):
    o = P.box(
        n,
        (1.2 * r, 1.2 * r, 1.2 * r),
        (p[0], p[1], p[2] + 0.6 * r),
        pal.get("metal"),
        (0, 0, rng.uniform(0, 3)),
    )
    P.modifier(o, "SUBSURF", subdivision_type="SIMPLE", levels=1, render_levels=1)
    P.modifier(o, "WIREFRAME", thickness=0.006, use_replace=True)


THIN = {
    "spring": _spring,
    "mast": _mast,
    "lattice": _lattice,
    "wire_cube": _wire_cube,
    "wire": tabletop.OBJECTS["wire"],
    "bottle": tabletop.OBJECTS["bottle"],
}


def thin_structures(rng: random.Random, pal: Palette) -> paths.Built:
    """Wire objects on a table inside a railing hung with cables, overhead wires beyond."""
    t = tabletop.table(rng, pal, rng.choice(["rect", "round"]))
    tabletop.place_objects(rng, pal, t, tuple(THIN), rng.randint(5, 8), (0.06, 0.13), THIN)
    hx, hy = t.half[0] + 0.3, t.half[1] + 0.3
    rh, metal, cable_mat = rng.uniform(0.9, 1.05), pal.shared("metal"), pal.get("object")
    corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
    posts: list[tuple[float, float]] = []
    for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1]):
        n = max(2, round(math.hypot(x1 - x0, y1 - y0) / rng.uniform(0.35, 0.5)))
        posts += [(x0 + (x1 - x0) * k / n, y0 + (y1 - y0) * k / n) for k in range(n)]
    for k, (x, y) in enumerate(posts):
        P.rod(f"post{k}", (t.x + x, t.y + y, 0.0), (t.x + x, t.y + y, rh), 0.012, metal)
        x1, y1 = posts[(k + 1) % len(posts)]
        S.cable(
            f"cable{k}",
            S.catenary(
                (t.x + x, t.y + y, 0.7 * rh), (t.x + x1, t.y + y1, 0.7 * rh), rng.uniform(0.03, 0.1)
            ),
            0.003,
            cable_mat,
        )
    for k, (x0, y0) in enumerate(corners):
        x1, y1 = corners[(k + 1) % 4]
        for j, z in enumerate((rh, 0.4 * rh)):
            P.rod(
                f"rail{k}_{j}",
                (t.x + x0, t.y + y0, z),
                (t.x + x1, t.y + y1, z),
                0.015 - 0.007 * j,
                metal,
            )
    S.cable("lamp_cord", [(t.x, t.y, 3.0), (t.x, t.y, t.top + 0.75)], 0.004, cable_mat)
    P.cylinder(
        "lamp_shade", 0.12, 0.12, (t.x, t.y, t.top + 0.69), pal.get("emissive"), radius_top=0.03
    )
    railing = tabletop.Table(t.x, t.y, t.top, (hx, hy))
    built = tabletop.orbit_trajectory(rng, railing)
    reach = float(np.max(np.linalg.norm(built.eyes[:, :2], axis=1))) + 0.8
    for k in range(2):  # overhead wires between two poles outside the orbit
        a = rng.uniform(0, math.pi) + k * math.pi / 2
        p0 = (reach * math.cos(a), reach * math.sin(a))
        for side, (x, y) in enumerate((p0, (-p0[0], -p0[1]))):
            P.rod(f"pole{k}_{side}", (x, y, 0.0), (x, y, 3.4), 0.04, metal)
        for j in range(2):
            z = 3.0 + 0.25 * j
            S.cable(
                f"wire{k}_{j}",
                S.catenary((*p0, z), (-p0[0], -p0[1], z), 0.15, 24),
                0.005,
                cable_mat,
            )
    tabletop.surroundings(rng, pal, reach + 0.2)
    return built


def near_far(rng: random.Random, pal: Palette) -> paths.Built:
    """Walk along x looking sideways (+y) past small things 0.5-0.7 m away at eye level,
    with buildings and hills 80-150 m behind them."""
    open_scene.ground_and_sky(rng, pal)
    length = rng.uniform(6, 10)
    built = open_scene.walk(rng, length, 0.03, 0.3, math.pi / 2, 20.0)
    x, k = -length / 2 - 1.0, 0
    while x < length / 2 + 1.0:
        y, top = rng.uniform(0.5, 0.7), rng.uniform(1.2, 1.9)
        r = rng.uniform(0.05, 0.09)
        P.rod(f"near{k}_stem", (x, y, 0.0), (x, y, top - r), 0.012, pal.get("wood"), 6)
        kind = rng.choice(["sphere", "cube", "leaf"])
        if kind == "sphere":
            P.uv_sphere(f"near{k}", r, (x, y, top), pal.get("object"), 16, 8)
        elif kind == "cube":
            P.box(
                f"near{k}",
                (1.4 * r, 1.4 * r, 1.4 * r),
                (x, y, top),
                pal.get("object"),
                (0, 0, rng.uniform(0, 3)),
            )
        else:
            P.ico_sphere(f"near{k}", r, (x, y, top), pal.shared("foliage"), 1, 0.3, P.np_rng(rng))
        x, k = x + rng.uniform(0.4, 0.6), k + 1
    for k in range(rng.randint(3, 6)):  # a little middle ground
        open_scene.tree(
            rng, pal, rng.uniform(-20, 20), rng.uniform(8, 30), rng.uniform(4, 9), f"mid{k}"
        )
    open_scene.far_ring(
        rng, pal, (80, 150), rng.randint(10, 16), (math.pi / 2 - 0.9, math.pi / 2 + 0.9)
    )
    open_scene.far_ring(rng, pal, (100, 190), rng.randint(4, 8))
    return built
