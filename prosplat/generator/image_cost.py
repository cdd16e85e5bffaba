"""A plane sweep of the input images themselves: windowed ZNCC against the neighbour views.

Why the generator needs it beside its learned cost volume: the learned matching features
pick the right region among the 32 planes over near-far, but they cannot rank depths a few
planes apart. Where the truth lies within two planes of the depth head's estimate, the
features' correlation peaks farther from it than a random candidate does (BENCHMARKS "A
learned band search"), and a learned second search on them did not train. The test-time
depth sweep (:mod:`prosplat.pipeline.depth_sweep`) gains because it correlates the images: the pixels
themselves rank nearby depths wherever there is texture, and that carries over to real
photos. This volume gives the depth head that signal at every plane, from the first step.

Per reference pixel and candidate plane, the ZNCC of the ``window`` x ``window`` patch (the
three channels as one vector) against each neighbour's image warped to that plane, averaged
over the neighbours in whose image the point lands, then averaged down to the depth head's
1/4 resolution. Flat patches correlate to about 0 (``ZNCC_EPS``), not to their noise.
Nothing here is learned, and nothing needs gradients (the inputs are images and cameras).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.generator.cost_volume import planes_per_chunk, warp_grid
from prosplat.geometry.matching import patch_mean_var, window_zncc

#: Added to var_ref · var_src (images in [0, 1], variances summed over the channels): two
#: patches with a standard deviation of 0.1 correlate at most 1/√2, of 0.03 at most 0.09, so
#: flat patches (a wall with a render's noise) say little whatever their noise does.
ZNCC_EPS = 1e-4


@torch.no_grad()
def image_cost_volume(
    images: Tensor,
    K: Tensor,
    w2c: Tensor,
    depths: Tensor,
    neighbours: Tensor,
    window: int,
    pool: int,
) -> Tensor:
    """ZNCC plane sweep of the images.

    Args:
        images: [B,V,3,H,W] in [0, 1].
        K: [B,V,3,3] intrinsics at H x W.
        w2c: [B,V,4,4] world-to-camera.
        depths: [B,D] candidate depths (the learned cost volume's planes), or [B,V,D,H,W]
            each pixel's own candidates (a band around a depth map).
        neighbours: [B,V,k] the views each view is matched against.
        window: the ZNCC window in pixels (odd).
        pool: the result is averaged over ``pool`` x ``pool`` cells (H and W divisible by it).
    Returns:
        [B,V,D,H/pool,W/pool] mean ZNCC in [-1, 1]; 0 where no neighbour sees the point.
    """
    b, v, c, h, w = images.shape
    d = depths.shape[-3] if depths.ndim == 5 else depths.shape[1]
    if h % pool or w % pool:
        raise ValueError(f"image_cost_volume: {w}x{h} is not divisible by pool={pool}")
    ref = images.flatten(0, 1)  # [BV,C,H,W]
    mu_r, var_r = patch_mean_var(ref, window)  # [BV,C,H,W], [BV,H,W]
    # against every plane: [BV,C,1,H,W] x2 and [BV,1,H,W]
    ref_d, mu_r_d, var_r_d = ref[:, :, None], mu_r[:, :, None], var_r[:, None]
    bidx = torch.arange(b, device=images.device)[:, None]  # [B,1]
    total = images.new_zeros(b * v, d, h, w)
    seen = images.new_zeros(b * v, d, h, w)
    per = planes_per_chunk(b * v * (c + 2) * h * w)  # the ZNCC's statistics per plane
    for n in range(neighbours.shape[-1]):
        nbr = neighbours[..., n]  # [B,V]
        grid = warp_grid(K, w2c, nbr, depths, h, w).to(images.dtype)  # [B,V,D,H,W,2]
        inside = (grid.abs().amax(-1) <= 1).reshape(b * v, d, h, w).to(images.dtype)
        src = images[bidx, nbr].reshape(b * v, c, h, w)  # [BV,C,H,W]
        for d0 in range(0, d, per):  # a chunk of planes at a time: see PLANE_CHUNK_VALUES
            dc = min(per, d - d0)
            part = grid[:, :, d0 : d0 + dc].reshape(b * v, dc * h, w, 2)
            warped = F.grid_sample(src, part, align_corners=False).view(b * v, c, dc, h, w)
            zncc, _ = window_zncc(warped, ref_d, mu_r_d, var_r_d, window, ZNCC_EPS)  # [BV,Dc,H,W]
            total[:, d0 : d0 + dc].addcmul_(zncc, inside[:, d0 : d0 + dc])
        seen = seen + inside
    mean = total / seen.clamp(min=1)  # [BV,D,H,W]
    return F.avg_pool2d(mean, pool).view(b, v, d, h // pool, w // pool)
