"""The CNN feature extractor: a 7x7 stem and three stages of two residual blocks each, with
instance normalisation. Outputs at 1/2, 1/2 or 1/4, and 1/4 or 1/8 of the input."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.depthsplat.ops import InstanceNorm


class ResidualBlock(nn.Module):
    """conv3x3-IN-ReLU twice, plus the input (through a strided 1x1 conv where the shape changes)."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1, bias=False)
        self.norm1 = InstanceNorm()
        self.norm2 = InstanceNorm()
        self.downsample = None
        if stride != 1 or cin != cout:
            # index 0 is the conv; index 1 an instance norm (no parameters), as in the
            # checkpoints' key layout ("downsample.0.weight")
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride), InstanceNorm())

    def forward(self, x: Tensor) -> Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = F.relu(self.norm2(self.conv2(y)))
        skip = x if self.downsample is None else self.downsample(x)
        return F.relu(skip + y)


class CNNBackbone(nn.Module):
    """images [N,3,H,W] (ImageNet-normalised) -> features high to low resolution:
    [N,64,H/2,W/2], [N,96,H/s,W/s], [N,out,H/2s,W/2s] with s = lowest_scale / 2."""

    def __init__(self, out_channels: int = 128, lowest_scale: int = 4):
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.norm1 = InstanceNorm()
        self.layer1 = nn.Sequential(ResidualBlock(64, 64), ResidualBlock(64, 64))
        stride2 = 1 if lowest_scale == 4 else 2
        self.layer2 = nn.Sequential(ResidualBlock(64, 96, stride2), ResidualBlock(96, 96))
        self.layer3 = nn.Sequential(ResidualBlock(96, 128, 2), ResidualBlock(128, 128))
        self.conv2 = nn.Conv2d(128, out_channels, 1)

    def forward(self, x: Tensor) -> list[Tensor]:
        x = F.relu(self.norm1(self.conv1(x)))
        f1 = self.layer1(x)  # [N,64,H/2,W/2]
        f2 = self.layer2(f1)  # [N,96,H/2 or H/4, ...]
        f3 = self.conv2(self.layer3(f2))  # [N,128,H/4 or H/8, ...]
        return [f1, f2, f3]
