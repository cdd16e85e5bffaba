"""Monocular features: what a single view says about depth on its own.

DepthSplat takes these from a pre-trained monocular depth ViT; they are what keeps depth sane
where matching fails (textureless walls, reflections, occlusions, parts seen by one view). We
train from scratch, so this is a per-view conv branch with dilated residual blocks and a
1/8-resolution context path for a wide receptive field, at the cost-volume resolution (1/4).
With ``alexnet_layers`` it also reads frozen ImageNet features (:mod:`prosplat.generator.alexnet`)
through a small projection whose last layer starts at zero, so a branch grown from trained
weights computes what it computed before until training opens that path.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.alexnet import FrozenAlexNet
from prosplat.generator.layers import ConvNormAct, ResBlock


class MonocularBranch(nn.Module):
    """[N,3,H,W] images in [-1,1] -> [N,Cm,H/4,W/4] monocular features."""

    def __init__(self, channels: int, blocks: int, alexnet_layers: int = 0) -> None:
        super().__init__()
        half = max(channels // 2, 8)
        self.down = nn.Sequential(
            ConvNormAct(3, half, stride=2), ConvNormAct(half, channels, stride=2)
        )  # 1/4
        dilations = (1, 2, 4)
        self.blocks = nn.Sequential(*(ResBlock(channels, dilations[i % 3]) for i in range(blocks)))
        self.context = nn.Sequential(
            ConvNormAct(channels, channels, stride=2), ResBlock(channels, 2)
        )  # 1/8
        self.fuse = nn.Conv2d(2 * channels, channels, 1)
        self.alexnet = self.alexnet_proj = None
        if alexnet_layers:
            self.alexnet = FrozenAlexNet(alexnet_layers)
            self.alexnet_proj = nn.Sequential(
                nn.Conv2d(self.alexnet.out_channels, channels, 1),
                nn.GELU(),
                nn.Conv2d(channels, channels, 1),
            )
            nn.init.zeros_(self.alexnet_proj[2].weight)
            nn.init.zeros_(self.alexnet_proj[2].bias)

    def forward(self, x: Tensor) -> Tensor:
        f = self.blocks(self.down(x))  # [N,Cm,H/4,W/4]
        ctx = F.interpolate(
            self.context(f), size=f.shape[-2:], mode="bilinear", align_corners=False
        )
        out = self.fuse(torch.cat([f, ctx], dim=1))  # [N,Cm,H/4,W/4]
        if self.alexnet is not None:
            out = out + self.alexnet_proj(self.alexnet(x))
        return out
