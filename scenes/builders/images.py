"""Seeded textures drawn with numpy and packed into the .blend as images.

Procedural shader nodes are smooth and statistically alike; drawn images add the other kind
of texture a reconstruction model meets in practice: hard edges, flat colour regions,
text-like marks, tiles. They are packed (``Image.pack``) so a saved .blend is
self-contained, and are small (64-128 px) because they tile over the surfaces.
"""

from __future__ import annotations

import colorsys

import bpy
import numpy as np

PATTERNS: tuple[str, ...] = ("tiles", "stripes", "dots", "blocks", "blobs", "glyphs")


def palette(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` display-referred (sRGB) colours around a random hue, ``[n, 3]`` in [0, 1]."""
    base = rng.uniform()
    cols = []
    for _ in range(n):
        h = (base + rng.normal(0, 0.12)) % 1.0
        cols.append(colorsys.hsv_to_rgb(h, rng.uniform(0.15, 0.7), rng.uniform(0.25, 0.95)))
    return np.asarray(cols, dtype=np.float32)


def _tiles(rng: np.random.Generator, size: int) -> np.ndarray:
    n = int(rng.choice([4, 8]))
    cols = palette(rng, 4)
    idx = rng.integers(0, len(cols), (n, n))
    img = cols[np.kron(idx, np.ones((size // n, size // n), dtype=int))]
    grout = size // n
    img[::grout, :] = img[:, ::grout] = 0.85 * rng.uniform(0.3, 1.0)
    return img


def _stripes(rng: np.random.Generator, size: int) -> np.ndarray:
    cols = palette(rng, 3)
    widths = rng.integers(2, max(3, size // 6), 64)
    band = np.repeat(np.arange(64) % len(cols), widths)[:size]
    band = np.pad(band, (0, size - len(band)), mode="wrap")
    return np.broadcast_to(cols[band][None, :, :], (size, size, 3)).copy()


def _dots(rng: np.random.Generator, size: int) -> np.ndarray:
    cols = palette(rng, 4)
    img = np.broadcast_to(cols[0], (size, size, 3)).copy()
    yy, xx = np.mgrid[0:size, 0:size]
    for _ in range(int(rng.integers(6, 18))):
        cx, cy, r = rng.uniform(0, size, 2).tolist() + [rng.uniform(size / 20, size / 7)]
        dx = np.minimum(abs(xx - cx), size - abs(xx - cx))  # wrap so the image tiles
        dy = np.minimum(abs(yy - cy), size - abs(yy - cy))
        img[dx**2 + dy**2 < r**2] = cols[int(rng.integers(1, len(cols)))]
    return img


def _blocks(rng: np.random.Generator, size: int) -> np.ndarray:
    cols = palette(rng, 5)
    img = np.broadcast_to(cols[0], (size, size, 3)).copy()
    for _ in range(int(rng.integers(5, 14))):
        x0, y0 = rng.integers(0, size, 2)
        w, h = rng.integers(size // 10, size // 2, 2)
        img[y0 : y0 + h, x0 : x0 + w] = cols[int(rng.integers(1, len(cols)))]
    return img


def _blobs(rng: np.random.Generator, size: int) -> np.ndarray:
    cols = palette(rng, 3)
    coarse = rng.uniform(0, 1, (8, 8))
    # periodic bilinear upsampling of coarse value noise -> smooth tileable blobs
    t = np.arange(size) * 8 / size
    i0 = np.floor(t).astype(int)
    f = t - i0
    i1 = (i0 + 1) % 8
    rows = coarse[i0] * (1 - f)[:, None] + coarse[i1] * f[:, None]
    val = rows[:, i0] * (1 - f)[None, :] + rows[:, i1] * f[None, :]
    k = np.clip(val * (len(cols) - 1), 0, len(cols) - 1.001)
    lo = np.floor(k).astype(int)
    w = (k - lo)[..., None]
    return cols[lo] * (1 - w) + cols[lo + 1] * w


def _glyphs(rng: np.random.Generator, size: int) -> np.ndarray:
    paper, ink = palette(rng, 2)
    paper = np.maximum(paper, 0.7)
    ink = ink * 0.4
    img = np.broadcast_to(paper, (size, size, 3)).copy()
    cell = max(size // 16, 4)
    for y in range(1, size // cell - 1, 2):
        for x in range(1, size // cell - 1):
            if rng.uniform() < 0.8:
                bits = rng.uniform(0, 1, (cell - 1, cell - 2)) < 0.45
                img[y * cell : y * cell + cell - 1, x * cell : x * cell + cell - 2][bits] = ink
    return img


_DRAW = {
    "tiles": _tiles,
    "stripes": _stripes,
    "dots": _dots,
    "blocks": _blocks,
    "blobs": _blobs,
    "glyphs": _glyphs,
}


def draw(pattern: str, rng: np.random.Generator, size: int = 64) -> np.ndarray:
    """Draw ``pattern`` as an ``[size, size, 3]`` float32 sRGB image (row 0 = bottom)."""
    return np.clip(_DRAW[pattern](rng, size), 0.0, 1.0).astype(np.float32)


def packed_image(name: str, rgb: np.ndarray) -> bpy.types.Image:
    """Create a packed 8-bit sRGB image datablock holding ``rgb`` ``[H, W, 3]``."""
    h, w = rgb.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=False)
    rgba = np.concatenate([rgb, np.ones((h, w, 1), np.float32)], axis=2)
    img.pixels.foreach_set(rgba.ravel())
    img.pack()
    return img
