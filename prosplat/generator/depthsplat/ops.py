"""Small layout-aware helpers: the model runs channels-last (oneDNN's fast convolution
layout), where a few stock ops would copy to and from NCHW."""

from __future__ import annotations

import torch
from torch import Tensor, nn

CL = torch.channels_last


def cat_channels(tensors: list[Tensor]) -> Tensor:
    """torch.cat on dim 1 with every input channels-last (mixed layouts take a slow path)."""
    return torch.cat([t.contiguous(memory_format=CL) for t in tensors], dim=1)


class InstanceNorm(nn.Module):
    """nn.InstanceNorm2d(affine=False) computed in place of layout: (x - mean) / sqrt(var + eps)
    over H and W (the stock op reshapes to [1, N*C, H, W] and copies channels-last input)."""

    def __init__(self, eps: float = 1e-5):
        super().__init__()
        self.eps = eps

    def forward(self, x: Tensor) -> Tensor:
        var, mean = torch.var_mean(x, dim=(2, 3), keepdim=True, correction=0)
        return (x - mean) * torch.rsqrt(var + self.eps)
