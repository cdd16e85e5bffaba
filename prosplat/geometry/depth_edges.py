"""Depth edges: where a pixel-aligned depth map jumps from one surface to another.

Why (issues 68 and 70): a network's depth map is smooth where the scene is not. Across the
silhouette of a wall in front of a field it passes through every depth in between over a few
pixels, and the upsampling from the size the generator matched at to the inputs' size widens
that ramp by the upsampling factor. Each of those pixels becomes a Gaussian at its in-between
depth: together they form a *curtain* hanging from the wall's edge toward the field (or toward
the camera, seen from aside), the streaks and doubled facades of the real-photo sets and the
curtains of dots at 512 px. No surface has those depths.

The remedy here needs no learning. A pixel whose depth changes steeply (more than ``jump``
per pixel of the size the depth was predicted at) both before and after it, in the same
direction along a row or a column, sits inside such a ramp: its depth belongs to no surface.
(The last pixel of a true surface at its silhouette is steep on one side only: its own
surface goes on, so exact depth is left as it is.) Its Gaussian is then dropped (``"drop"``:
made transparent, so the budget removes it and the view's other inputs or the hole fill
show what lies there) or moved onto the nearer of the two surfaces read a little way
along the ramp (``"snap"``). Away from ramps nothing changes, so a smooth surface cannot be
harmed.

On the ray-cast test scene with its depth blurred as a 4x-upsampling generator blurs it
(``tests/geometry/test_depth_edges.py``), the share of target pixels drawn more than 10 %
in front of the truth went from 7.4 % to 0.3 % dropped and 3.0 % snapped, and the filled
views' PSNR from 20.5 to 24.0 dB dropped and 23.8 dB snapped (true depth: 1.0 %, 26.7 dB).
Snapping by colour (the side whose pixel looks more like this one) did worse than by depth
on textured surfaces and is not offered. On the shipped generator's own output it measured
level (6 Blender scenes at 512 px, 7 real sets at 256 px; BENCHMARKS.md, "Depth ramps"):
there the floaters are whole surfaces at a wrong depth, not thin ramps, so it is off by
default (``ProSplat.depth_edges`` None, ``--depth-edges``).

Everything is shifts of ``[V,H,W]`` maps (and one max pool to grow the dropped region).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["EDGE_CHOICES", "EdgeOptions", "depth_edges", "edge_options", "resolve_depth_edges"]


@dataclass(frozen=True)
class EdgeOptions:
    """How the ramps between surfaces are found and what becomes of their Gaussians.

    Attributes:
        jump: the relative depth change per pixel of the *matching* size (the size the
            depth was predicted at) that makes a ramp, before and after the pixel (0.07: 7 %
            from one pixel to the next). A generator spreads a jump between two surfaces
            over about two of its pixels, so a wall in front of a field twice as far changes
            by some 40 % per pixel there; a floor seen at a slant by a few per cent (at 128
            px and 60 degrees of view, 7 % per pixel is a surface within about 4 degrees of
            edge-on).
        remedy: ``"drop"`` makes a ramp pixel's Gaussian transparent; ``"snap"`` moves it
            onto the surface before or after the ramp whose depth is nearer its own.
        grow: ``"drop"`` also drops the pixels within this many matching pixels of a ramp
            (its ends, where the depth is still a few per cent off; 0: the ramp alone).
        reach: ``"snap"`` reads the two surfaces this many matching pixels before and after
            the pixel along the ramp.
    """

    jump: float = 0.07
    remedy: Literal["drop", "snap"] = "drop"
    grow: float = 0.0
    reach: float = 1.0

    def __post_init__(self) -> None:
        if not (self.jump > 0 and math.isfinite(self.jump)):
            raise ValueError(f"EdgeOptions.jump must be a positive number, got {self.jump}")
        if self.remedy not in ("drop", "snap"):
            raise ValueError(f"EdgeOptions.remedy must be 'drop' or 'snap', got {self.remedy!r}")
        if not (self.grow >= 0 and math.isfinite(self.grow)):
            raise ValueError(f"EdgeOptions.grow must be 0 or more, got {self.grow}")
        if not (self.reach > 0 and math.isfinite(self.reach)):
            raise ValueError(f"EdgeOptions.reach must be positive, got {self.reach}")


#: the command line's ``--depth-edges`` values (:func:`edge_options`)
EDGE_CHOICES = ("drop", "snap", "off")


def edge_options(choice: str) -> EdgeOptions | None:
    """``--depth-edges CHOICE`` as ``ProSplat.depth_edges``: "off" is None, "drop" and
    "snap" the default options with that remedy."""
    if choice not in EDGE_CHOICES:
        raise ValueError(f"--depth-edges must be one of {', '.join(EDGE_CHOICES)}, got {choice!r}")
    return None if choice == "off" else EdgeOptions(remedy=choice)


def _pixels(matching_px: float, scale: float) -> int:
    """``matching_px`` pixels of the matching size in input pixels (``scale`` per one), ≥ 1."""
    return max(1, round(matching_px * scale))


def _shift(x: Tensor, dim: int, k: int) -> Tensor:
    """``x`` read ``k`` pixels further along ``dim`` (negative: back), the border repeated."""
    n = x.shape[dim]
    idx = (torch.arange(n, device=x.device) + k).clamp(0, n - 1)
    return x.index_select(dim, idx)


def _log_depth(depth: Tensor) -> tuple[Tensor, Tensor]:
    """(log depth [V,H,W], valid [V,H,W] bool); invalid pixels (≤ 0, not finite) get their
    view's median valid log depth, so a missing depth never reads as a surface at depth 1."""
    valid = (depth > 0) & torch.isfinite(depth)
    log_d = torch.where(valid, depth.clamp_min(1e-12).log(), torch.zeros_like(depth))
    for v in range(log_d.shape[0]):
        if bool(valid[v].any()) and not bool(valid[v].all()):
            log_d[v][~valid[v]] = log_d[v][valid[v]].median()
    return log_d, valid


def _ramps(
    log_d: Tensor, valid: Tensor, options: EdgeOptions, scale: float
) -> tuple[Tensor, Tensor, Tensor]:
    """Where the depth map ramps between two surfaces, and the surfaces.

    A pixel is *between* two surfaces when, along a row or a column, its log depth changes
    by more than ``log(1 + jump)`` over one matching pixel (``scale`` input pixels) both
    before and after it, in the same direction: it sits inside a steep monotone ramp. The
    last pixel of a true surface at its silhouette is steep on one side only (its own surface
    goes on), so exact depth stays as it is. The two surfaces are read ``options.reach``
    matching pixels before and after it along that axis (the axis with the larger jump when
    both qualify).

    Returns (between [V,H,W] bool, the log depth before and after it [V,H,W] each)."""
    limit = math.log1p(options.jump)
    step, reach = _pixels(1.0, scale), _pixels(options.reach, scale)
    between = torch.zeros_like(valid)
    gap = torch.full_like(log_d, -1.0)
    before, after = log_d.clone(), log_d.clone()
    for dim in (-1, -2):
        fwd = _shift(log_d, dim, step) - log_d
        bwd = log_d - _shift(log_d, dim, -step)
        ok = valid & _shift(valid, dim, step) & _shift(valid, dim, -step)
        ramp = ok & (fwd.abs() > limit) & (bwd.abs() > limit) & (fwd * bwd > 0)
        b, a = _shift(log_d, dim, -reach), _shift(log_d, dim, reach)
        jump = (a - b).abs()
        take = ramp & (jump > gap)
        between |= ramp
        gap = torch.where(take, jump, gap)
        before, after = torch.where(take, b, before), torch.where(take, a, after)
    return between, before, after


def depth_edges(depth: Tensor, options: EdgeOptions | None = None, scale: float = 1.0) -> Tensor:
    """[V,H,W] bool: valid pixels inside a steep ramp between two surfaces (:func:`_ramps`),
    the Gaussians of a curtain. ``scale``: input pixels per pixel of the size the depth was
    predicted at. Pixels without a depth (≤ 0 or not finite) are never edges."""
    log_d, valid = _log_depth(depth)
    return _ramps(log_d, valid, options or EdgeOptions(), scale)[0]


@torch.no_grad()
def resolve_depth_edges(
    depth: Tensor, options: EdgeOptions | None = None, scale: float = 1.0
) -> tuple[Tensor, Tensor]:
    """What becomes of the pixels inside ramps between surfaces (:func:`depth_edges`) of
    ``depth`` [V,H,W]: (new depth [V,H,W], dropped [V,H,W] bool).

    ``"drop"``: the depth is unchanged and the ramp pixels (grown by ``options.grow``) are
    dropped. ``"snap"``: each ramp pixel takes the depth of the nearer of the two surfaces
    and nothing is dropped. Other pixels, and pixels without a depth, keep theirs exactly;
    ``scale`` is input pixels per pixel of the size the depth was predicted at (the ramps
    and the reach widen with it)."""
    options = options or EdgeOptions()
    if depth.ndim != 3:
        raise ValueError(f"resolve_depth_edges: depth must be [V,H,W], got {list(depth.shape)}")
    log_d, valid = _log_depth(depth)
    edge, before, after = _ramps(log_d, valid, options, scale)
    if options.remedy == "drop":
        if options.grow > 0:
            r = round(options.grow * scale)
            if r > 0:
                grown = F.max_pool2d(edge.float()[:, None], 2 * r + 1, stride=1, padding=r)
                edge = valid & (grown[:, 0] > 0)
        return depth, edge
    to_before = (log_d - before).abs() <= (after - log_d).abs()
    snapped = torch.where(to_before, before, after).exp().to(depth.dtype)
    return torch.where(edge, snapped, depth), torch.zeros_like(edge)
