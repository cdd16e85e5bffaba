"""Depth accuracy: how far a predicted depth map is from the true (Blender) one."""

from __future__ import annotations

from torch import Tensor


def abs_rel(pred: Tensor, gt: Tensor, alpha: Tensor) -> float:
    """Mean |pred − gt| / gt over pixels with Blender depth and a drawn surface (alpha > 0.5)."""
    valid = (gt > 0) & (alpha > 0.5)
    if not valid.any():
        return float("nan")
    return float(((pred[valid] - gt[valid]).abs() / gt[valid]).mean())
