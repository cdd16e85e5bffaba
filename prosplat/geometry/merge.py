"""Merge flat 2x2 pixel blocks of pixel-aligned Gaussians into one Gaussian each.

A pixel-aligned generator places one Gaussian per input pixel whatever the image shows: a
white wall at 512 px costs as many Gaussians as a bookshelf. Where four neighbouring pixels
of one view agree (same colour, same depth, same opacity), their four Gaussians carry one
Gaussian's worth of information, so :func:`merge_flat` replaces them by one, and the count
follows the image's detail instead of its pixel count.

A 2x2 block (even row and column origin, in the grid of the depth maps the Gaussians were
placed on) is merged when

* all four of its pixels survived the budget (a block with a hole is an edge of something:
  duplicates dropped there belong to another view);
* the colours (SH DC) of its four Gaussians span at most ``color_tol`` in every channel
  (RGB units, 0-1);
* its four depths span at most ``depth_tol`` times the nearest of them (a depth edge is not
  merged, so no Gaussian is stretched across two surfaces);
* its four opacities span at most ``opacity_tol``.

The four become one by **moment matching** the opacity-weighted mixture: weights
``w_i = o_i / Σo``, mean ``μ = Σ w_i μ_i``, covariance ``Σ w_i (Σ_i + (μ_i - μ)(μ_i - μ)ᵀ)``,
SH the weighted mean, opacity the mean opacity. Opacities are the weights because a
Gaussian's share of the picture is its opacity (a faint one should not pull the merged one
towards it); the blocks merged have alike opacities, so this is close to equal weights
anyway. The covariance goes back to quaternion + scales by a symmetric eigendecomposition
(``torch.linalg.eigh``, float64), its eigenvector matrix made a proper rotation (det +1).

Moment matching alone keeps the four's spread but not what they paint: the rasterizer dilates
every Gaussian (0.3 px²), so four small Gaussians a pixel apart cover their block while the
one merged Gaussian is dilated once and lets the background through. With ``cover`` (the
default) its two widest axes are then grown until its opacity x screen area in its own view
equals the four's sum (:func:`_keep_coverage`): a merged surface is the unmerged lattice
scaled by two.

``levels=2`` then merges 2x2 groups of merged blocks (4x4 pixels) by the same rule, the
tolerances judged over all 16 original pixels (ranges of colour, depth and opacity are
carried up per block), so a 4x4 merge never happens where a 2x2 one would not.

Everything is vectorised torch: one gather per level, no per-Gaussian Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import SH_C0, Gaussians
from prosplat.core.rotations import rotmat_to_quat
from prosplat.geometry.budget import check_depth_maps, importance
from prosplat.render.projection import quat_to_rotmat

__all__ = ["MergeOptions", "merge_flat", "moment_match"]


@dataclass(frozen=True)
class MergeOptions:
    """When :func:`merge_flat` merges a 2x2 block (see the module docstring).

    Attributes:
        color_tol: the most the four colours may span per channel (RGB, 0-1).
        depth_tol: the most the four depths may span, relative to the nearest.
        opacity_tol: the most the four opacities may span.
        levels: 1 merges 2x2 pixel blocks; 2 also merges 2x2 groups of merged blocks.
        cover: grow each merged Gaussian to the screen coverage of its four in their view
            (:func:`_keep_coverage`); False: plain moment matching.
        above_scale: merge only where the Gaussians were placed at more than this many times
            the generator's matching size (:meth:`prosplat.ProSplat._pruned` checks it; 0: at
            any size). At the matching size a pixel is the finest the generator resolves.

    The defaults were measured at 512 px (Gaussians at 4x the 128-px matching size) on the
    6 test scenes, filled raw views of 4 targets each: 951k -> 620k Gaussians, PSNR 19.16
    -> 19.21 dB, LPIPS 0.3345 -> 0.3341. ``color_tol=0.04, depth_tol=0.02`` halves the count
    (447k) but costs LPIPS (+0.002) and floaters (10.7% -> 13.8%); ``levels=2`` removed only
    another ~10% at a further LPIPS cost (one scene, plain moment matching).
    """

    color_tol: float = 0.02
    depth_tol: float = 0.01
    opacity_tol: float = 0.1
    levels: int = 1
    above_scale: float = 1.0
    cover: bool = True

    def check(self) -> None:
        for name in ("color_tol", "depth_tol", "opacity_tol", "above_scale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (math.isfinite(value) and value >= 0):
                raise ValueError(f"MergeOptions.{name} must be a finite number >= 0, got {value!r}")
        if self.levels not in (1, 2):
            raise ValueError(f"MergeOptions.levels must be 1 or 2, got {self.levels!r}")


def moment_match(g: Gaussians, groups: Tensor) -> Gaussians:
    """One Gaussian per row of ``groups [B,K]`` (indices into ``g``): the opacity-weighted
    moment match of those K Gaussians (mean, covariance, SH; opacity their mean). Computed in
    float64, returned in ``g``'s dtype; ``views`` from the first of each group."""
    dt = g.dtype
    f64 = torch.float64
    means = g.means[groups].to(f64)  # [B,K,3]
    o = g.opacities[groups].to(f64)  # [B,K]
    w = o / o.sum(1, keepdim=True).clamp_min(1e-12)  # [B,K]
    zero = o.sum(1, keepdim=True) <= 1e-12  # all transparent: equal weights
    w = torch.where(zero, torch.full_like(w, 1.0 / groups.shape[1]), w)
    mu = (w[..., None] * means).sum(1)  # [B,3]
    rot = quat_to_rotmat(g.quats[groups].reshape(-1, 4).to(f64)).reshape(*groups.shape, 3, 3)
    s2 = g.scales[groups].to(f64) ** 2  # [B,K,3]
    cov_i = (rot * s2[..., None, :]) @ rot.transpose(-1, -2)  # [B,K,3,3] R S² Rᵀ
    d = means - mu[:, None]  # [B,K,3]
    cov_i = cov_i + d[..., :, None] * d[..., None, :]
    cov = (w[..., None, None] * cov_i).sum(1)  # [B,3,3]
    cov = 0.5 * (cov + cov.transpose(-1, -2))
    evals, evecs = torch.linalg.eigh(cov)  # ascending, evecs [B,3,3] columns
    flip = torch.linalg.det(evecs) < 0  # a reflection: make it a proper rotation
    evecs = torch.where(flip[:, None, None], evecs * evecs.new_tensor([1.0, 1.0, -1.0]), evecs)
    quats = rotmat_to_quat(evecs)  # [B,4]
    scales = evals.clamp_min(0).sqrt()  # [B,3]
    sh = (w[..., None, None] * g.sh[groups].to(f64)).sum(1)  # [B,K_sh,3]
    views = None if g.views is None else g.views[groups[:, 0]]
    return Gaussians.trusted(
        mu.to(dt), quats.to(dt), scales.to(dt), o.mean(1).to(dt), sh.to(dt), views
    )


def _alike(lo: Tensor, hi: Tensor, tol: float) -> Tensor:
    """[B] bool: ``hi - lo`` within ``tol`` over every trailing channel (lo, hi [B,4,...])."""
    span = hi.amax(1) - lo.amin(1)  # [B,...]
    return (span <= tol).reshape(span.shape[0], -1).all(1)


def _rows(x: Tensor, idx: Tensor) -> Tensor:
    """[V,h,w,4,...] block grid -> [B,4,...]: the blocks at flat indices ``idx [B]``."""
    return x.reshape(-1, *x.shape[3:])[idx]


def _blocks(x: Tensor) -> Tensor:
    """[V,H,W,...] -> [V,H/2,W/2,4,...]: the 4 cells of each 2x2 block (H, W even), in the
    order top-left, top-right, bottom-left, bottom-right."""
    v, h, w = x.shape[:3]
    rest = x.shape[3:]
    x = x.reshape(v, h // 2, 2, w // 2, 2, *rest).transpose(2, 3)
    return x.reshape(v, h // 2, w // 2, 4, *rest)


@torch.no_grad()
def merge_flat(
    gaussians: Gaussians,
    keep: Tensor,
    depths: Tensor,
    cameras: list[Camera],
    options: MergeOptions | None = None,
) -> tuple[Gaussians, Tensor, dict[str, int]]:
    """Merge the flat 2x2 blocks of pixel-aligned Gaussians (see the module docstring).

    Args:
        gaussians: the N survivors of :func:`prosplat.geometry.budget.prune_pixel_aligned`,
            in its order (view-major, row-major).
        keep: [V*H*W] bool, its mask: which pixel each survivor came from.
        depths: [V,H,W] the depth maps the Gaussians were placed on (<= 0 or non-finite: no
            surface, never merged).
        cameras: the V cameras of those maps (checked against their size).
        options: the tolerances (default :class:`MergeOptions`).

    Returns:
        The merged Gaussians (each merged one where its block's top-left Gaussian was, so the
        order stays view-major), their view index [M], and counts: ``before``, ``after``,
        ``blocks`` (2x2 blocks merged), ``blocks4`` (of those, 4x4 groups merged again).
    """
    options = MergeOptions() if options is None else options
    options.check()
    check_depth_maps(depths, cameras)
    v, h, w = depths.shape
    if not isinstance(keep, Tensor) or keep.dtype != torch.bool or keep.shape != (v * h * w,):
        raise ValueError(f"keep must be a bool [V*H*W={v * h * w}] tensor (the budget's mask)")
    n = len(gaussians)
    if int(keep.sum()) != n:
        raise ValueError(f"keep marks {int(keep.sum())} pixels but there are {n} Gaussians")
    device = gaussians.device
    keep = keep.to(device)
    stats = {"before": n, "after": n, "blocks": 0, "blocks4": 0}
    pixel_view = torch.arange(v, device=device).repeat_interleave(h * w)  # [V*H*W]
    if n == 0:
        return gaussians, pixel_view[keep], stats

    # per pixel: its survivor's index (-1: none), cropped to even sides
    slot = torch.full((v * h * w,), -1, dtype=torch.long, device=device)
    slot[keep] = torch.arange(n, device=device)
    h2, w2 = h // 2 * 2, w // 2 * 2
    slot = slot.reshape(v, h, w)[:, :h2, :w2]  # [V,h2,w2]
    d = depths.to(device=device, dtype=torch.float64)[:, :h2, :w2]
    rgb = (gaussians.sh[:, 0].to(torch.float64) * SH_C0).detach()  # [N,3] colour - 0.5
    op = gaussians.opacities.detach().to(torch.float64)  # [N]

    ok = slot >= 0
    surface = torch.isfinite(d) & (d > 0)
    safe = slot.clamp_min(0)
    # per cell: (lo, hi) of colour [..,3], depth, opacity; a cell is a pixel at level 1
    c_lo = c_hi = rgb[safe]  # [V,h2,w2,3]
    d_lo = d_hi = d
    o_lo = o_hi = op[safe]
    alive = ok & surface  # [V,h2,w2] the cell may merge
    g = gaussians
    drop = torch.zeros(n, dtype=torch.bool, device=device)
    for level in range(options.levels):
        if alive.shape[1] < 2 or alive.shape[2] < 2:
            break
        hh, ww = alive.shape[1] // 2 * 2, alive.shape[2] // 2 * 2
        crop = (slice(None), slice(0, hh), slice(0, ww))
        a_b = _blocks(alive[crop])  # [V,hh/2,ww/2,4]
        s_b = _blocks(slot[crop])
        cl, ch = _blocks(c_lo[crop]), _blocks(c_hi[crop])  # [V,hh/2,ww/2,4,3]
        dl, dh = _blocks(d_lo[crop]), _blocks(d_hi[crop])
        ol, oh = _blocks(o_lo[crop]), _blocks(o_hi[crop])
        flat = a_b.all(-1)  # [V,hh/2,ww/2]
        idx = torch.nonzero(flat.reshape(-1)).squeeze(1)  # [B'] candidate blocks
        dmin = _rows(dl, idx).amin(1)  # [B']
        merge = (
            _alike(_rows(cl, idx), _rows(ch, idx), options.color_tol)
            & (_rows(dh, idx).amax(1) - dmin <= options.depth_tol * dmin)
            & _alike(_rows(ol, idx), _rows(oh, idx), options.opacity_tol)
        )
        idx = idx[merge]  # [B] blocks merged
        groups = _rows(s_b, idx)  # [B,4] indices into g
        if idx.numel():
            merged = moment_match(g, groups)
            if options.cover:
                merged = _keep_coverage(g, groups, merged, pixel_view[keep], cameras)
            first = groups[:, 0]
            g = _put(g, first, merged)
            drop[groups[:, 1:].reshape(-1)] = True
        stats["blocks" if level == 0 else "blocks4"] = int(idx.numel())
        # the next level's cells: merged blocks, with ranges over all their pixels
        mask = torch.zeros_like(flat).reshape(-1)
        mask[idx] = True
        alive = mask.reshape(flat.shape)
        slot = s_b[..., 0]
        c_lo, c_hi = cl.amin(3), ch.amax(3)
        d_lo, d_hi = dl.amin(3), dh.amax(3)
        o_lo, o_hi = ol.amin(3), oh.amax(3)
        if not idx.numel():
            break
    out = g[~drop]
    stats["after"] = len(out)
    view_index = pixel_view[keep][~drop]
    return out, view_index, stats


def _keep_coverage(
    g: Gaussians, groups: Tensor, merged: Gaussians, view_index: Tensor, cameras: list[Camera]
) -> Gaussians:
    """``merged`` (one per row of ``groups [B,4]``) with its two widest axes (the surface's)
    grown until it paints, in its own view, what its four Gaussians painted: its opacity x
    screen area (the rasterizer's 1σ ellipse with its 0.3 px² dilation,
    :func:`prosplat.geometry.budget.importance`) equal to the sum of theirs. Never shrunk.

    Why: moment matching keeps the mixture's spread, not its coverage. The rasterizer dilates
    every Gaussian to at least about a pixel, so four small ones a pixel apart together cover
    their 2x2 block, while the one moment-matched Gaussian at their mean opacity is dilated
    once and covers about a third of it. A surface of merged blocks is then a lattice twice
    as coarse whose Gaussians are not twice as wide: it lets the background through. Grown
    this way it is the same lattice scaled by two (for equal Gaussians: area x4, opacity
    kept). On a slanted plane of one-per-pixel Gaussians (footprints 0.3-1 px, opacities
    0.3-0.95) the merged render was 15-38 dB from the unmerged one with the mean opacity and
    35-53 dB grown (the inputs' view and a novel one; tests/geometry/test_merge.py)."""
    views = view_index[groups[:, 0]]  # [B] the block's view
    members = importance(g[groups.reshape(-1)], view_index[groups.reshape(-1)], cameras)
    painted = members.reshape(groups.shape).sum(1)  # [B] Σ o_i · area_i (px²)
    f64 = torch.float64
    scales = merged.scales.to(f64)  # [B,3]
    axes = scales.argsort(1)[:, 1:]  # [B,2] the two widest axes
    for _ in range(3):  # the dilation makes area nonlinear in the scales: a few fixed-point steps
        now = importance(replace(merged, scales=scales.to(merged.dtype)), views, cameras)  # [B]
        grow = torch.where(now > 0, painted / now.clamp_min(1e-30), 1.0).clamp(1.0, 16.0).sqrt()
        if bool((grow <= 1.0 + 1e-3).all()):
            break
        scales = scales.scatter(1, axes, scales.gather(1, axes) * grow[:, None])
    return replace(merged, scales=scales.to(merged.dtype))


def _put(g: Gaussians, at: Tensor, new: Gaussians) -> Gaussians:
    """``g`` with the Gaussians at indices ``at [B]`` replaced by ``new`` (B Gaussians)."""
    parts = {}
    for name in Gaussians.PARAMS:
        x = getattr(g, name).clone()
        x[at] = getattr(new, name)
        parts[name] = x
    return Gaussians.trusted(**parts, views=g.views)
