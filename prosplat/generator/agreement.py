"""How far each input pixel's Gaussian agrees with the other views, for the Gaussian adapter.

Why: refinement's gain over the one pass comes almost all from the Gaussians' opacities (with
opacities frozen, refine 100 gains +0.02 dB at 64 px instead of +0.25; BENCHMARKS "What limits
the depth"): fitting the inputs teaches which view's Gaussian to trust where views overlap.
The adapter that sets opacities sees one pixel's features and colour, nothing of the other
views, so the one pass cannot learn that. These maps give it, per pixel at its predicted
depth, what each neighbour view says about the Gaussian there:

- the colour difference to the neighbours that see the point (not occluded by their own
  depth): a surface at the right depth looks alike from every view that sees it;
- the share of neighbours whose own depth lies behind the point by more than ``tau``: those
  views see through it, so it floats in front of their surface (a free-space violation);
- the share of neighbours whose depth agrees within ``tau``.

The hard rule built on the second (drop such Gaussians, as MVS depth fusion does) lost: the
views' depths disagree where they are wrong, so it removes good surfaces as often as floaters
(BENCHMARKS "Refinement: three probes"). Here training decides how much each cue is worth.
Nothing here is learned, and nothing needs gradients.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.generator.cost_volume import _relative_projection

#: Maps returned per pixel: colour difference, free-space violations, depth agreement.
AGREEMENT_CHANNELS = 3


@torch.no_grad()
def view_agreement(
    images: Tensor, depth: Tensor, K: Tensor, w2c: Tensor, neighbours: Tensor, tau: float = 0.1
) -> Tensor:
    """Per pixel of every view, how its point at ``depth`` agrees with the neighbour views.

    Args:
        images: [B,V,3,H,W] in [0, 1].
        depth: [B,V,H,W] each view's depth (z along its optical axis).
        K: [B,V,3,3] intrinsics at H x W.
        w2c: [B,V,4,4] world-to-camera.
        neighbours: [B,V,k] the views each view is compared with.
        tau: relative depth tolerance of "agrees" and "in front".
    Returns:
        [B,V,3,H,W]: mean absolute colour difference (over RGB) to the neighbours that see the
        point unoccluded (0 where none does), the share of the k neighbours that see behind
        the point, the share whose depth agrees with it.
    """
    b, v, _, h, w = images.shape
    k = neighbours.shape[-1]
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=K.dtype, device=K.device) + 0.5,
        torch.arange(w, dtype=K.dtype, device=K.device) + 0.5,
        indexing="ij",
    )
    pix = torch.stack([xs, ys, torch.ones_like(xs)], dim=0).view(3, h * w)  # [3,HW]
    z = depth.reshape(b, v, 1, h * w).to(K.dtype)  # [B,V,1,HW]
    bidx = torch.arange(b, device=images.device)[:, None]  # [B,1]
    colour_sum = images.new_zeros(b, v, h * w)
    seen = images.new_zeros(b, v, h * w)
    front = images.new_zeros(b, v, h * w)
    agree = images.new_zeros(b, v, h * w)
    for n in range(k):
        nbr = neighbours[..., n]  # [B,V]
        A, off = _relative_projection(K, w2c, nbr)  # [B,V,3,3], [B,V,3]
        p = z * (A @ pix) + off[..., None]  # [B,V,3,HW] in neighbour pixels, homogeneous
        z_j = p[:, :, 2]  # [B,V,HW]
        ahead = z_j > 1e-6 * z[:, :, 0]
        inv = torch.where(ahead, z_j, torch.ones_like(z_j)).reciprocal()
        grid = torch.stack([p[:, :, 0] * inv * (2 / w) - 1, p[:, :, 1] * inv * (2 / h) - 1], -1)
        inside = ahead & (grid.abs() <= 1).all(-1)  # [B,V,HW]
        grid = grid.clamp(-2, 2).to(images.dtype).view(b * v, 1, h * w, 2)
        src = torch.cat([images[bidx, nbr], depth[bidx, nbr][:, :, None]], 2)  # [B,V,4,H,W]
        sampled = F.grid_sample(
            src.flatten(0, 1), grid, mode="bilinear", padding_mode="border", align_corners=False
        ).view(b, v, 4, h * w)  # [B,V,4,HW]
        ratio = z_j / sampled[:, :, 3].clamp(min=1e-6)  # the point's depth / what j sees
        visible = inside & (ratio < 1 + tau)
        diff = (sampled[:, :, :3] - images.reshape(b, v, 3, h * w)).abs().mean(2)  # [B,V,HW]
        colour_sum += diff * visible
        seen += visible
        front += inside & (ratio < 1 - tau)
        agree += inside & ((ratio - 1).abs() <= tau)
    colour = colour_sum / seen.clamp(min=1)
    maps = torch.stack([colour, front / k, agree / k], 2)  # [B,V,3,HW]
    return maps.view(b, v, AGREEMENT_CHANNELS, h, w)
