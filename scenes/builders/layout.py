"""Walls: frames, openings, and filling them with furniture and pictures.

Shared by the room family and the house of ``inside_outside``. A wall is built from box
pieces around its openings (no booleans: exact, fast, deterministic).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from . import furniture as F
from .palette import Palette

WALL_T = 0.12


@dataclass
class Wall:
    """One wall's frame, inner length, usable span and blocked spans (openings)."""

    frame: F.Frame
    length: float
    u_range: tuple[float, float]
    blocked: list[tuple[float, float, float]] = field(default_factory=list)
    pieces: list[F.Piece] = field(default_factory=list)


def wall_frames(width: float, depth: float, z: float = 0.0) -> list[tuple[F.Frame, float]]:
    """Frames of the four inner wall faces (counter-clockwise, ``v`` into the room)."""
    w, d = width / 2, depth / 2
    return [
        (F.Frame(-w, -d, 0.0, z), width),
        (F.Frame(w, -d, math.pi / 2, z), depth),
        (F.Frame(w, d, math.pi, z), width),
        (F.Frame(-w, d, 3 * math.pi / 2, z), depth),
    ]


def wall_with_openings(
    f: F.Frame, length: float, height: float, openings, mat, name: str, thick: float = WALL_T
) -> None:
    """Build a wall (outside the frame's ``v = 0`` face) around ``openings``
    ``[(u0, u1, z0, z1)]``, extending ``thick`` past both ends to close the corners."""
    cuts = sorted(openings)
    u = -thick
    for k, (u0, u1, z0, z1) in enumerate(cuts + [(length + thick, None, 0, 0)]):
        if u0 > u:
            f.box(
                f"{name}_col{k}",
                (u0 - u, thick, height),
                (u + u0) / 2,
                -thick / 2,
                height / 2,
                mat,
                role="structure",
            )
        if u1 is None:
            break
        if z0 > 0:
            f.box(
                f"{name}_low{k}",
                (u1 - u0, thick, z0),
                (u0 + u1) / 2,
                -thick / 2,
                z0 / 2,
                mat,
                role="structure",
            )
        if z1 < height:
            f.box(
                f"{name}_high{k}",
                (u1 - u0, thick, height - z1),
                (u0 + u1) / 2,
                -thick / 2,
                (z1 + height) / 2,
                mat,
                role="structure",
            )
        u = u1


def pictures(wall: Wall, height: float, pal: Palette, rng: random.Random, name: str) -> None:
    """Hang up to two pictures where nothing tall stands and nothing is cut out."""
    for k in range(rng.randint(0, 2)):
        w, h = rng.uniform(0.4, 1.0), rng.uniform(0.3, 0.7)
        z = min(rng.uniform(1.45, 1.8), height - 0.2 - h / 2)
        u = rng.uniform(wall.u_range[0] + w / 2 + 0.1, wall.u_range[1] - w / 2 - 0.1)
        a, b = u - w / 2 - 0.1, u + w / 2 + 0.1
        if any(p.u0 < b and p.u1 > a and p.height > z - h / 2 - 0.05 for p in wall.pieces):
            continue
        if any(u0 < b and u1 > a for u0, u1, _ in wall.blocked):
            continue
        picture(wall.frame, u, w, h, z, pal, f"{name}{k}")
        wall.pieces.append(F.Piece(a, b, 0.05, 99.0))  # no second picture on top


def fill_wall(
    f: F.Frame,
    length: float,
    u_range: tuple[float, float],
    blocked: list[tuple[float, float, float]],
    pal: Palette,
    rng: random.Random,
    prefix: str,
    choices: tuple[str, ...] | None = None,
) -> list[F.Piece]:
    """Place pieces along a wall between ``u_range`` with random gaps.

    ``blocked`` holds ``(u0, u1, max_height)`` spans (0 for a door, sill height under a
    window); pieces overlapping a span must be lower, or are skipped.
    """
    pieces, u = [], u_range[0] + rng.uniform(0.0, 0.6)
    k = 0
    while u < u_range[1] - 0.45:
        pool = F.TALL if choices is None else {c: F.TALL[c] for c in choices if c in F.TALL}
        name = rng.choice(sorted(pool))
        builder, wmin, wmax = pool[name]
        w = rng.uniform(wmin, wmax)
        if u + w > u_range[1]:
            w = u_range[1] - u
        limit = min([h for a, b, h in blocked if a < u + w and b > u], default=None)
        if limit is not None:
            low = [c for c in sorted(F.LOW) if choices is None or c in choices]
            if limit < 0.5 or not low:
                u = max(b for a, b, h in blocked if a < u + w and b > u) + 0.1
                continue
            builder, wmin, wmax = F.LOW[rng.choice(low)]
            w = min(w, wmax)
            if w < wmin:
                u += 0.3
                continue
        if w >= wmin:
            kw = {"max_h": limit - 0.05} if limit is not None else {}
            pieces.append(builder(f, u + w / 2, w, pal, rng, f"{prefix}{k}", **kw))
            k += 1
        u += w + rng.uniform(0.05, 0.8)
    return pieces


def picture(f: F.Frame, u: float, w: float, h: float, z: float, pal: Palette, n: str) -> None:
    """A framed picture hanging on the wall, its centre at height ``z``."""
    f.box(f"{n}_frame", (w + 0.06, 0.03, h + 0.06), u, 0.015, z, pal.shared("wood"), 0.005)
    f.box(f"{n}_canvas", (w, 0.01, h), u, 0.035, z, pal.get("picture"))
