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
3. **duplicate**: a Gaussian of view j whose mean projects (nearest pixel) into an earlier
   view i < j onto a pixel whose depth agrees within ``dedup_tol`` (relative) and where view
   i's own Gaussian survived steps 1-2: that surface is already covered by view i, which
   keeps its copy. The kept copy is *not* enlarged: view i's Gaussians already tile its
   pixel grid without holes, and the dropped copy only lay on the same surface.
4. **over budget** (only if ``budget`` is given): the survivors are ranked by importance =
   opacity x the area (px²) of the Gaussian's 1σ ellipse in the view it came from, as the
   rasterizer projects it (EWA with its 0.3 px² dilation), i.e. how much of its input image
   it paints; the most important are kept.

Everything is vectorised torch: per view (pair) a projection and a gather, no per-Gaussian
Python.
"""

from __future__ import annotations

import math
import numbers

import torch
from torch import Tensor

from prosplat.camera import Camera
from prosplat.gaussians import Gaussians

__all__ = ["prune_gaussians", "importance"]

_RANGE_SLACK = 1e-3  # relative: a Gaussian exactly at near/far is never dropped by rounding


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
    if not isinstance(cameras, (list, tuple)) or not all(isinstance(c, Camera) for c in cameras):
        raise ValueError("cameras must be a list of prosplat.Camera")
    if len(cameras) == 0:
        raise ValueError("cameras must hold at least one Camera (one per input view)")
    if not isinstance(view_index, Tensor) or tuple(view_index.shape) != (n,):
        shape = (
            list(view_index.shape) if isinstance(view_index, Tensor) else type(view_index).__name__
        )
        raise ValueError(
            f"view_index must be a [N={n}] tensor (the input view of each Gaussian), got {shape}"
        )
    if view_index.is_floating_point() or view_index.dtype == torch.bool or view_index.is_complex():
        raise ValueError(f"view_index must be an integer tensor, got {view_index.dtype}")
    if n and (view_index.min() < 0 or view_index.max() >= len(cameras)):
        raise ValueError(
            f"view_index values must lie in [0, {len(cameras)}) (one per camera), "
            f"got [{int(view_index.min())}, {int(view_index.max())}]"
        )
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
                f"{cam.width}x{cam.height}; pass the depth each view's pixels were unprojected at"
            )
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


def _duplicates(
    means: Tensor,
    view_index: Tensor,
    depths: Tensor,
    cameras: list[Camera],
    alive: Tensor,
    tol: float,
) -> Tensor:
    """[N] bool: alive Gaussians whose surface an earlier view's alive Gaussian already covers."""
    n = means.shape[0]
    dup = torch.zeros(n, dtype=torch.bool, device=means.device)
    # covered[i][r, c]: view i has a surviving Gaussian at pixel (c, r), found by projecting
    # each Gaussian into its own view, so any subset or order of the V·H·W layout works.
    covered = []
    for i, cam in enumerate(cameras[:-1]):
        idx = torch.nonzero(alive & (view_index == i)).squeeze(1)
        col, row, _, inside = cam.nearest_pixels(means[idx])
        mask = torch.zeros(cam.height, cam.width, dtype=torch.bool, device=means.device)
        mask[row[inside], col[inside]] = True
        covered.append(mask)
    for j in range(1, len(cameras)):
        idx = torch.nonzero(alive & (view_index == j)).squeeze(1)
        if idx.numel() == 0:
            continue
        pts = means[idx]
        hit = torch.zeros(idx.shape[0], dtype=torch.bool, device=means.device)
        for i in range(j):
            col, row, z, inside = cameras[i].nearest_pixels(pts)
            d = depths[i].to(device=means.device, dtype=means.dtype)[row, col]
            agree = (d > 0) & torch.isfinite(d) & ((d - z).abs() <= tol * z)
            hit |= inside & covered[i][row, col] & agree
        dup[idx] = hit
    return dup


def importance(gaussians: Gaussians, view_index: Tensor, cameras: list[Camera]) -> Tensor:
    """[N] opacity x area (px²) of each Gaussian's 1σ ellipse in its own input view.

    The area is ``π sqrt(det Σ₂)`` with Σ₂ the rasterizer's dilated 2D covariance, so it is
    what the Gaussian paints in the image it was predicted from; Gaussians behind that camera
    or too faint to draw score 0.
    """
    from prosplat.render.projection import project_gaussians

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
    dedup_tol: float = 0.01,
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
        dedup_tol: relative depth agreement for two views' Gaussians to be one surface.

    Returns:
        The kept Gaussians (in their original order, detached: index the input with keep_mask
        to keep gradients), keep_mask [N] bool, and stats with the
        counts ``input``, ``transparent``, ``out_of_bounds``, ``duplicate``, ``over_budget``,
        ``kept``.
    """
    _check(
        gaussians, view_index, depths, cameras, near, far, bounds, min_opacity, budget, dedup_tol
    )
    n = len(gaussians)
    g = gaussians.detach()
    means = g.means.to(torch.float64)
    view_index = view_index.to(device=g.device, dtype=torch.long)

    transparent = g.opacities < min_opacity
    oob = _out_of_bounds(means, cameras, near, far, bounds) & ~transparent
    alive = ~transparent & ~oob
    dup = _duplicates(means, view_index, depths, cameras, alive, dedup_tol)
    alive &= ~dup

    over = torch.zeros_like(alive)
    if budget is not None:
        k = _budget_count(budget, n)
        idx = torch.nonzero(alive).squeeze(1)
        if idx.numel() > k:
            score = importance(g[idx], view_index[idx], cameras)
            order = torch.argsort(score, descending=True, stable=True)
            over[idx[order[k:]]] = True
            alive &= ~over

    stats = {
        "input": n,
        "transparent": int(transparent.sum()),
        "out_of_bounds": int(oob.sum()),
        "duplicate": int(dup.sum()),
        "over_budget": int(over.sum()),
        "kept": int(alive.sum()),
    }
    return gaussians[alive], alive, stats
