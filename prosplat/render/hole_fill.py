"""Filling a render's holes (where no input saw the scene) from the render's own colours.

A feed-forward generator places Gaussians only where some input pixel looked, so a novel
camera sees holes: on the test scenes 7 % of a target's pixels at 64 px, left black by the
rasterizer's default background. Black is the worst answer there: filling them lifts the
generator's raw render by 3.1 / 3.5 / 4.1 dB at 64 / 128 / 256 px (BENCHMARKS.md, "Holes in
the raw render"). What lies in a hole is usually the continuation of what surrounds it (the
floor or wall that runs out of the inputs' view), so the hole is filled by pull-push
(Gortler et al., "The Lumigraph", 1996): an alpha-weighted image pyramid is pulled down
until every level is covered, then each level is composited *over* the level below it on
the way back up. A pixel takes the colour of the nearest covered pixels, blended smoothly
across the hole; a pixel the render covers keeps its colour exactly, and a half-covered
one is completed by the same ``over`` compositing the rasterizer uses for its background.

Nothing is learned and nothing is invented beyond a smooth continuation, so this is a
display choice for raw renders, not geometry: stage 2 gets the render on black with its
alpha, as it was trained (unless its config says ``fill_input``), and the ladder keeps the
unfilled ``generator`` row beside the ``generator filled`` one.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["fill_colour", "fill_holes"]


def fill_holes(rgb: Tensor, alpha: Tensor) -> Tensor:
    """Complete a render composited over black with a pull-push fill of its holes:
    ``rgb + (1 - alpha) · fill_colour(rgb, alpha)``.

    Args and shapes as :func:`fill_colour`; returns rgb's shape: fully covered pixels are
    unchanged, and a render with no coverage at all comes back unchanged (black).
    """
    a = _alpha_like(rgb, alpha)
    return rgb + (1 - a) * fill_colour(rgb, alpha)


def _alpha_like(rgb: Tensor, alpha: Tensor) -> Tensor:
    """alpha reshaped to broadcast against rgb ([1,H,W] or [B,1,H,W]), clamped to [0, 1]."""
    if rgb.ndim not in (3, 4) or rgb.shape[-3] != 3:
        raise ValueError(f"fill_holes: rgb must be [3,H,W] or [B,3,H,W], got {list(rgb.shape)}")
    shape = (*rgb.shape[:-3], 1, *rgb.shape[-2:])
    try:
        return alpha.reshape(shape).to(rgb.dtype).clamp(0, 1)
    except RuntimeError:
        raise ValueError(
            f"fill_holes: alpha {list(alpha.shape)} does not match rgb {list(rgb.shape)}"
        ) from None


def fill_colour(rgb: Tensor, alpha: Tensor) -> Tensor:
    """The colour a pull-push fill gives every pixel from the covered pixels around it.

    Args:
        rgb: [3,H,W] or [B,3,H,W] colour premultiplied by ``alpha``, i.e. composited over a
            black background (what :func:`prosplat.render.render` returns by default).
        alpha: [H,W], [1,H,W] or [B,1,H,W] (or [B,H,W]) coverage in [0, 1].

    Returns:
        [3,H,W] or [B,3,H,W] (not premultiplied): at every pixel the alpha-weighted mean
        colour of the covered pixels nearest it, read from the next-coarser pyramid level,
        so it never leaves the range of the render's own (un-premultiplied) colours; black
        where nothing at all is covered (there is nothing to continue).
    """
    a = _alpha_like(rgb, alpha)
    single = rgb.ndim == 3
    c, a = (rgb[None], a[None]) if single else (rgb, a)  # [B,3,H,W], [B,1,H,W]
    h, w = c.shape[-2:]
    # pull: premultiplied colour and coverage, averaged 2x2 and renormalised so that a
    # block with any coverage becomes (more) opaque: a coarse level holds the mean colour
    # of what was covered below it, and coverage saturates within a few levels
    levels = [(c, a)]
    while max(levels[-1][1].shape[-2:]) > 1:
        pc, pa = levels[-1]
        sc = F.avg_pool2d(pc, 2, ceil_mode=True, count_include_pad=False)  # [B,3,h/2,w/2]
        sa = F.avg_pool2d(pa, 2, ceil_mode=True, count_include_pad=False)  # [B,1,h/2,w/2]
        na = (4 * sa).clamp(max=1)  # coverage: one fully covered child of four suffices
        nc = torch.where(sa > 0, sc * (na / sa.clamp_min(1e-12)), torch.zeros_like(sc))
        levels.append((nc, na))
    # push: from the coarsest level up, each level composited over the one below it
    fill = levels[-1][0]  # [B,3,1,1] (over black when nothing at all is covered)
    for pc, pa in reversed(levels[1:-1]):
        up = F.interpolate(fill, size=pc.shape[-2:], mode="bilinear", align_corners=False)
        fill = pc + (1 - pa) * up
    if len(levels) > 1:
        fill = F.interpolate(fill, size=(h, w), mode="bilinear", align_corners=False)
    else:  # a 1x1 image: nothing around it to continue
        fill = torch.zeros_like(c)
    return fill[0] if single else fill  # [B,3,H,W]
