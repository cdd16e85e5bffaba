"""Gaussians the input views agree on: a cross-view check of pixel-aligned Gaussians.

Why (issue 68, item 2): a pixel-aligned generator places each input pixel's Gaussian at the
depth it predicts for that pixel, from that view alone. Where the prediction is wrong the
Gaussian floats in empty space, and the other inputs can tell: on real photos the castle
facade came out doubled and streaked, and at depth edges Gaussians stretched into curtains
toward the camera (a pixel between a near and a far surface gets a depth in between). Such a
Gaussian lies *in front of* what another input saw along the same ray: that view looked
straight through the place where the Gaussian sits, so the Gaussian cannot be there.

The rule, for a Gaussian of view i at world point p:

* p is projected into every other view j. View j **sees** p when p lands inside j's image,
  in front of its camera (z > 0), on pixels where j's depth map is valid (> 0 and finite).
* View j **contradicts** p when j sees it and p is nearer to j, by more than the relative
  margin ``tau``, than *every* surface j recorded around that spot:
  ``z_ij < (1 - tau) * min(d_j over the 2x2 pixels p falls between)``. The minimum over the
  four pixels makes the test lenient at j's own depth edges, where a true foreground point
  can land on a background pixel by a fraction of a pixel (a nearest-pixel read would drop
  the foreground's silhouette).
* A point *behind* j's surface (z_ij > d_j) is occluded in j, not contradicted: j could not
  have seen it, so nothing is said about it. A point no other view sees keeps its own
  confidence (it is kept): a single view is no evidence against itself.
* The Gaussian is kept when fewer than ``min_votes`` views contradict it.

Dropping every contradicted Gaussian removes much correct surface, because the other views'
depths are wrong too (a view whose depth is too far "sees through" good Gaussians). Fading
does better: :func:`fade_contradicted` multiplies each Gaussian's opacity by ``fade`` per
contradicting view, so one wrong vote costs a correct Gaussian part of its weight, not its
place, and a floater several views see through all but vanishes. On the twelve held-back
512-px scenes (BENCHMARKS "Cross-view check") :class:`CrossViewOptions`' defaults take the
floaters from 12.7 % to 8.9 % of the target pixels at +0.09 dB; dropping (``fade=0``) takes
them to 8.0 % at -0.31 dB. On eight real photo sets it costs 0.5 dB enhanced, so
``ProSplat.cross_view`` (which runs it in :meth:`ProSplat.reconstruct`) is off by default.
Everything is vectorised torch: per view pair one projection and one gather, no
per-Gaussian Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.geometry.budget import bilinear_depth, check_depth_maps, check_view_index

__all__ = [
    "ConsistencyResult",
    "CrossViewOptions",
    "DEFAULT_TAU",
    "cross_view_check",
    "fade_contradicted",
]

#: relative depth margin: a point must lie more than 5 % nearer to another view than the
#: surface that view recorded there before it counts as seen through (generator depths on the
#: test scenes are within a few per cent where they are right; floaters are far off)
DEFAULT_TAU = 0.05


@dataclass(frozen=True)
class ConsistencyResult:
    """The outcome of :func:`cross_view_check` for N points (N = V·h·w for depth maps).

    Attributes:
        keep: [N] bool, fewer than ``min_votes`` other views contradict the point.
        contradictions: [N] long, how many other views saw through the point.
        seen_by: [N] long, how many other views see the point at all (0: only its own view).
    """

    keep: Tensor
    contradictions: Tensor
    seen_by: Tensor

    @property
    def dropped(self) -> int:
        """How many points the check drops."""
        return int((~self.keep).sum())

    def stats(self) -> dict[str, int]:
        """Counts for reports: input, dropped, kept, and points no other view sees."""
        n = int(self.keep.numel())
        return {"input": n, "dropped": self.dropped, "kept": n - self.dropped,
                "unseen_elsewhere": int((self.seen_by == 0).sum())}  # fmt: skip


def _check_inputs(depths, cameras, tau: float, min_votes: int) -> None:
    check_depth_maps(depths, cameras)
    if not (math.isfinite(tau) and 0 <= tau < 1):
        raise ValueError(f"tau must lie in [0, 1), got {tau}")
    if isinstance(min_votes, bool) or not isinstance(min_votes, int) or min_votes < 1:
        raise ValueError(f"min_votes must be an int >= 1, got {min_votes!r}")


def _unprojected(depths: Tensor, cameras: list[Camera]) -> tuple[Tensor, Tensor]:
    """Every pixel of every view at its depth: world points [V·h·w, 3] (float64, view-major,
    pixel order) and the view of each [V·h·w]. Invalid depths give meaningless points; the
    caller masks them."""
    pts = []
    for i, cam in enumerate(cameras):
        c = cam.to(device=depths.device, dtype=torch.float64)
        d = depths[i].to(torch.float64)  # [h,w]
        pts.append(c.unproject(c.pixel_centers(torch.float64), d).reshape(-1, 3))  # [h*w,3]
    v, h, w = depths.shape
    view_index = torch.arange(v, device=depths.device).repeat_interleave(h * w)  # [V*h*w]
    return torch.cat(pts), view_index


def cross_view_check(
    depths: Tensor,
    cameras: list[Camera],
    tau: float = DEFAULT_TAU,
    *,
    means: Tensor | None = None,
    view_index: Tensor | None = None,
    min_votes: int = 1,
) -> ConsistencyResult:
    """Which Gaussians the other input views agree on (the rule: module docstring).

    Args:
        depths: [V,h,w] each input view's depth map (z along its optical axis; <= 0 or
            non-finite: nothing recorded there, so that view sees nothing at that pixel).
        cameras: V cameras at the depth maps' size.
        tau: the relative margin by which a point must lie in front of another view's
            surface to count as seen through (:data:`DEFAULT_TAU`).
        means: [N,3] the points to check (e.g. a reconstruction's Gaussian means, after the
            budget); None: every pixel of every view unprojected at its own depth
            (N = V·h·w, view-major, pixel order, as the generator emits its Gaussians).
        view_index: [N] the input view of each point in ``means`` (that view is not asked
            about its own points); required with ``means``.
        min_votes: how many contradicting views drop a point (1: any one).

    Returns:
        :class:`ConsistencyResult` with ``keep``, ``contradictions``, ``seen_by``, all [N].
        Pixels with no valid depth of their own (None ``means``) are kept and counted as
        seen by none.
    """
    cameras = list(cameras)
    _check_inputs(depths, cameras, tau, min_votes)
    own_valid = None
    if means is None:
        if view_index is not None:
            raise ValueError("view_index is only for means; depth-map pixels know their view")
        means, view_index = _unprojected(depths, cameras)
        own_valid = (torch.isfinite(depths) & (depths > 0)).reshape(-1)  # [V*h*w]
    else:
        if not isinstance(means, Tensor) or means.ndim != 2 or means.shape[1] != 3:
            shape = list(means.shape) if isinstance(means, Tensor) else type(means).__name__
            raise ValueError(f"means must be an [N,3] tensor, got {shape}")
        check_view_index(view_index, means.shape[0], len(cameras), "cross_view_check: ")
    pts = means.detach().to(device=depths.device, dtype=torch.float64)  # [N,3]
    finite = torch.isfinite(pts).all(dim=1)  # [N] (a NaN would index out of the maps)
    pts = torch.where(finite[:, None], pts, torch.zeros_like(pts))
    view_index = view_index.to(depths.device)
    n = pts.shape[0]
    contradictions = torch.zeros(n, dtype=torch.long, device=depths.device)  # [N]
    seen_by = torch.zeros_like(contradictions)  # [N]
    for j, cam in enumerate(cameras):
        c = cam.to(device=depths.device, dtype=torch.float64)
        dmap = depths[j].to(torch.float64)  # [h,w]
        uv, z = c.project(pts)  # [N,2], [N]
        inside = (
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < c.width) & (uv[:, 1] >= 0)
            & (uv[:, 1] < c.height)
        )  # fmt: skip
        _, corners = bilinear_depth(dmap, uv)  # [N,4] the pixels around the landing spot
        valid = ((corners > 0) & torch.isfinite(corners)).all(dim=1)  # [N]
        seen = inside & valid & finite & (view_index != j)
        if own_valid is not None:
            seen &= own_valid
        nearest = corners.amin(dim=1)  # [N] the nearest surface view j recorded there
        through = seen & (z < (1 - tau) * nearest)
        seen_by += seen.long()
        contradictions += through.long()
    keep = contradictions < min_votes
    return ConsistencyResult(keep, contradictions, seen_by)


@dataclass(frozen=True)
class CrossViewOptions:
    """How :meth:`ProSplat.reconstruct` applies the cross-view check (``ProSplat.cross_view``).

    Attributes:
        tau: the check's relative margin (:func:`cross_view_check`). 0.1: on the twelve
            512-px test scenes it faded fewer correct Gaussians than 0.05 for the same
            floaters (BENCHMARKS "Cross-view check").
        fade: each Gaussian's opacity is multiplied by this once per other input view that saw
            through it (:func:`fade_contradicted`); 0 drops every contradicted Gaussian.
    """

    tau: float = 0.1
    fade: float = 0.3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tau) and 0 <= self.tau < 1):
            raise ValueError(f"tau must lie in [0, 1), got {self.tau}")
        if not (math.isfinite(self.fade) and 0 <= self.fade <= 1):
            raise ValueError(f"fade must lie in [0, 1], got {self.fade}")


def fade_contradicted(
    gaussians: Gaussians, result: ConsistencyResult, fade: float
) -> tuple[Gaussians, int]:
    """``gaussians`` with each opacity times ``fade ** contradictions`` (``result`` of
    :func:`cross_view_check` on these Gaussians' means), and how many were faded. With
    ``fade=0`` the contradicted Gaussians are dropped instead (a zero opacity would only cost
    time to draw). Why a product per view: one wrong vote (another view's depth too far)
    costs a correct Gaussian part of its weight; a floater that several views see through
    all but vanishes."""
    n = len(gaussians)
    if result.contradictions.shape != (n,):
        raise ValueError(
            f"the check is for {result.contradictions.numel()} points, the Gaussians are {n}"
        )
    votes = result.contradictions.to(gaussians.opacities.device)  # [N]
    faded = int((votes > 0).sum())
    if fade == 0:
        return gaussians[votes == 0], faded
    factor = torch.full_like(gaussians.opacities, fade) ** votes.to(gaussians.opacities.dtype)
    g = gaussians
    return Gaussians.trusted(g.means, g.quats, g.scales, g.opacities * factor, g.sh, g.views), faded
