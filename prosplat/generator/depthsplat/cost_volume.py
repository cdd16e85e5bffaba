"""The plane-sweep cost volume over inverse-depth candidates.

For each reference view and each of its M matched views, the matched view's features are
warped into the reference camera at every candidate depth and correlated with the
reference features (dot product / sqrt(C)); the M correlations are averaged. The candidates
are streamed in chunks so that the [N,M,C,D,H,W] warped volume is never held at once.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

# the most warped feature values held at once (floats); the reference holds all of them
CHUNK_VALUES = 1 << 26


def pixel_grid(h: int, w: int, device, dtype) -> Tensor:
    """[3, h*w] homogeneous integer pixel coordinates (x, y, 1), row-major (the reference
    samples features at integer coordinates with align_corners=True)."""
    ys, xs = torch.meshgrid(
        torch.arange(h, device=device, dtype=dtype),
        torch.arange(w, device=device, dtype=dtype),
        indexing="ij",
    )
    return torch.stack(
        [xs.reshape(-1), ys.reshape(-1), torch.ones(h * w, device=device, dtype=dtype)]
    )


def correlation_volume(
    ref: Tensor, tgt: Tensor, K: Tensor, K_tgt: Tensor, ref_to_tgt: Tensor, depth: Tensor
) -> Tensor:
    """Plane-sweep correlation.

    Args:
        ref: [N,C,H,W] reference features.
        tgt: [N,M,C,H,W] matched views' features.
        K: [N,3,3] reference intrinsics in feature pixels; K_tgt: [N,M,3,3] (the reference
            uses the reference camera's intrinsics for the matched views too; passed
            separately so the caller decides).
        ref_to_tgt: [N,M,4,4] reference-camera to matched-camera transforms.
        depth: [N,D,H,W] or [N,D,1,1] candidate depths (not inverse).
    Returns:
        [N,D,H,W] correlation averaged over the M views.
    """
    n, c, h, w = ref.shape
    m = tgt.shape[1]
    d = depth.shape[1]
    depth = depth.expand(n, d, h, w)
    grid = pixel_grid(h, w, ref.device, ref.dtype)  # [3,HW]
    rays = torch.linalg.inv(K) @ grid  # [N,3,HW] ray per pixel at depth 1
    R = ref_to_tgt[..., :3, :3]  # [N,M,3,3]
    t = ref_to_tgt[..., :3, 3:]  # [N,M,3,1]
    rot_rays = R @ rays[:, None]  # [N,M,3,HW]
    per = max(1, CHUNK_VALUES // max(1, n * m * c * h * w))  # candidates per chunk
    out = []
    # channels-last input: grid_sample gathers each sample's C values contiguously (~2x faster)
    tgt_flat = tgt.reshape(n * m, c, h, w).contiguous(memory_format=torch.channels_last)
    ref_b = ref.contiguous().reshape(n, 1, c, 1, h, w)
    for d0 in range(0, d, per):
        dc = min(per, d - d0)
        z = depth[:, None, d0 : d0 + dc].reshape(n, 1, 1, dc, h * w)  # [N,1,1,Dc,HW]
        pts = rot_rays[:, :, :, None, :] * z + t[..., None]  # [N,M,3,Dc,HW]
        pix = K_tgt[:, :, None] @ pts.reshape(n, m, 3, dc * h * w)[:, :, None]  # [N,M,1,3,DcHW]
        pix = pix[:, :, 0]
        xy = pix[:, :, :2] / pix[:, :, 2:].clamp(min=1e-3)  # [N,M,2,DcHW]
        gx = 2 * xy[:, :, 0] / (w - 1) - 1
        gy = 2 * xy[:, :, 1] / (h - 1) - 1
        g = torch.stack([gx, gy], dim=-1).reshape(n * m, dc * h, w, 2)
        warped = F.grid_sample(
            tgt_flat, g, mode="bilinear", padding_mode="zeros", align_corners=True
        )
        warped = warped.reshape(n, m, c, dc, h, w)
        corr = (warped * ref_b).sum(dim=2).sum(dim=1) / (c**0.5 * m)  # [N,Dc,H,W]
        out.append(corr)
    return torch.cat(out, dim=1)
