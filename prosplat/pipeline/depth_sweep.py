"""A local plane sweep: the generator's depth moved to where the input views match best.

The generator's depth is learned from a few hundred rendered scenes and is often right in
shape but off by 10-30 % (median input-depth AbsRel 0.15 at 128 px). Classical stereo has the
opposite profile: precise where a window matches uniquely, lost where it does not (a global
sweep over near-far finds the wrong peak on repeated or flat texture). Searching only a
narrow band around the generator's depth takes both: for every input pixel, ``candidates``
depths from ``depth·e^-span`` to ``depth·e^+span`` are scored by ZNCC against the other input
views (:func:`prosplat.geometry.matching.zncc_cost`, the plane-sweep baseline's cost,
averaged over the source views that match best so that an occluded view does not vote), and
the winner replaces the generator's depth where its match is unique enough
(``min_confidence``) and not at the edge of the band (a peak at the edge means the truth lies
outside it, or nowhere).

The generator's Gaussians are pixel-aligned: Gaussian ``v·H·W + r·W + c`` lies on the ray of
pixel (c, r) of view v at that pixel's depth. :func:`snap_output` slides each along its ray to
the new depth and scales it by the depth ratio, so it covers the same pixel footprint and its
own view renders as before; only where the other views see it changes.

After the local sweep, one factor for the whole scene is chosen (:func:`scale_search`): all
Gaussians slid along their rays by each of ``scale_candidates`` factors, every input view is
re-rendered from all of them, and the factor whose renders match the inputs best wins. A
view's own Gaussians draw it at any depth, so what the renders measure is where the *other*
views' Gaussians land, occlusion included: a whole-scene match that still works where the
windows of the local sweep match nothing (a bias of the generator over a textureless wall).

    >>> out = snap_output(out, images, cameras)  # a GeneratorOutput, B = 1
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.data.scene import resize_views
from prosplat.generator.output import GeneratorOutput
from prosplat.geometry.budget import prune_pixel_aligned
from prosplat.geometry.matching import winner_take_all, zncc_cost
from prosplat.geometry.pixel_gaussians import slide_gaussians
from prosplat.pipeline.refine import photometric_loss
from prosplat.render import render

__all__ = [
    "DepthSweepOptions",
    "scale_search",
    "slide_along_rays",
    "snap_output",
    "sweep_depths",
]


@dataclass(frozen=True)
class DepthSweepOptions:
    """The band searched around each depth and when its winner is taken.

    Attributes:
        span: candidates run from ``depth·exp(-span)`` to ``depth·exp(span)`` (0.3: ±30 %).
        candidates: how many, evenly spaced in log depth (25 at span 0.3: 2.5 % apart,
            and the parabola through the winner's neighbours refines within a step).
        best_views: source views averaged per pixel, the best-matching ones (None: half
            of them rounded up, so that with 4 inputs 2 of the 3 others vote).
        min_confidence: the winner replaces the depth only where the plane sweep's
            confidence (margin to the second-best peak times the ZNCC) exceeds this.
        smooth: σ of a Gaussian, as a fraction of the image height, over which the log depth
            corrections are averaged, weighted by confidence (0: each pixel keeps its own
            winner). Per-pixel winners are noisy, and neighbours moved apart open cracks that
            other views see through; the generator's errors are smooth over a surface.
        max_height: images taller than this are swept at this height (antialiased) and the
            correction is upsampled: a 256-px sweep costs 4-5x a 128-px one and the smoothed
            correction has no detail that needs it (None: always at the images' size).
        min_views: fewer input views than this are left as the generator made them. With 2
            one other view votes, and on the 24 test scenes at 64 px the sweep gained nothing
            there (+0.02 dB enhanced, LPIPS +0.002; 6 views: +0.22 dB), so it saves the time.
        scale_span, scale_candidates: the scene-wide factors :func:`scale_search` tries run
            from ``exp(-scale_span)`` to ``exp(scale_span)``, evenly in log (5 at 0.2: 10 %
            apart; 9 did no better on the validation or test scenes and cost 1.6-1.8x the
            search, BENCHMARKS "The depth sweep's scene-wide factor"); fewer than 2
            candidates turn the search off.
        scale_height: the search renders and compares the views at most this high (the
            Gaussians are the same; only where they land matters, not detail).

    The defaults are the best of those tried on the 8 validation scenes (data/val128) at 64
    and 128 px with generator v7 and stage 2 v16 (BENCHMARKS.md, "Depth sweep"); the factor
    count with generator v12 and stage 2 v19.
    """

    span: float = 0.3
    candidates: int = 25
    best_views: int | None = None
    min_confidence: float = 0.4
    smooth: float = 0.03
    max_height: int | None = 128
    min_views: int = 3
    scale_span: float = 0.2
    scale_candidates: int = 5
    scale_height: int = 64

    def searches_scale(self, n_views: int) -> bool:
        """Whether :func:`scale_search` looks for a scene-wide factor with ``n_views`` inputs
        (at least 2 candidates and :attr:`min_views` views, as the local sweep)."""
        return self.scale_candidates >= 2 and n_views >= self.min_views

    def check(self) -> None:
        if not (math.isfinite(self.span) and 0 < self.span <= 2):
            raise ValueError(f"DepthSweepOptions.span must be in (0, 2], got {self.span}")
        if int(self.candidates) != self.candidates or self.candidates < 3:
            raise ValueError(
                f"DepthSweepOptions.candidates must be an integer >= 3, got {self.candidates}"
            )
        if self.best_views is not None and (
            int(self.best_views) != self.best_views or self.best_views < 1
        ):
            raise ValueError(
                f"DepthSweepOptions.best_views must be None or an integer >= 1, got "
                f"{self.best_views}"
            )
        if not (math.isfinite(self.smooth) and 0 <= self.smooth <= 1):
            raise ValueError(f"DepthSweepOptions.smooth must be in [0, 1], got {self.smooth}")
        if self.max_height is not None and (
            int(self.max_height) != self.max_height or self.max_height < 32
        ):
            raise ValueError(
                f"DepthSweepOptions.max_height must be None or an integer >= 32, got "
                f"{self.max_height}"
            )
        if int(self.min_views) != self.min_views or self.min_views < 2:
            raise ValueError(
                f"DepthSweepOptions.min_views must be an integer >= 2, got {self.min_views}"
            )
        if not (math.isfinite(self.scale_span) and 0 < self.scale_span <= 1):
            raise ValueError(
                f"DepthSweepOptions.scale_span must be in (0, 1], got {self.scale_span}"
            )
        if int(self.scale_candidates) != self.scale_candidates or self.scale_candidates < 0:
            raise ValueError(
                "DepthSweepOptions.scale_candidates must be an integer >= 0 (< 2: off), got "
                f"{self.scale_candidates}"
            )
        if int(self.scale_height) != self.scale_height or self.scale_height < 16:
            raise ValueError(
                f"DepthSweepOptions.scale_height must be an integer >= 16, got {self.scale_height}"
            )
        if not (0 <= self.min_confidence < 1):
            raise ValueError(
                f"DepthSweepOptions.min_confidence must be in [0, 1), got {self.min_confidence}"
            )


@torch.no_grad()
def sweep_depths(
    images: Tensor,
    cameras: list[Camera],
    depths: Tensor,
    options: DepthSweepOptions | None = None,
) -> tuple[Tensor, Tensor]:
    """The depth maps ``depths [V,H,W]`` of ``images [V,3,H,W]`` moved to the best match
    within the band (:class:`DepthSweepOptions`).

    Returns:
        new depths [V,H,W] (the given depth where nothing better was found) and moved [V,H,W]
        bool, the pixels whose depth was replaced (with ``smooth`` > 0 every pixel with a
        depth: the smoothed correction reaches all of them, fading to 0 where nothing near
        matched). A single view has nothing to match and comes back unchanged.
    """
    options = DepthSweepOptions() if options is None else options
    options.check()
    v, _, h, w = images.shape
    if tuple(depths.shape) != (v, h, w):
        raise ValueError(f"depths must be [V,H,W] = [{v},{h},{w}], got {list(depths.shape)}")
    if len(cameras) != v:
        raise ValueError(f"one camera per image: got {len(cameras)} cameras for {v} images")
    if v < options.min_views:  # too little to match against (check() keeps it >= 2)
        return depths.clone(), torch.zeros(v, h, w, dtype=torch.bool, device=depths.device)
    top = options.max_height
    if top is None or h <= top:
        log_f, take = _corrections(images, cameras, depths, options)
    else:  # sweep a smaller copy; the correction is smooth, so it is upsampled
        small, small_cams = resize_views(images, cameras, int(top))
        size = tuple(small.shape[-2:])
        small_depths = F.interpolate(depths[:, None], size=size, mode="nearest")[:, 0]
        log_f, take = _corrections(small, small_cams, small_depths, options)
        log_f = F.interpolate(log_f[:, None], size=(h, w), mode="bilinear", align_corners=False)
        take = F.interpolate(take[:, None].float(), size=(h, w), mode="nearest")[:, 0] > 0.5
        log_f, take = log_f[:, 0], take & (depths > 0)
    new = torch.where(take, (depths.to(torch.float64) * torch.exp(log_f)).to(depths.dtype), depths)
    return new, take


def _corrections(
    images: Tensor, cameras: list[Camera], depths: Tensor, options: DepthSweepOptions
) -> tuple[Tensor, Tensor]:
    """[V,H,W] log depth corrections (float64) and [V,H,W] where they apply, at the images'
    size (:func:`sweep_depths`)."""
    v, _, h, w = images.shape
    best_views = options.best_views or math.ceil((v - 1) / 2)
    k = int(options.candidates)
    log_step = torch.linspace(-options.span, options.span, k, dtype=torch.float64)
    factors = torch.exp(log_step).to(device=depths.device)  # [K]
    images = images.to(torch.float32)
    out = torch.zeros(v, h, w, dtype=torch.float64, device=depths.device)
    where = torch.zeros(v, h, w, dtype=torch.bool, device=depths.device)
    for i in range(v):
        base = depths[i].to(torch.float64).clamp_min(1e-6)  # [H,W]
        cand = base[None] * factors[:, None, None]  # [K,H,W]
        cost = zncc_cost(images, cameras, i, cand, best_views=best_views)  # [K,H,W]
        pos, conf = winner_take_all(cost)  # [H,W] fractional index, confidence
        inside = (pos > 0.5) & (pos < k - 1.5)  # not at the band's edge
        take = inside & (conf > options.min_confidence) & (depths[i] > 0)
        log_f = -options.span + pos.to(torch.float64) * (2 * options.span / (k - 1))
        log_f = torch.where(take, log_f, torch.zeros_like(log_f))
        if options.smooth > 0:
            weight = torch.where(take, conf.to(torch.float64), torch.zeros_like(log_f))
            sigma = options.smooth * h
            num, den = _blur(weight * log_f, sigma), _blur(weight, sigma)
            # where little was matched nearby the correction fades out toward 0
            log_f = num / (den + 0.05)
            take = depths[i] > 0
        out[i], where[i] = log_f, take
    return out, where


def _blur(x: Tensor, sigma: float) -> Tensor:
    """[H,W] blurred by a Gaussian of ``sigma`` px (separable, zero-padded: the weights are
    blurred the same way, so the border does not pull toward 0 in their ratio)."""
    radius = max(1, int(math.ceil(3 * sigma)))
    t = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    y = F.conv2d(x[None, None], k.view(1, 1, 1, -1), padding=(0, radius))
    return F.conv2d(y, k.view(1, 1, -1, 1), padding=(radius, 0))[0, 0]


def snap_output(
    out: GeneratorOutput,
    images: Tensor,
    cameras: list[Camera],
    options: DepthSweepOptions | None = None,
) -> GeneratorOutput:
    """``out`` (one scene, its Gaussians pixel-aligned with ``images [V,3,H,W]``) with each
    input pixel's depth swept (:func:`sweep_depths`) and its Gaussian slid along its ray to
    the new depth, scaled by the depth ratio (so its footprint in its own view is kept)."""
    if out.batch_size != 1:
        raise ValueError(f"snap_output takes one scene (B = 1), got B = {out.batch_size}")
    depths = out.depths[0]  # [V,H,W]
    if tuple(depths.shape[-2:]) != tuple(images.shape[-2:]):
        raise ValueError(
            f"the generator's depth maps are {list(depths.shape[-2:])} but the images are "
            f"{list(images.shape[-2:])}: sweep the images its Gaussians were placed at"
        )
    options = DepthSweepOptions() if options is None else options
    images = images.to(depths.device)
    new, _ = sweep_depths(images, cameras, depths.detach(), options)
    out = slide_along_rays(out, cameras, new)
    if options.searches_scale(len(cameras)):
        # scored on what the pipeline keeps: one copy of each surface seen by several views
        _, keep, _ = prune_pixel_aligned(out.gaussians(0).detach(), out.depths[0], cameras)
        factor, _ = scale_search(out, images, cameras, options, keep=keep)
        if factor != 1.0:
            out = slide_along_rays(out, cameras, out.depths[0] * factor)
    return out


@torch.no_grad()
def scale_search(
    out: GeneratorOutput,
    images: Tensor,
    cameras: list[Camera],
    options: DepthSweepOptions | None = None,
    keep: Tensor | None = None,
) -> tuple[float, list[tuple[float, float]]]:
    """The scene-wide depth factor whose Gaussians re-render the input views best.

    For each candidate factor f (:class:`DepthSweepOptions` ``scale_span``,
    ``scale_candidates``) every Gaussian of ``out`` (one scene, pixel-aligned with ``images
    [V,3,H,W]``) is slid along its ray to f times its depth (:func:`slide_along_rays`), each
    input camera is rendered from all of them at most ``scale_height`` high (from every
    stride-th pixel's Gaussian, grown by the stride: what a render that small can show),
    and the mean photometric loss against the inputs (refinement's L1 + SSIM) scores f.
    Ties go to the factor nearest 1; with the search off (fewer than 2 candidates, or fewer
    than ``min_views`` views) the factor is 1. ``keep`` [N] bool: only these Gaussians are rendered
    (the budget's survivors, :func:`prosplat.geometry.budget.prune_pixel_aligned`; None: all). With
    every view's copy of a surface kept, each view's own copy covers its pixels whatever the
    factor and the renders say less (on the 8 validation scenes at 64 px, +0.06 dB enhanced
    against +0.2 with the pruned set).

    Why: the generator's depth errs by a scene-wide factor as well as locally (v7's swept
    depth lies a median 5 % too near on the test scenes, near-far scenes 74 %), and the local
    sweep cannot see that where its windows match nothing; rendering can, because each
    view's colours must land on the other views' pixels. On the test scenes the enhanced
    views gain +0.15 / +0.09 / +0.03 dB at 64 / 128 / 256 px (BENCHMARKS.md, "A scene-wide
    depth factor"). Refinement starts from it too: with generator v7 the fox photos refined
    0.6 dB worse from the scaled depth, with v16 they are level and the near-far scene no
    longer loses to one pass (BENCHMARKS.md, "Refinement from the one-pass Gaussians").

    Returns:
        the winning factor and ``[(factor, loss), ...]`` for every candidate.
    """

    options = DepthSweepOptions() if options is None else options
    options.check()
    v, _, h, w = images.shape
    if not options.searches_scale(v):
        return 1.0, [(1.0, math.nan)]
    if len(cameras) != v:
        raise ValueError(f"one camera per image: got {len(cameras)} cameras for {v} images")
    if tuple(out.depths.shape[-2:]) != (h, w):
        raise ValueError(
            f"the output's depth maps are {list(out.depths.shape[-2:])} but the images are "
            f"[{h}, {w}]: search with the images its Gaussians were placed at"
        )
    small, small_cams = resize_views(images.float(), list(cameras), min(h, options.scale_height))
    # Rendered this small, one Gaussian per `stride` x `stride` input pixels carries all the
    # renders can show: every stride-th row and column of each view, each grown by the
    # stride to cover its neighbours (a 256-px view's 65,536 Gaussians become 4,096).
    stride = max(1, h // small.shape[-2])
    rows = torch.arange(0, h, stride)
    cols = torch.arange(0, w, stride)
    pix = (rows[:, None] * w + cols[None, :]).reshape(-1)  # [P] pixels kept per view
    idx = (torch.arange(v)[:, None] * (h * w) + pix[None, :]).reshape(-1).to(out.means.device)
    if keep is not None:
        if keep.shape != (out.means.shape[1],):
            raise ValueError(f"keep must be [N] = [{out.means.shape[1]}], got {list(keep.shape)}")
        idx = idx[keep.to(idx.device)[idx]]
    g = out.gaussians(0).detach().to(dtype=torch.float32)[idx]
    g = g.with_scale_factor(stride)
    view_index = torch.div(idx, h * w, rounding_mode="floor")  # [M] each one's own view
    backend = "cpu-fused" if g.means.device.type == "cpu" else "auto"
    k = int(options.scale_candidates)
    logs = torch.linspace(-options.scale_span, options.scale_span, k, dtype=torch.float64)
    scored = []
    for log_f in logs.tolist():
        f = math.exp(log_f)
        gf = slide_gaussians(g, view_index, cameras, f)
        loss = sum(
            float(photometric_loss(render(gf, cam, None, backend).rgb.clamp(0, 1), img))
            for cam, img in zip(small_cams, small.to(g.means.device))
        )
        scored.append((f, loss / v))
    best = min(scored, key=lambda fl: (fl[1], abs(math.log(fl[0]))))[0]
    return best, scored


def slide_along_rays(
    out: GeneratorOutput, cameras: list[Camera], depths: Tensor
) -> GeneratorOutput:
    """``out`` (one scene, pixel-aligned) with pixel (c, r) of view v's Gaussian moved along
    its ray from ``out.depths`` to ``depths [V,H,W]``: its mean scaled about the camera's
    centre and its scales by the same ratio. Under the rasterizer's perspective Jacobian
    (∝ 1/z) the Gaussian then projects to the same 2D footprint in its own view."""
    old = out.depths[0]  # [V,H,W]
    if tuple(depths.shape) != tuple(old.shape):
        raise ValueError(f"depths must be {list(old.shape)}, got {list(depths.shape)}")
    v, h, w = old.shape
    old_d = old.detach()
    ratio = torch.where(old_d > 0, depths.to(old) / old_d.clamp_min(1e-12), torch.ones_like(old_d))
    ratio = ratio.reshape(-1)  # [N], N = V·H·W; pixels without a depth stay where they are
    centers = torch.stack([c.center for c in cameras]).to(out.means)  # [V,3]
    c = centers.repeat_interleave(h * w, dim=0)  # [N,3]
    r = ratio.to(out.means.dtype)[:, None]  # [N,1]
    means = c + (out.means[0] - c) * r
    return replace(out, means=means[None], scales=out.scales * r[None], depths=depths[None].to(old))
