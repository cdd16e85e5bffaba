"""A frozen ImageNet backbone for the monocular branch: AlexNet's first layers, as LPIPS ships it.

The generator is trained here from scratch on a few hundred rendered scenes, so its monocular
branch only knows what those scenes show. DepthSplat leans on a pretrained monocular network
for the cues matching lacks (texture-poor walls, reflections, what one view sees alone). The
one pretrained CNN this project can get without a model hub is the AlexNet of LPIPS
(:mod:`prosplat.metrics.lpips_weights`); its relu1-3 maps (1/4, 1/8 and 1/16 of the image,
with receptive fields of 11, 51 and 99 pixels) are copied into the generator's own weights
file, so the generator needs nothing else at run time, and are never trained: they are
buffers, not parameters, so no optimiser or ``requires_grad_`` call can change them.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.config import MAX_ALEXNET_LAYERS
from prosplat.metrics.lpips import (
    ALEX_CHANNELS,
    ALEX_SCALE,
    ALEX_SHIFT,
    alexnet_relus,
    unit_normalize,
)

#: Kernel sizes of AlexNet's conv1..conv3.
_KERNELS = (11, 5, 3)


def alexnet_channels(layers: int) -> int:
    """Channels of the concatenated relu1..relu``layers`` maps."""
    return sum(ALEX_CHANNELS[:layers])


class FrozenAlexNet(nn.Module):
    """``[N,3,H,W]`` images in [-1,1] -> ``[N,C,H/4,W/4]``: relu1..relu``layers`` of AlexNet,
    each unit-normalised over channels (as LPIPS compares them: the scale of a layer's
    activations then does not depend on the image's contrast) and resized to 1/4 resolution.

    The weights start at zero: :func:`prosplat.generator.grow.grow_alexnet` fills them from
    the LPIPS file, and a saved generator carries them.
    """

    def __init__(self, layers: int) -> None:
        super().__init__()
        if not 1 <= layers <= MAX_ALEXNET_LAYERS:
            raise ValueError(f"FrozenAlexNet: layers must be 1-{MAX_ALEXNET_LAYERS}, got {layers}")
        self.layers = layers
        for i in range(layers):
            co, ci, k = ALEX_CHANNELS[i], (3, *ALEX_CHANNELS)[i], _KERNELS[i]
            self.register_buffer(f"conv{i + 1}_weight", torch.zeros(co, ci, k, k))
            self.register_buffer(f"conv{i + 1}_bias", torch.zeros(co))
        self.register_buffer("shift", torch.tensor(ALEX_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(ALEX_SCALE).view(1, 3, 1, 1), persistent=False)

    @property
    def out_channels(self) -> int:
        return alexnet_channels(self.layers)

    def forward(self, x: Tensor) -> Tensor:
        h, w = x.shape[-2] // 4, x.shape[-1] // 4
        convs = [
            (getattr(self, f"conv{i}_weight"), getattr(self, f"conv{i}_bias"))
            for i in range(1, self.layers + 1)
        ]
        maps = alexnet_relus((x - self.shift) / self.scale, convs)  # [N,C_l,h_l,w_l] each
        maps = [unit_normalize(m) for m in maps]
        return torch.cat(
            [F.interpolate(m, size=(h, w), mode="bilinear", align_corners=False) for m in maps], 1
        )  # [N,C,H/4,W/4]
