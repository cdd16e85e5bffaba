"""Small convolutional building blocks shared by the generator's branches.

GroupNorm everywhere (never BatchNorm): training batches are a scene or two, and train/eval
must behave the same. A constant (textureless) input has zero variance, which GroupNorm maps
to zeros through its epsilon, so such inputs stay finite.
"""

from __future__ import annotations

import math

from torch import Tensor, nn


def group_norm(channels: int) -> nn.GroupNorm:
    """GroupNorm with up to 8 groups that divide ``channels``."""
    return nn.GroupNorm(math.gcd(8, channels), channels)


class ConvNormAct(nn.Sequential):
    """3x3 (or ``kernel``) conv -> GroupNorm -> GELU."""

    def __init__(
        self, c_in: int, c_out: int, stride: int = 1, kernel: int = 3, dilation: int = 1
    ) -> None:
        pad = dilation * (kernel - 1) // 2
        super().__init__(
            nn.Conv2d(c_in, c_out, kernel, stride, pad, dilation=dilation, bias=False),
            group_norm(c_out),
            nn.GELU(),
        )


class ResBlock(nn.Module):
    """Two 3x3 convs with a skip; ``dilation`` widens the receptive field at no parameter cost."""

    def __init__(self, channels: int, dilation: int = 1) -> None:
        super().__init__()
        self.body = nn.Sequential(
            ConvNormAct(channels, channels, dilation=dilation),
            nn.Conv2d(channels, channels, 3, 1, dilation, dilation=dilation, bias=False),
            group_norm(channels),
        )
        self.act = nn.GELU()

    def forward(self, x: Tensor) -> Tensor:  # [N,C,H,W] -> [N,C,H,W]
        return self.act(x + self.body(x))
