"""A ViTDet-style simple feature pyramid: the input as it is, plus 2x (and 4x) upsampled copies
with halved (quartered) channels. Used by the 2-scale models for the multi-view and the
monocular features."""

from __future__ import annotations

from torch import Tensor, nn


class FeaturePyramid(nn.Module):
    """x [N,C,h,w] -> [x, [N,C/2,2h,2w], ...] (low to high resolution)."""

    def __init__(self, channels: int, num_scales: int):
        super().__init__()
        self.stages = nn.ModuleList()
        for i in range(num_scales):
            factor = 2**i
            if factor == 1:
                self.stages.append(nn.Sequential())
            elif factor == 2:
                c = channels // 2
                self.stages.append(
                    nn.Sequential(
                        nn.ConvTranspose2d(channels, c, 2, 2), nn.GELU(), nn.Conv2d(c, c, 3, 1, 1)
                    )
                )
            elif factor == 4:
                c2, c4 = channels // 2, channels // 4
                self.stages.append(
                    nn.Sequential(
                        nn.ConvTranspose2d(channels, c2, 2, 2),
                        nn.GELU(),
                        nn.ConvTranspose2d(c2, c4, 2, 2),
                        nn.GELU(),
                        nn.Conv2d(c4, c4, 3, 1, 1),
                    )
                )
            else:
                raise ValueError(f"pyramid factor {factor} not supported")

    def forward(self, x: Tensor) -> list[Tensor]:
        return [stage(x) for stage in self.stages]
