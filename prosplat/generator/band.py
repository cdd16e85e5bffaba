"""A learned depth sweep: the generator's own depth moved to where the input images match.

Why here, and why the images: the generator's output depth is already close (at 64-128 px on
the validation scenes its inverse depth is within 1.5 of the cost volume's plane steps of the
truth for two thirds of the pixels; ``benchmarks/plane_peaks.py``), and what is left is a
correction of a few per cent that its learned features cannot rank (BENCHMARKS "A learned
band search") but the pixels can: the test-time depth sweep (:mod:`prosplat.pipeline.depth_sweep`)
gains +0.15 / +0.27 dB enhanced at 64 / 128 px by correlating the images in a ±30 % band
around that depth, with hand-set rules for when to trust a peak. This module runs the same
search inside the network and learns the rules: per pixel, at half the matching size,
``candidates`` depths from ``depth·e^-BAND_SPAN`` to ``depth·e^+BAND_SPAN`` are scored by the
ZNCC of the images against the neighbour views (:func:`image_cost_volume`), and a small conv
net reads those scores beside the depth refiner's features and gives a log-depth correction
bounded by the band. Its last convolution starts at zero, so a generator grown by it
(:func:`prosplat.generator.grow.grow_band`) starts from its exact outputs.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.cost_volume import scale_intrinsics
from prosplat.generator.image_cost import image_cost_volume
from prosplat.generator.layers import ConvNormAct, ResBlock

#: Half-width of the band in log depth (±30 %: the test-time sweep's span, which covers the
#: generator's usual error).
BAND_SPAN = 0.3
#: The ZNCC window, in pixels at half the matching size.
BAND_WINDOW = 5


class BandRefiner(nn.Module):
    """``forward(images [B,V,3,H,W] in [0,1], depth [B,V,H,W], features [BV,R,H,W], K at H x W,
    w2c, neighbours [B,V,k]) -> depth [B,V,H,W]`` moved by at most ``BAND_SPAN`` in log."""

    def __init__(self, candidates: int, feature_channels: int) -> None:
        super().__init__()
        if candidates < 2:
            raise ValueError(f"BandRefiner needs >= 2 candidates, got {candidates}")
        self.candidates = candidates
        width = max(16, feature_channels)
        self.body = nn.Sequential(
            ConvNormAct(candidates + feature_channels, width), ResBlock(width)
        )
        self.delta = nn.Conv2d(width, 1, 3, padding=1)
        with torch.no_grad():  # closed at the start: the depth passes through unchanged
            self.delta.weight.zero_()
            self.delta.bias.zero_()

    def scores(
        self, images: Tensor, depth: Tensor, K: Tensor, w2c: Tensor, neighbours: Tensor
    ) -> Tensor:
        """The band's ZNCC at half size: [B,V,n,H/2,W/2] (n candidates, nearest first)."""
        b, v, _, h, w = images.shape
        hh, wh = h // 2, w // 2
        half = F.interpolate(
            images.flatten(0, 1), size=(hh, wh), mode="bilinear", antialias=True
        ).clamp(0, 1)  # [BV,3,H/2,W/2]
        inv = F.avg_pool2d(1 / depth.flatten(0, 1)[:, None], 2)  # [BV,1,H/2,W/2] mean 1/z
        offsets = torch.linspace(
            -BAND_SPAN, BAND_SPAN, self.candidates, dtype=depth.dtype, device=depth.device
        )
        band = (1 / inv).view(b, v, 1, hh, wh) * offsets.exp().view(1, 1, -1, 1, 1)
        K_half = scale_intrinsics(K, wh / w, hh / h)
        return image_cost_volume(
            half.view(b, v, 3, hh, wh), K_half, w2c, band.detach(), neighbours, BAND_WINDOW, 1
        )

    def forward(
        self,
        images: Tensor,
        depth: Tensor,
        features: Tensor,
        K: Tensor,
        w2c: Tensor,
        neighbours: Tensor,
    ) -> Tensor:
        b, v, h, w = depth.shape
        zncc = self.scores(images, depth, K, w2c, neighbours).flatten(0, 1)  # [BV,n,H/2,W/2]
        x = torch.cat([zncc, F.avg_pool2d(features, 2)], 1)  # [BV,n+R,H/2,W/2]
        step = BAND_SPAN * torch.tanh(self.delta(self.body(x)))  # [BV,1,H/2,W/2] log depth
        step = F.interpolate(step, size=(h, w), mode="bilinear", align_corners=False)
        return depth * step.view(b, v, h, w).exp()
