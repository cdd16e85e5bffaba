"""The Gaussian budget: keep only the Gaussians a scene needs.

A pixel-aligned generator emits one Gaussian per input pixel, V·H·W in all, whatever the
scene. Many are wasted: nearly transparent ones the rasterizer never draws, floaters outside
the scene, and, above all, the same surface emitted once per view that sees it (two views
that overlap by 70% give 70% duplicates of one view). :func:`prune_gaussians` removes them,
in this order, each Gaussian counted under the first reason that removes it:

1. **transparent**: opacity below ``min_opacity``. The default, 1/255, is lossless: the
   rasterizer skips every sample under 1/255 and such a Gaussian's peak is one.
2. **out of bounds**: outside the given AABB, or, when ``near``/``far`` are given, at a
   depth outside [near, far] in any camera whose image it falls in (e.g. a floater just in
   front of another camera's lens), or in no camera's image at all.
3. **duplicate**: two views' Gaussians on one surface. A Gaussian g of view j is projected
   into every other view i; view i's depth map, read *bilinearly* at that sub-pixel position,
   agrees with g's depth within ``dedup_tol·z + dedup_px·(g's pixel footprint z/f) + the
   depth spread of the 2x2 pixels read`` (the spread widens the test on slanted surfaces and
   at edges, where one pixel spans a range of depths), and view i has a surviving Gaussian
   at that pixel. Of such a pair the copy from the view that sees the surface at the higher
   resolution (more pixels per unit length, f/z in its own view; ties: the earlier view)
   is kept, the coarser one dropped: it is the blurrier estimate of the same surface, and
   dropping it costs no quality (measured in BENCHMARKS.md, "budget"). The kept copy is *not*
   enlarged: its view's Gaussians already tile its pixel grid without holes. Only views that
   see the point from directions within ``dedup_angle`` degrees of each other are asked
   (:data:`DEDUP_ANGLE`). The depth test runs along view i's ray, and between views far apart
   its slack becomes a sideways shift as view j sees it (2 % of z plus 2 footprints at 60
   degrees: about 6 pixels at 256 px), while view i's pixel grid lies foreshortened on the
   surface as j sees it: the copy kept does not cover j's pixels, and dropping j's own copy
   tears cracks through which the background shows (the real fox's chest crossed by white
   ropes of wallpaper; BENCHMARKS "Duplicates only between nearby views").
4. **over budget** (only if ``budget`` is given): the survivors are thinned *evenly*. For
   pixel-aligned Gaussians (N = V·H·W) each pixel has a rank in an 8x8 ordered-dither
   (Bayer) pattern, so keeping the lowest ranks keeps a uniform lattice (1/2: a checkerboard,
   1/4: every other row and column) instead of leaving holes; ties within a rank go to
   importance = opacity x the area (px²) of the Gaussian's 1σ ellipse in the view it came
   from, as the rasterizer projects it (EWA with its 0.3 px² dilation). Each view's
   survivors are then enlarged by sqrt(before / after) of that view, so they cover the
   surface the dropped ones covered. Thinning by importance alone left holes: on test64, a
   1/2 budget cost up to 4.7 dB (BENCHMARKS.md, "budget"). Gaussians that are not
   pixel-aligned are ranked by importance alone and not enlarged.

Everything is vectorised torch: per view (pair) a projection and a gather, no per-Gaussian
Python.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import replace

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.render.projection import project_gaussians

__all__ = ["DEDUP_ANGLE", "budget_arg", "prune_gaussians", "prune_pixel_aligned", "importance"]

_RANGE_SLACK = 1e-3  # relative: a Gaussian exactly at near/far is never dropped by rounding

#: degrees: two views' Gaussians can be duplicates only where the views' rays to the point lie
#: within this angle of each other (rule 3; measured on eight real photo sets and the twelve
#: 512-px test scenes, where 10 degrees changed one set by 0.16 dB: BENCHMARKS "Duplicates
#: only between nearby views")
DEDUP_ANGLE = 20.0


def check_view_index(view_index, n: int, n_views: int, what: str = "") -> None:
    """``view_index`` must be an integer [N] tensor of values in [0, ``n_views``): the input
    view that predicted each of N Gaussians. ``what`` prefixes the messages (the caller)."""
    if not isinstance(view_index, Tensor) or tuple(view_index.shape) != (n,):
        shape = (
            list(view_index.shape) if isinstance(view_index, Tensor) else type(view_index).__name__
        )
        raise ValueError(
            f"{what}view_index must be an integer [N={n}] tensor (the input view of each "
            f"Gaussian), got {shape}"
        )
    if view_index.is_floating_point() or view_index.dtype == torch.bool or view_index.is_complex():
        raise ValueError(f"{what}view_index must be an integer tensor, got {view_index.dtype}")
    if n and (view_index.min() < 0 or view_index.max() >= n_views):
        raise ValueError(
            f"{what}view_index values must lie in [0, {n_views}) (one per input view), "
            f"got [{int(view_index.min())}, {int(view_index.max())}]"
        )


def check_depth_maps(depths: Tensor, cameras) -> None:
    """``cameras``: a non-empty list of :class:`Camera`; ``depths``: one float map [V,H,W]
    per camera, at that camera's size. The budget and the cross-view check both read the
    input views' depth maps at the cameras' pixels, so both refuse the same mistakes with the
    same messages."""
    if not isinstance(cameras, (list, tuple)) or not all(isinstance(c, Camera) for c in cameras):
        raise ValueError("cameras must be a list of prosplat.Camera")
    if len(cameras) == 0:
        raise ValueError("cameras must hold at least one Camera (one per input view)")
    if not isinstance(depths, Tensor) or depths.ndim != 3 or depths.shape[0] != len(cameras):
        shape = list(depths.shape) if isinstance(depths, Tensor) else type(depths).__name__
        raise ValueError(
            f"depths must be a [V={len(cameras)}, H, W] tensor (one map per camera), got {shape}"
        )
    if not depths.is_floating_point():
        raise ValueError(f"depths must be a float tensor, got {depths.dtype}")
    for i, cam in enumerate(cameras):
        if (cam.height, cam.width) != tuple(depths.shape[1:]):
            raise ValueError(
                f"depths maps are {depths.shape[2]}x{depths.shape[1]} but cameras[{i}] is "
                f"{cam.width}x{cam.height}; pass the cameras at the size of the depth maps "
                "(the size each view's pixels were unprojected at)"
            )


def _check(
    gaussians: Gaussians,
    view_index: Tensor,
    depths: Tensor,
    cameras: list[Camera],
    near: float | None,
    far: float | None,
    bounds,
    min_opacity: float,
    budget,
    dedup_tol: float,
) -> None:
    if not isinstance(gaussians, Gaussians):
        raise ValueError(f"gaussians must be prosplat.Gaussians, got {type(gaussians).__name__}")
    n = len(gaussians)
    check_depth_maps(depths, cameras)
    check_view_index(view_index, n, len(cameras))
    for name, value in (("near", near), ("far", far)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite non-negative number or None, got {value}")
    if near is not None and far is not None and not near < far:
        raise ValueError(f"near must be less than far, got near={near}, far={far}")
    if bounds is not None:
        lo, hi = (torch.as_tensor(b, dtype=torch.float64) for b in bounds)
        if lo.shape != (3,) or hi.shape != (3,) or not (lo <= hi).all():
            raise ValueError(f"bounds must be (min xyz, max xyz) with min <= max, got {bounds}")
    if not (0 <= min_opacity <= 1):
        raise ValueError(f"min_opacity must lie in [0, 1], got {min_opacity}")
    if not (math.isfinite(dedup_tol) and dedup_tol >= 0):
        raise ValueError(f"dedup_tol must be a finite non-negative number, got {dedup_tol}")
    if budget is not None:
        if isinstance(budget, bool) or not isinstance(budget, (numbers.Integral, float)):
            raise ValueError(
                f"budget must be an int (count), a float in (0, 1] (fraction) or None, got {budget!r}"
            )
        if isinstance(budget, numbers.Integral) and budget < 0:
            raise ValueError(f"budget as a count must be >= 0, got {budget}")
        if isinstance(budget, float) and not 0 < budget <= 1:
            raise ValueError(
                f"budget as a fraction must lie in (0, 1], got {budget}; pass an int for a count"
            )


def _out_of_bounds(
    means: Tensor, cameras: list[Camera], near: float | None, far: float | None, bounds
) -> Tensor:
    """[N] bool: outside the AABB, or outside [near, far] in a camera that sees it, or unseen."""
    out = torch.zeros(means.shape[0], dtype=torch.bool, device=means.device)
    if bounds is not None:
        lo, hi = (torch.as_tensor(b, dtype=means.dtype, device=means.device) for b in bounds)
        out |= ((means < lo) | (means > hi)).any(dim=1)
    if near is None and far is None:
        return out
    seen = torch.zeros_like(out)
    for cam in cameras:
        _, _, z, inside = cam.nearest_pixels(means)
        bad = torch.zeros_like(out)
        if near is not None:
            bad |= z < near * (1 - _RANGE_SLACK)
        if far is not None:
            bad |= z > far * (1 + _RANGE_SLACK)
        out |= inside & bad
        seen |= inside
    return out | ~seen


def bilinear_depth(dmap: Tensor, uv: Tensor) -> tuple[Tensor, Tensor]:
    """Bilinear read of ``dmap [H,W]`` at pixel coordinates ``uv [M,2]`` (centres at +0.5,
    border pixels replicated): the value [M] and the four pixels it mixes [M,4]."""
    h, w = dmap.shape
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    x0, y0 = x.floor().clamp(0, w - 1), y.floor().clamp(0, h - 1)
    fx, fy = (x - x0).clamp(0, 1), (y - y0).clamp(0, 1)
    c0, r0 = x0.long(), y0.long()
    c1, r1 = (c0 + 1).clamp(max=w - 1), (r0 + 1).clamp(max=h - 1)
    corners = torch.stack([dmap[r0, c0], dmap[r0, c1], dmap[r1, c0], dmap[r1, c1]], dim=-1)
    top = corners[:, 0] * (1 - fx) + corners[:, 1] * fx
    bottom = corners[:, 2] * (1 - fx) + corners[:, 3] * fx
    return top * (1 - fy) + bottom * fy, corners


def _resolution(
    means: Tensor, view_index: Tensor, cameras: list[Camera], alive: Tensor
) -> tuple[Tensor, list[Tensor]]:
    """Pixels per unit length (f/z) at each Gaussian in its own view, and per view a map of
    that value for the view's surviving Gaussian at each pixel (0: no survivor there).

    The maps come from projecting each Gaussian into its own view, so any subset or order of
    the V·H·W layout works.
    """
    res = torch.zeros(means.shape[0], dtype=torch.float64, device=means.device)
    maps = []
    for i, cam in enumerate(cameras):
        idx = torch.nonzero(view_index == i).squeeze(1)
        col, row, z, inside = cam.nearest_pixels(means[idx])
        focal = math.sqrt(float(cam.K[0, 0]) * float(cam.K[1, 1]))
        res[idx] = focal / z.clamp_min(1e-12)
        flat = torch.zeros(cam.height * cam.width, dtype=torch.float64, device=means.device)
        ok = inside & alive[idx]
        flat.scatter_reduce_(0, (row * cam.width + col)[ok], res[idx][ok], reduce="amax")
        maps.append(flat.reshape(cam.height, cam.width))
    return res, maps


def _duplicates(
    means: Tensor,
    view_index: Tensor,
    depths: Tensor,
    cameras: list[Camera],
    alive: Tensor,
    tol: float,
    px: float,
    angle: float,
) -> Tensor:
    """[N] bool: alive Gaussians whose surface another view's alive Gaussian covers at a
    higher resolution, seen from within ``angle`` degrees (rule 3 in the module docstring)."""
    n = means.shape[0]
    dup = torch.zeros(n, dtype=torch.bool, device=means.device)
    res, res_maps = _resolution(means, view_index, cameras, alive)
    min_cos = math.cos(math.radians(angle))
    for j in range(len(cameras)):
        idx = torch.nonzero(alive & (view_index == j)).squeeze(1)
        if idx.numel() == 0:
            continue
        for i, cam in enumerate(cameras):
            if i == j or idx.numel() == 0:
                continue
            pts, res_j = means[idx], res[idx]
            uv, z = cam.project(pts)
            col, row = uv[:, 0].floor(), uv[:, 1].floor()  # as Camera.nearest_pixels
            inside = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
            col = col.clamp(0, cam.width - 1).long()
            row = row.clamp(0, cam.height - 1).long()
            dmap = depths[i].to(device=means.device, dtype=torch.float64)
            d, corners = bilinear_depth(dmap, uv)
            valid = ((corners > 0) & torch.isfinite(corners)).all(dim=1)
            spread = (corners - d[:, None]).abs().amax(dim=1)
            agree = (d - z).abs() <= tol * z + px / res_j + spread
            res_i = res_maps[i][row, col]  # 0 where view i kept nothing at that pixel
            finer = (res_i > res_j) | ((res_i == res_j) & (i < j))
            ray_i = pts - cam.center.to(pts)  # [M,3] from each camera to the point
            ray_j = pts - cameras[j].center.to(pts)
            cos = (ray_i * ray_j).sum(1) / (ray_i.norm(dim=1) * ray_j.norm(dim=1)).clamp_min(1e-300)
            hit = inside & valid & agree & (res_i > 0) & finer & (cos >= min_cos)
            dup[idx[hit]] = True
            idx = idx[~hit]  # found once is enough: later views test only the rest
    return dup


def importance(gaussians: Gaussians, view_index: Tensor, cameras: list[Camera]) -> Tensor:
    """[N] opacity x area (px²) of each Gaussian's 1σ ellipse in its own input view.

    The area is ``π sqrt(det Σ₂)`` with Σ₂ the rasterizer's dilated 2D covariance, so it is
    what the Gaussian paints in the image it was predicted from; Gaussians behind that camera
    or too faint to draw score 0.
    """

    g = gaussians.detach()
    score = torch.zeros(len(g), dtype=torch.float64, device=g.device)
    for i, cam in enumerate(cameras):
        idx = torch.nonzero(view_index == i).squeeze(1)
        if idx.numel() == 0:
            continue
        p = project_gaussians(g[idx], cam)
        a, b, c = p.conics.to(torch.float64).unbind(-1)
        det_conic = (a * c - b * b).clamp_min(1e-30)  # = 1 / det Σ₂
        area = math.pi / torch.sqrt(det_conic)
        score[idx] = torch.where(p.valid, g.opacities[idx].to(torch.float64) * area, 0.0)
    return score


def budget_arg(value: float | None) -> int | float | None:
    """A ``--budget`` as given on a command line (a float) as the pruning functions take it:
    None (automatic) stays None, a count above 1 becomes an int, and a fraction (<= 1) stays
    a float (:func:`_budget_count` tells the two apart by type)."""
    return None if value is None else (int(value) if value > 1 else value)


def _budget_count(budget: int | float, n_input: int) -> int:
    if isinstance(budget, float):
        return int(math.floor(budget * n_input + 1e-9))
    return int(budget)


@torch.no_grad()
def prune_gaussians(
    gaussians: Gaussians,
    view_index: Tensor,
    depths: Tensor,
    cameras: list[Camera],
    near: float | None = None,
    far: float | None = None,
    bounds: tuple | None = None,
    min_opacity: float = 1.0 / 255.0,
    budget: int | float | None = None,
    dedup_tol: float | None = 0.02,
    dedup_px: float = 2.0,
    dedup_angle: float = DEDUP_ANGLE,
) -> tuple[Gaussians, Tensor, dict]:
    """Drop the Gaussians a scene does not need (see the module docstring for the rules).

    Args:
        gaussians: N Gaussians, typically pixel-aligned (N = V·H·W, view-major, row-major).
        view_index: [N] integer, the input view each Gaussian was predicted from.
        depths: [V,H,W] z-depth at which each view's pixels were unprojected (<= 0 or
            non-finite: no surface there).
        cameras: the V input cameras, each W x H.
        near, far: the scene's depth range (None: not checked).
        bounds: optional AABB ``(min xyz, max xyz)``; Gaussians outside are dropped.
        min_opacity: Gaussians with a lower opacity are dropped (1/255: lossless).
        budget: None (steps 1-3 only, the automatic default), an int (keep at most this many)
            or a float in (0, 1] (keep at most ``floor(budget * N)``).
        dedup_tol: relative depth agreement for two views' Gaussians to be one surface
            (None: no duplicate test).
        dedup_px: further depth slack in units of the Gaussian's pixel footprint z/f, so the
            test scales with image resolution (a 64² view's pixel spans 4x the depth of a
            256² view's at the same distance).
        dedup_angle: degrees; two views' Gaussians are compared only where the views' rays
            to the point lie within this angle (:data:`DEDUP_ANGLE`; 180: every pair).

    Returns:
        The kept Gaussians (in their original order, detached: index the input with keep_mask
        to keep gradients; when a budget thinned pixel-aligned Gaussians their scales are
        enlarged as described above), keep_mask [N] bool, and stats with the
        counts ``input``, ``transparent``, ``out_of_bounds``, ``duplicate``, ``over_budget``,
        ``kept``.
    """
    _check(
        gaussians,
        view_index,
        depths,
        cameras,
        near,
        far,
        bounds,
        min_opacity,
        budget,
        0.0 if dedup_tol is None else dedup_tol,
    )
    if not (math.isfinite(dedup_px) and dedup_px >= 0):
        raise ValueError(f"dedup_px must be a finite non-negative number, got {dedup_px}")
    if not (math.isfinite(dedup_angle) and 0 <= dedup_angle <= 180):
        raise ValueError(f"dedup_angle must be in [0, 180] degrees, got {dedup_angle}")
    n = len(gaussians)
    g = gaussians.detach()
    means = g.means.to(torch.float64)
    view_index = view_index.to(device=g.device, dtype=torch.long)

    transparent = g.opacities < min_opacity
    oob = _out_of_bounds(means, cameras, near, far, bounds) & ~transparent
    alive = ~transparent & ~oob
    dup = torch.zeros_like(alive)
    if dedup_tol is not None:
        dup = _duplicates(
            means, view_index, depths, cameras, alive, dedup_tol, dedup_px, dedup_angle
        )
    alive &= ~dup

    over = torch.zeros_like(alive)
    scales = None
    if budget is not None:
        k = _budget_count(budget, n)
        idx = torch.nonzero(alive).squeeze(1)
        if idx.numel() > k:
            score = importance(g[idx], view_index[idx], cameras)
            order = torch.argsort(score, descending=True, stable=True)
            v, h, w = depths.shape
            pixel_aligned = n == v * h * w
            if pixel_aligned:  # stable sort by dither rank keeps the importance order within
                rank = _dither_rank(h, w, g.device).reshape(-1).repeat(v)[idx]
                order = order[torch.argsort(rank[order], stable=True)]
            over[idx[order[k:]]] = True
            alive &= ~over
            if pixel_aligned:
                before = torch.bincount(view_index[idx], minlength=len(cameras))
                after = torch.bincount(view_index[alive], minlength=len(cameras))
                grow = torch.sqrt(before / after.clamp_min(1))  # [V] spacing ratio per view
                scales = g.scales * grow[view_index, None].to(g.scales.dtype)

    stats = {
        "input": n,
        "transparent": int(transparent.sum()),
        "out_of_bounds": int(oob.sum()),
        "duplicate": int(dup.sum()),
        "over_budget": int(over.sum()),
        "kept": int(alive.sum()),
    }
    kept = gaussians[alive]
    if scales is not None:
        kept = replace(kept, scales=scales[alive])
    return kept, alive, stats


def prune_pixel_aligned(
    gaussians: Gaussians, depths: Tensor, cameras: list[Camera], **kwargs
) -> tuple[Gaussians, Tensor, dict]:
    """:func:`prune_gaussians` for a generator's output: V·H·W Gaussians, view-major, one per
    pixel of the V depth maps ``depths [V,H,W]`` (the view index follows from that layout).
    ``kwargs`` go to :func:`prune_gaussians` (``budget``, ``near``/``far``, ...)."""
    v, h, w = depths.shape
    view_index = torch.arange(v, device=gaussians.device).repeat_interleave(h * w)
    return prune_gaussians(gaussians, view_index, depths, cameras, **kwargs)


def _dither_rank(h: int, w: int, device) -> Tensor:
    """[H,W] rank 0..63 of each pixel in an 8x8 Bayer ordered-dither matrix tiled over the
    image: the first k/64 ranks of every 8x8 block form an even lattice for any k."""
    m = torch.zeros(1, 1, dtype=torch.long)
    while m.shape[0] < 8:  # M_2n = [[4M, 4M+2], [4M+3, 4M+1]]
        m = torch.cat([torch.cat([4 * m, 4 * m + 2], 1), torch.cat([4 * m + 3, 4 * m + 1], 1)], 0)
    rows = torch.arange(h, device=device) % 8
    cols = torch.arange(w, device=device) % 8
    return m.to(device)[rows[:, None], cols[None, :]]
