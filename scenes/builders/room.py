"""Family "room": a closed room with furniture, a window, a door, lamps and pictures.

The room is a box of slabs (floor, ceiling, four walls) with openings cut by building the
wall from pieces around them (no booleans: exact, fast, deterministic). Furniture stands
against the walls no deeper than ``furniture.MAX_DEPTH``, so the middle of the room stays
free for the camera, which loops round it looking across the room. The window opens onto
an emissive sky panel, so every view ray hits geometry.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import numpy as np

from . import furniture as F
from . import layout, paths, world
from . import lights as L
from . import primitives as P
from . import shapes as S
from .palette import Palette

WALL_T = layout.WALL_T


@dataclass
class Room:
    """Layout facts that hard-scene variants build on."""

    width: float
    depth: float
    height: float
    walls: list[layout.Wall]


def window(
    wall: layout.Wall,
    u0: float,
    u1: float,
    z0: float,
    z1: float,
    pal: Palette,
    name: str,
    thick: float = WALL_T,
) -> None:
    """Frame bars, a sill, the sky panel behind and a daylight area light."""
    f, uc, zc = wall.frame, (u0 + u1) / 2, (z0 + z1) / 2
    bar = pal.shared("wood")
    f.box(f"{name}_vbar", (0.04, 0.05, z1 - z0), uc, -thick / 2, zc, bar, role="structure")
    f.box(f"{name}_hbar", (u1 - u0, 0.05, 0.04), uc, -thick / 2, zc, bar, role="structure")
    f.box(f"{name}_sill", (u1 - u0 + 0.1, 0.2, 0.04), uc, 0.03, z0 - 0.02, bar, role="structure")
    # close behind the opening and wide, so that even grazing view rays land on it
    sky = pal.get("sky_panel")
    size = (u1 - u0 + 6.0, 0.02, z1 - z0 + 4.0)
    f.box(f"{name}_sky", size, uc, -thick - 0.4, zc, sky, role="structure")
    lamp = L.light(
        f"{name}_daylight",
        "AREA",
        f.at(uc, -0.01, zc),
        60.0 * (u1 - u0) * (z1 - z0),
        (0.85, 0.92, 1.0),
        target=f.at(uc, 2.0, zc - 0.8),
    )
    lamp.data.shape = "RECTANGLE"
    lamp.data.size, lamp.data.size_y = u1 - u0, z1 - z0


def door(wall: layout.Wall, u0: float, pal: Palette, name: str) -> None:
    """A closed door panel with a knob; its span is blocked for furniture."""
    f = wall.frame
    f.box(f"{name}_panel", (0.9, 0.04, 2.05), u0 + 0.45, 0.02, 1.025, pal.get("wood"), 0.005)
    P.uv_sphere(f"{name}_knob", 0.03, f.at(u0 + 0.8, 0.07, 1.0), pal.shared("metal"), 12, 6)
    wall.blocked.append((u0 - 0.1, u0 + 1.0, 0.0))


def build(
    rng: random.Random,
    pal: Palette,
    choices: tuple[str, ...] | None = None,
    with_pictures: bool = True,
    centrepiece: bool = True,
) -> tuple[paths.Built, Room]:
    """Build a room into the current scene; returns the camera loop and the layout."""
    W, D, H = rng.uniform(4.0, 8.0), rng.uniform(4.0, 7.0), rng.uniform(2.6, 3.2)
    t = WALL_T
    P.box_between(
        "floor",
        (-W / 2 - t, -D / 2 - t, -t),
        (W / 2 + t, D / 2 + t, 0),
        pal.shared("floor"),
        "structure",
    )
    P.box_between(
        "ceiling",
        (-W / 2 - t, -D / 2 - t, H),
        (W / 2 + t, D / 2 + t, H + t),
        pal.shared("ceiling"),
        "structure",
    )
    m = F.MAX_DEPTH + 0.05
    walls = [
        layout.Wall(f, L, (0.05, L - 0.05) if i % 2 == 0 else (m, L - m))
        for i, (f, L) in enumerate(layout.wall_frames(W, D))
    ]
    # window on one wall, a door on another
    iw, idoor = rng.sample(range(4), 2)
    ww = walls[iw]
    win_w = rng.uniform(1.0, min(2.2, ww.u_range[1] - ww.u_range[0] - 0.5))
    u0 = rng.uniform(ww.u_range[0] + 0.2, ww.u_range[1] - win_w - 0.2)
    z0 = rng.uniform(0.8, 1.0)
    z1 = min(H - 0.3, z0 + rng.uniform(1.0, 1.5))
    window(ww, u0, u0 + win_w, z0, z1, pal, "window")
    ww.blocked.append((u0 - 0.05, u0 + win_w + 0.05, z0))
    wd = walls[idoor]
    door(wd, rng.uniform(wd.u_range[0] + 0.1, wd.u_range[1] - 1.0), pal, "door")
    for i, wall in enumerate(walls):
        openings = [(u0, u0 + win_w, z0, z1)] if i == iw else []
        layout.wall_with_openings(
            wall.frame, wall.length, H, openings, pal.shared("wall"), f"wall{i}"
        )
        wall.pieces = layout.fill_wall(
            wall.frame, wall.length, wall.u_range, wall.blocked, pal, rng, f"w{i}_", choices
        )
        if with_pictures:
            layout.pictures(wall, H, pal, rng, f"picture{i}_")
    # rug and coffee table: low, so the camera (>= 1.15 m) passes above them with margin
    P.box(
        "rug",
        (W * rng.uniform(0.3, 0.5), D * rng.uniform(0.3, 0.5), 0.01),
        (0, 0, 0.005),
        pal.get("fabric"),
    )
    if centrepiece and rng.random() < 0.7:
        top = rng.uniform(0.35, 0.5)
        tw, td = rng.uniform(0.6, 1.2), rng.uniform(0.4, 0.7)
        P.bevel(P.box("coffee_top", (tw, td, 0.04), (0, 0, top - 0.02), pal.get("wood")), 0.01)
        for k, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
            P.cylinder(
                f"coffee_leg{k}",
                0.02,
                top - 0.04,
                (sx * (tw / 2 - 0.05), sy * (td / 2 - 0.05), (top - 0.04) / 2),
                pal.shared("metal"),
                segments=8,
            )
        S.torus("coffee_deco", 0.08, 0.025, (0, 0, top + 0.025), pal.get("object"))
    # ceiling lights: emissive panels with an area light under each
    n_lamps = 2 if W > 6 else 1
    for k in range(n_lamps):
        x = 0.0 if n_lamps == 1 else (k - 0.5) * W / 2
        P.box(f"ceiling_panel{k}", (0.5, 0.5, 0.02), (x, 0, H - 0.01), pal.get("emissive"))
        L.light(
            f"ceiling_light{k}",
            "AREA",
            (x, 0, H - 0.03),
            rng.uniform(40, 90) * W * D / 25,
            (1.0, 0.93, 0.85),
            0.8,
            (x, 0, 0),
        )
    # a weak light facing up: the ceiling gets direct light (much less noise at low samples)
    L.light(
        "uplight",
        "AREA",
        (0, 0, H - 0.6),
        10.0 * W * D / 25 * n_lamps,
        (1.0, 0.95, 0.9),
        0.8 * min(W, D),
        (0, 0, 2 * H),
    )
    world.uniform_world((0.6, 0.7, 0.9), 0.05)
    # camera loop in the free middle, looking across the room
    ax, ay = W / 2 - F.MAX_DEPTH - 0.35, D / 2 - F.MAX_DEPTH - 0.35
    phase = rng.uniform(0, 2 * math.pi)
    eyes = paths.orbit(np.zeros(2), 1.0, (1.15, 1.65), phase, 0.12, direction=rng.choice([-1, 1]))
    eyes[:, 0] *= ax / 1.12
    eyes[:, 1] *= ay / 1.12
    a = paths.loop_parameter(len(eyes))
    theta = np.arctan2(eyes[:, 1], eyes[:, 0])
    psi = theta + math.pi + rng.uniform(0.5, 1.3) * np.sin(2 * a + rng.uniform(0, 6.3))
    pitch = -0.15 + 0.2 * np.sin(a * 3 + rng.uniform(0, 6.3))
    targets = eyes + 3.0 * np.stack([np.cos(psi), np.sin(psi), pitch], axis=1)
    built = paths.Built(eyes, targets, rng.uniform(18.0, 24.0))
    return built, Room(W, D, H, walls)
