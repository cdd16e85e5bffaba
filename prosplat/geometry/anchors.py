"""Depth anchors: each input's depth map scaled to agree with the sparse 3D points it observes.

Why (issue 68, item 3): a generator trained on rendered scenes gets the relative layout of a
real photo roughly right but each view's depth scale wrong, and views that disagree in scale
double every surface (the doubled facades). Structure from motion, or triangulation of the
inputs with their known poses (:func:`prosplat.poses.triangulate_inputs`), gives 3D points
whose depth in each view is measured, not guessed. Each view's depth map is multiplied by the
robust ratio of the points' depths to the map's at their pixels.

A scale, not an affine map: on four inputs the points cover a narrow band of depths (the
object of a ring: 0.52-0.61 on the Middlebury temple), where a fitted shift is ill-posed (the
slopes came out 0.08-0.23, flattening the object into a plane) while the ratio is stable
(0.90-0.97). A fit is kept only when enough points agree and it lowers their error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from prosplat.core.camera import Camera

__all__ = [
    "AnchorFit",
    "DepthAnchors",
    "MIN_ANCHOR_POINTS",
    "anchor_depths",
    "fit_scale",
    "point_depths",
]

#: fewer points than this in a view leave its depth as the generator made it
MIN_ANCHOR_POINTS = 12
#: Huber threshold in units of the log ratios' robust spread (1.4826 · MAD)
HUBER_K = 1.345


@dataclass(frozen=True)
class DepthAnchors:
    """Sparse 3D points the inputs observe: ``points [P,3]`` (world, float64) and
    ``observed[v]`` (int64 indices into ``points``) per input view, or None when every point
    in front of a view and inside it counts as observed."""

    points: Tensor
    observed: list[Tensor] | None = None

    def views(self, indices: Sequence[int]) -> DepthAnchors:
        """The anchors of a subset of the inputs (e.g. all but one, leave-one-out)."""
        if self.observed is None:
            return self
        return DepthAnchors(self.points, [self.observed[i] for i in indices])


@dataclass(frozen=True)
class AnchorFit:
    """One view's alignment: depth ``z`` becomes ``scale · z``.

    Attributes:
        points: how many anchor points fell on the view's depth map.
        used: whether the fit was applied (False: too few points or an untrustworthy fit).
        before, after: median relative depth error at the points, ``|z_map − z_pt| / z_pt``,
            before and after the fit (``after`` equals ``before`` when not used).
    """

    scale: float
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
    col, row, z, inside = camera.nearest_pixels(points.to(torch.float64))  # [P] each
    return row[inside] * width + col[inside], z[inside]


def fit_scale(z_map: Tensor, z_pt: Tensor, iters: int = 10) -> float:
    """The robust factor ``s`` with ``z_pt ≈ s · z_map`` for depths ``[M]``: the Huber mean of
    the log ratios by iteratively reweighted averaging, started from their median (so gross
    outliers, SfM's wrong matches, cannot start it off). Float64 throughout."""
    r = (z_pt.double() / z_map.double()).log()  # [M]
    m = float(r.median())
    spread = 1.4826 * float((r - m).abs().median()) + 1e-12
    for _ in range(iters):
        w = (HUBER_K * spread / (r - m).abs().clamp_min(1e-12)).clamp(max=1.0)  # [M]
        m = float((w * r).sum() / w.sum())
    return float(torch.tensor(m).exp())


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

    A view keeps its depth when it has fewer than ``min_points`` points or when the factor
    does not lower the points' median relative error.
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
        before = _median_rel(z_map, z_pt) if n else float("nan")
        if n < min_points:
            fits.append(AnchorFit(1.0, n, False, before, before))
            continue
        scale = fit_scale(z_map, z_pt)
        after = _median_rel(scale * z_map, z_pt)
        good = after < before
        if good:
            out[i] = depths[i] * scale  # pixels without a depth (0) stay at 0
        fits.append(AnchorFit(scale, n, good, before, after if good else before))
    return out, fits
