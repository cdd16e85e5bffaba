"""How much two views see of the same surface, measured from their depth maps.

Used to report the baseline of every input set (so benchmarks can bin scenes by overlap)
and, later, as MORI's geometry-based reference choice.
"""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.core.camera import Camera


def covisibility(
    src: Camera, src_depth: Tensor, dst: Camera, dst_depth: Tensor, rel_tol: float = 0.02
) -> float:
    """Fraction of ``src``'s valid pixels whose surface point is visible in ``dst``.

    A pixel is valid where ``src_depth > 0`` (0 marks sky / no surface). Its point is
    unprojected, projected into ``dst``, and counts when it lands inside the image, in front
    of the camera, and agrees with ``dst_depth`` at that pixel within ``rel_tol`` (not
    occluded). Nearest-pixel lookup, so the measure is cheap and exact enough for binning.
    """
    valid = src_depth > 0
    n_valid = int(valid.sum())
    if n_valid == 0:
        return 0.0
    uv = src.pixel_centers(torch.float64)[valid]  # [P,2]
    pts = src.unproject(uv, src_depth.to(torch.float64)[valid])  # [P,3]
    col, row, z2, inside = dst.nearest_pixels(pts)
    d = dst_depth.to(torch.float64)[row, col]
    seen = inside & (d > 0) & ((d - z2).abs() <= rel_tol * z2)
    return float(seen.sum()) / n_valid


def overlap_matrix(cameras: list[Camera], depths: list[Tensor]) -> Tensor:
    """[V,V] symmetric overlap: mean of the two directed covisibilities; 1 on the diagonal."""
    v = len(cameras)
    out = torch.eye(v, dtype=torch.float64)
    for i in range(v):
        for j in range(i + 1, v):
            a = covisibility(cameras[i], depths[i], cameras[j], depths[j])
            b = covisibility(cameras[j], depths[j], cameras[i], depths[i])
            out[i, j] = out[j, i] = 0.5 * (a + b)
    return out
