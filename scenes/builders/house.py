"""Hard scene ``inside_outside``: a house in an open landscape, entered through its doorway.

The camera starts outside (the building fills the view), walks straight through the
doorway (so it clears the door jambs with margin) and then loops round the free middle of
the furnished inside, looking about. Interior and exterior share one continuous path, which
is what makes the scene hard: the visible geometry and lighting change completely.
"""

from __future__ import annotations

import math
import random

import numpy as np

from . import furniture as F
from . import layout, open_scene, paths
from . import lights as L
from . import primitives as P
from . import shapes as S
from .palette import Palette


def inside_outside(rng: random.Random, pal: Palette) -> paths.Built:
    """A house with an open doorway and windows in an open landscape; the camera starts
    outside, walks through the doorway and looks round the furnished inside."""
    open_scene.ground_and_sky(rng, pal)
    W, D, H, t = rng.uniform(5.5, 7.5), rng.uniform(4.6, 6.0), rng.uniform(2.8, 3.1), 0.2
    walls = [
        layout.Wall(
            f, L, (0.05, L - 0.05) if i % 2 == 0 else (F.MAX_DEPTH + 0.05, L - F.MAX_DEPTH - 0.05)
        )
        for i, (f, L) in enumerate(layout.wall_frames(W, D))
    ]
    P.box_between(
        "house_floor",
        (-W / 2 - t, -D / 2 - t, 0.0),
        (W / 2 + t, D / 2 + t, 0.03),
        pal.shared("floor"),
        "structure",
    )
    P.box_between(
        "house_ceiling",
        (-W / 2 - t, -D / 2 - t, H),
        (W / 2 + t, D / 2 + t, H + t),
        pal.shared("ceiling"),
        "structure",
    )
    S.prism_roof(
        "house_roof",
        W + 2 * t + 0.6,
        D + 2 * t + 0.6,
        rng.uniform(1.0, 1.8),
        (0, 0, H + t),
        pal.shared("roof"),
        0.0,
    )
    door_w = rng.uniform(1.3, 1.6)
    door_u = rng.uniform(1.5, W - 1.5 - door_w)
    xd = -W / 2 + door_u + door_w / 2
    for i, wall in enumerate(walls):
        openings = []
        if i == 0:
            openings.append((door_u, door_u + door_w, 0.0, 2.3))
        else:
            ww = rng.uniform(0.9, 1.4)
            u0 = rng.uniform(wall.u_range[0], wall.u_range[1] - ww)
            z0 = rng.uniform(0.9, 1.1)
            openings.append((u0, u0 + ww, z0, min(H - 0.3, z0 + 1.1)))
            wall.blocked.append((u0 - 0.05, u0 + ww + 0.05, z0))
        layout.wall_with_openings(
            wall.frame, wall.length, H, openings, pal.shared("wall"), f"house_wall{i}", t
        )
        if i > 0:
            wall.pieces = layout.fill_wall(
                wall.frame, wall.length, wall.u_range, wall.blocked, pal, rng, f"w{i}_"
            )
    L.light(
        "house_light",
        "AREA",
        (0, 0, H - 0.05),
        rng.uniform(120, 250),
        (1.0, 0.93, 0.85),
        1.0,
        (0, 0, 0),
    )
    P.box("house_lamp", (0.6, 0.6, 0.02), (0, 0, H - 0.01), pal.get("emissive"))
    # path: straight through the doorway, then round the free middle of the room
    ax, ay = W / 2 - F.MAX_DEPTH - 0.35, D / 2 - F.MAX_DEPTH - 0.35
    y_in = -D / 2 + 1.6
    ctrl = [
        (xd + rng.uniform(-2, 2), -D / 2 - 9.0),
        (xd, -D / 2 - 4.0),
        (xd, -D / 2 - 1.5),
        (xd, -D / 2 + 0.9),
        (xd, y_in),
    ]
    # then along the free ellipse, turning towards the roomier side (no U-turn at entry)
    start = math.atan2(y_in / ay, xd / ax)
    turn = (1.0 if xd < 0 else -1.0) * math.radians(rng.uniform(50, 65))
    ctrl += [
        (ax * math.cos(start + k * turn), ay * math.sin(start + k * turn)) for k in range(1, 5)
    ]
    curve = paths.catmull_rom(np.array([(x, y, 0.0) for x, y in ctrl]), 48)
    eyes, idx = paths.resample(curve, paths.N_POSES)
    s = np.linspace(0, 1, len(eyes))
    eyes[:, 2] = 1.6 + 0.05 * np.sin(7 * s)
    # look along the walking direction, low-passed so tight corners do not jerk the view
    heading = np.gradient(eyes[:, :2], axis=0)
    heading /= np.linalg.norm(heading, axis=1, keepdims=True)
    kernel = np.hanning(13)[1:-1]
    padded = np.pad(heading, ((5, 5), (0, 0)), mode="edge")
    heading = np.stack(
        [np.convolve(padded[:, i], kernel / kernel.sum(), "valid") for i in range(2)], 1
    )
    yaw = np.arctan2(heading[:, 1], heading[:, 0])
    yaw = np.unwrap(yaw)
    inside = np.clip((eyes[:, 1] - (-D / 2)) / 1.5, 0, 1)  # 0 outside -> 1 well inside
    yaw = yaw + inside * 0.9 * np.sin(2 * math.pi * 1.5 * s + rng.uniform(0, 6.3))
    targets = eyes + 3.0 * np.stack([np.cos(yaw), np.sin(yaw), -0.12 - 0.1 * inside], axis=1)
    # outdoors: trees and rocks away from the house and the approach, far scenery
    for k in range(rng.randint(6, 12)):
        x, y = rng.uniform(-25, 25), rng.uniform(-25, 25)
        if abs(x) < W / 2 + 4 and y < D / 2 + 4:
            continue  # near the house or its approach
        open_scene.tree(rng, pal, x, y, rng.uniform(4, 9), f"tree{k}")
    open_scene.far_ring(rng, pal, (40, 190), rng.randint(8, 14))
    return paths.Built(eyes, targets, rng.uniform(20.0, 26.0))
