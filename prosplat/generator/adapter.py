"""Per-pixel Gaussian adapter: depth + features -> one 3D Gaussian per input pixel.

Each pixel's Gaussian sits on its own ray: pixel centre (c + 0.5, r + 0.5) plus a learned
sub-pixel offset (tanh-bounded), lifted to the predicted depth z along the optical axis and
taken to world coordinates with the input camera. Scales are tied to the pixel footprint
``z / f`` (the world size of one pixel at that depth) times a learned factor in
``[scale_factor_min, scale_factor_max]`` (log-uniform through a sigmoid), so Gaussians neither
vanish between pixels nor balloon, at any scene scale. Rotations are predicted in the camera
frame and turned into world quaternions. Colour starts as the pixel's own colour (SH DC of
``(rgb - 0.5) / C0``) plus a learned residual; higher SH bands start at zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from prosplat.core.gaussians import rgb_to_sh0
from prosplat.core.rotations import quat_multiply, rotmat_to_quat


def normalize_quat(q: Tensor, eps: float = 1e-6) -> Tensor:
    """[...,4] -> unit quaternions; a (near-)zero one becomes the identity, never NaN."""
    n = q.norm(dim=-1, keepdim=True)
    ident = torch.zeros_like(q)
    ident[..., 0] = 1.0
    return torch.where(n > eps, q / n.clamp_min(eps), ident)


def unproject_pixels(uv: Tensor, depth: Tensor, K: Tensor, w2c: Tensor) -> Tensor:
    """World points of pixels ``uv [N,H,W,2]`` (centres at +0.5) at depth z ``[N,H,W]``
    (along the optical axis), with ``K [N,3,3]``, ``w2c [N,4,4]`` -> ``[N,H,W,3]``.
    Same maths as :meth:`prosplat.Camera.unproject`, batched over cameras."""
    fx, fy = K[:, 0, 0, None, None], K[:, 1, 1, None, None]  # [N,1,1]
    cx, cy, skew = K[:, 0, 2, None, None], K[:, 1, 2, None, None], K[:, 0, 1, None, None]
    y = (uv[..., 1] - cy) / fy  # [N,H,W]
    x = (uv[..., 0] - cx - skew * y) / fx  # [N,H,W]
    pc = torch.stack([x * depth, y * depth, depth], dim=-1)  # [N,H,W,3] camera space
    R, t = w2c[:, :3, :3], w2c[:, :3, 3]  # [N,3,3], [N,3]
    return torch.einsum("nhwi,nij->nhwj", pc - t[:, None, None, :], R)  # R^T (p - t)


@dataclass
class PixelGaussians:
    """Per-pixel Gaussian parameters of N views, each ``[N,H,W,...]``."""

    means: Tensor  # [N,H,W,3]
    quats: Tensor  # [N,H,W,4]
    scales: Tensor  # [N,H,W,3]
    opacities: Tensor  # [N,H,W]
    sh: Tensor  # [N,H,W,K,3]


class GaussianAdapter(nn.Module):
    """Full-resolution features + depth + camera -> per-pixel Gaussians."""

    #: raw head channels: opacity 1, offset 2, scale 3, rotation 4, SH DC residual 3
    HEAD = (1, 2, 3, 4, 3)

    def __init__(
        self,
        channels: int,
        sh_degree: int,
        scale_factor_min: float,
        scale_factor_max: float,
        max_offset_px: float,
    ) -> None:
        super().__init__()
        self.k = (sh_degree + 1) ** 2
        self.log_scale_min = math.log(scale_factor_min)
        self.log_scale_max = math.log(scale_factor_max)
        self.max_offset_px = max_offset_px
        self.hidden = nn.Sequential(nn.Conv2d(channels + 1 + 3, channels, 1), nn.GELU())
        self.head = nn.Conv2d(channels, sum(self.HEAD), 1)
        with torch.no_grad():  # start near neutral: no offset, factor ~1, identity, pixel colour
            self.head.weight.mul_(0.1)
            self.head.bias.zero_()
        self.sh_rest = None
        if self.k > 1:
            self.sh_rest = nn.Conv2d(channels, 3 * (self.k - 1), 1)
            nn.init.zeros_(self.sh_rest.weight)
            nn.init.zeros_(self.sh_rest.bias)

    def forward(
        self, feats: Tensor, conf: Tensor, rgb: Tensor, depth: Tensor, K: Tensor, w2c: Tensor
    ) -> PixelGaussians:
        """feats [N,R,H,W]; conf [N,1,H,W]; rgb [N,3,H,W] in [0,1]; depth [N,H,W] (z);
        K [N,3,3] at full resolution; w2c [N,4,4]."""
        n, _, h, w = feats.shape
        hid = self.hidden(torch.cat([feats, conf, rgb], dim=1))  # [N,R,H,W]
        raw = self.head(hid).permute(0, 2, 3, 1)  # [N,H,W,13]
        r_op, r_off, r_scale, r_rot, r_dc = raw.split(self.HEAD, dim=-1)

        opacities = torch.sigmoid(r_op[..., 0])  # [N,H,W]

        offset = self.max_offset_px * torch.tanh(r_off)  # [N,H,W,2] pixels
        ys, xs = torch.meshgrid(
            torch.arange(h, dtype=feats.dtype, device=feats.device) + 0.5,
            torch.arange(w, dtype=feats.dtype, device=feats.device) + 0.5,
            indexing="ij",
        )
        uv = torch.stack([xs, ys], dim=-1) + offset  # [N,H,W,2]
        means = unproject_pixels(uv, depth, K, w2c)  # [N,H,W,3]

        footprint = depth / torch.sqrt(K[:, 0, 0] * K[:, 1, 1])[:, None, None]  # [N,H,W]
        span = self.log_scale_max - self.log_scale_min
        factor = torch.exp(self.log_scale_min + span * torch.sigmoid(r_scale))  # [N,H,W,3]
        scales = footprint[..., None] * factor  # [N,H,W,3]

        ident = r_rot.new_tensor([1.0, 0.0, 0.0, 0.0])
        q_cam = normalize_quat(r_rot + ident)  # [N,H,W,4] camera frame, identity at init
        q_c2w = rotmat_to_quat(w2c[:, :3, :3].transpose(1, 2))  # [N,4]
        quats = normalize_quat(quat_multiply(q_c2w[:, None, None, :], q_cam))  # [N,H,W,4]

        dc = rgb_to_sh0(rgb.permute(0, 2, 3, 1)) + r_dc  # [N,H,W,3]
        sh = dc[..., None, :]  # [N,H,W,1,3]
        if self.sh_rest is not None:
            rest = self.sh_rest(hid).permute(0, 2, 3, 1).reshape(n, h, w, self.k - 1, 3)
            sh = torch.cat([sh, rest], dim=-2)  # [N,H,W,K,3]
        return PixelGaussians(means, quats, scales, opacities, sh)
