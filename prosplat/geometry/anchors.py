"""Depth anchors: each input's depth map aligned to sparse 3D points that view observes.

Why (issue 68, item 3): a generator trained on rendered scenes gets the relative layout of a
real photo roughly right but its depth scale and offset per view wrong, and views that disagree
in scale double every surface (the doubled facades). Structure from motion, or triangulation
of the inputs with their known poses (:func:`prosplat.poses.triangulate_inputs`), gives 3D
points whose depth in each view is measured, not guessed. The generator's depth at those
points is fitted to theirs by a robust affine map in inverse depth (the quantity the cost
volume samples uniformly, and in which the generator's errors are closest to affine), and the
map is applied to the whole view.

A fit is kept only when it is trustworthy: enough points, a positive slope, the points'
residual lower after it than before, and no pixel sent behind the camera.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from prosplat.core.camera import Camera

__all__ = ["AnchorFit", "MIN_ANCHOR_POINTS", "anchor_depths", "fit_inverse_depth", "point_depths"]

#: fewer points than this in a view leave its depth as the generator made it
MIN_ANCHOR_POINTS = 12
#: Huber threshold in units of the residuals' robust spread (1.4826 · MAD)
HUBER_K = 1.345


@dataclass(frozen=True)
class AnchorFit:
    """One view's alignment: inverse depth ``1/z`` becomes ``scale / z + shift``.

    Attributes:
        points: how many anchor points fell on the view's depth map.
        used: whether the fit was applied (False: too few points or an untrustworthy fit).
        before, after: median relative depth error at the points, ``|z_map − z_pt| / z_pt``,
            before and after the fit (``after`` equals ``before`` when not used).
    """

    scale: float
    shift: float
    points: int
    used: bool
    before: float
    after: float


def point_depths(points: Tensor, camera: Camera, height: int, width: int) -> tuple[Tensor, Tensor]:
    """Where ``points [P,3]`` (world) fall on a ``height`` x ``width`` depth map of ``camera``
    (scaled to that size when the camera is another's): ``(flat pixel index [M] int64, depth
    z [M])`` of the points in front of the camera and inside the map."""
    if (camera.width, camera.height) != (width, height):
        camera = camera.resized(width, height)
    uv, z = camera.project(points.to(torch.float64))  # [P,2], [P]
    c, r = uv[:, 0].floor(), uv[:, 1].floor()
    ok = (z > 0) & (c >= 0) & (c < width) & (r >= 0) & (r < height)
    idx = (r[ok] * width + c[ok]).long()
    return idx, z[ok]


def fit_inverse_depth(d_map: Tensor, d_pt: Tensor, iters: int = 10) -> tuple[float, float]:
    """The robust affine map ``d_pt ≈ scale · d_map + shift`` between inverse depths ``[M]``:
    iteratively reweighted least squares with Huber weights, started from the ratio of
    medians (so one gross outlier cannot start it off). Float64 throughout."""
    x, y = d_map.double(), d_pt.double()
    a = float(y.median() / x.median().clamp_min(1e-12))
    b = 0.0
    for _ in range(iters):
        res = y - (a * x + b)
        spread = 1.4826 * float((res - res.median()).abs().median()) + 1e-12
        w = (HUBER_K * spread / res.abs().clamp_min(1e-12)).clamp(max=1.0)  # [M] Huber
        sw, sx, sy = w.sum(), (w * x).sum(), (w * y).sum()
        sxx, sxy = (w * x * x).sum(), (w * x * y).sum()
        det = sw * sxx - sx * sx
        if float(det) <= 1e-18 * float(sw * sxx + 1e-30):
            break  # all points at one depth: keep the ratio of medians
        a = float((sw * sxy - sx * sy) / det)
        b = float((sy - a * sx) / sw)
    return a, b


def _median_rel(z_map: Tensor, z_pt: Tensor) -> float:
    return float(((z_map - z_pt).abs() / z_pt).median())


def anchor_depths(
    depths: Tensor,
    cameras: Sequence[Camera],
    points: Tensor,
    observed: Sequence[Tensor] | None = None,
    *,
    min_points: int = MIN_ANCHOR_POINTS,
) -> tuple[Tensor, list[AnchorFit]]:
    """``depths [V,H,W]`` (each view's depth map, cameras of any size: scaled to the map) with
    each view aligned to the ``points [P,3]`` it observes (``observed[v]``: indices into
    ``points``; None: every point in front of it and inside it), and the fit of each view.

    Pixels without a depth (<= 0) stay at 0. A view keeps its depth when it has fewer than
    ``min_points`` points, when the fitted slope is not positive, when the fit does not lower
    the points' median relative error, or when it would send a pixel behind the camera.
    """
    v, h, w = depths.shape
    if len(cameras) != v:
        raise ValueError(f"{v} depth maps but {len(cameras)} cameras")
    out = depths.clone()
    fits: list[AnchorFit] = []
    for i, cam in enumerate(cameras):
        pts = points if observed is None else points[observed[i].long()]
        idx, z_pt = point_depths(pts, cam, h, w)
        z_map = depths[i].reshape(-1)[idx].double()  # [M]
        ok = z_map > 0
        idx, z_pt, z_map = idx[ok], z_pt[ok], z_map[ok]
        n = len(idx)
        if n < min_points:
            before = _median_rel(z_map, z_pt) if n else float("nan")
            fits.append(AnchorFit(1.0, 0.0, n, False, before, before))
            continue
        a, b = fit_inverse_depth(1.0 / z_map, 1.0 / z_pt)
        before = _median_rel(z_map, z_pt)
        valid = depths[i] > 0
        inv = a / depths[i].double().clamp_min(1e-12) + b  # [H,W]
        after = _median_rel(1.0 / (a / z_map + b).clamp_min(1e-12), z_pt)
        good = a > 0 and after < before and bool((inv[valid] > 0).all())
        if good:
            out[i] = torch.where(valid, 1.0 / inv.clamp_min(1e-12), depths[i].double()).to(depths)
        fits.append(AnchorFit(a, b, n, good, before, after if good else before))
    return out, fits
