"""Depth accuracy: how far a predicted depth map is from the true (Blender) one."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def abs_rel(pred: Tensor, gt: Tensor, alpha: Tensor) -> float:
    """Mean |pred − gt| / gt over pixels with Blender depth and a drawn surface (alpha > 0.5)."""
    valid = (gt > 0) & (alpha > 0.5)
    if not valid.any():
        return float("nan")
    return float(((pred[valid] - gt[valid]).abs() / gt[valid]).mean())


#: how far in front of the true surface a drawn depth must lie to count as a floater: 10 %
#: (the generator's depth where it is right is within a few per cent; a curtain between a
#: wall and the ground, or a Gaussian floating in empty space, is far off)
FLOATER_MARGIN = 0.1


def floater_share(pred: Tensor, gt: Tensor, alpha: Tensor, margin: float = FLOATER_MARGIN) -> float:
    """The share of pixels with Blender depth (``gt > 0``) where a drawn surface (alpha > 0.5)
    lies more than ``margin`` in front of every true surface within one pixel:
    ``pred < (1 - margin) · min(gt over the 3x3 pixels around it)``.

    Why a share of all pixels with a surface, not of the drawn ones: a reconstruction that
    drops a curtain leaves a hole the fill paints, which is no floater; one that keeps it
    blocks the view of what lies behind. Why the 3x3 minimum: a rendered depth is the
    alpha-weighted mean of the Gaussians a pixel sees, so at a silhouette even Gaussians at
    the exact depth mix the object into the background pixel beside it (on the ray-cast test
    scene 3.6 % of the pixels, a one-pixel ring around each object, without it). Depth
    *behind* the truth is not counted: it is seen through or occluded, not in the way. Sky
    (``gt == 0``) is left out: a generator places sky at its far depth, which no true depth
    can judge."""
    has = gt > 0
    if not bool(has.any()):
        return float("nan")
    surface = torch.where(has, gt, torch.full_like(gt, float("inf")))
    nearest = -F.max_pool2d(-surface[None, None], 3, stride=1, padding=1)[0, 0]  # [H,W]
    floating = has & (alpha > 0.5) & (pred < (1.0 - margin) * nearest)
    return float(floating.sum()) / float(has.sum())
