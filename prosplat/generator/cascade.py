"""A second, narrow cost volume at 1/2 resolution around the depth head's first estimate.

The depth head picks depth among D planes spread over the whole [near, far] range at 1/4
resolution; a pixel whose true depth falls between two planes, or whose 1/4-resolution cell
straddles an edge, is left to the expectation's interpolation. Cascade MVS networks (and our
own test-time depth sweep, :mod:`prosplat.depth_sweep`) search again in a narrow band around
the first estimate at a finer resolution. Here that search is learned: each 1/2-resolution
pixel gets ``candidates`` depths within ``BAND_STEPS`` coarse candidate steps of the upsampled
estimate (in normalised inverse depth t, where the coarse planes are uniform), the fine
matching features are correlated there against the same neighbours, and a small conv net turns
that band's correlation into a distribution whose expectation is a correction of t.

The correction enters through zeros (last conv and the correlation's logit gain start at 0, so
the band's distribution starts uniform and its expected offset is exactly 0): a generator grown
with this stage (:func:`prosplat.generator.grow.grow_cascade`) starts as the one it grew from.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.layers import ConvNormAct, ResBlock

#: Half-width of the band, in steps of the coarse candidates (1 / (D - 1) in t).
BAND_STEPS = 2.0

#: Kept away from t = 0 and 1 (depth exactly far or near) when a band candidate is warped.
_T_EPS = 1e-4


class CascadeStage(nn.Module):
    """Band candidates around a first t, and the learned correction from their correlation."""

    def __init__(
        self,
        candidates: int,
        coarse_candidates: int,
        hidden_channels: int,
        fine_channels: int,
        channels: int = 24,
    ) -> None:
        super().__init__()
        if candidates < 2:
            raise ValueError(f"CascadeStage needs >= 2 candidates, got {candidates}")
        step = 1.0 / (coarse_candidates - 1)
        offsets = torch.linspace(-BAND_STEPS * step, BAND_STEPS * step, candidates)
        self.register_buffer("offsets", offsets, persistent=False)  # [Dc] in t, symmetric
        self.reduce = nn.Conv2d(hidden_channels, channels, 1)
        self.body = nn.Sequential(
            ConvNormAct(candidates + channels + fine_channels, channels), ResBlock(channels)
        )
        self.logits = nn.Conv2d(channels, candidates, 3, padding=1)
        self.cost_gain = nn.Parameter(torch.zeros(()))
        with torch.no_grad():  # start uniform: the expected offset is exactly 0
            self.logits.weight.zero_()
            self.logits.bias.zero_()

    def band(self, t: Tensor) -> Tensor:
        """t [N,1,h,w] -> [N,Dc,h,w] the band's candidates in t, clamped inside (0, 1) so each
        is a depth in [near, far] that can be warped (no gradient: where to look, not what)."""
        return (t.detach() + self.offsets[None, :, None, None]).clamp(_T_EPS, 1 - _T_EPS)

    def forward(self, cost: Tensor, hidden: Tensor, fine: Tensor) -> Tensor:
        """cost [N,Dc,h,w] the band's correlation, hidden [N,U0,h/2,w/2] the depth head's
        features, fine [N,Cf,h,w] the view's own fine matching features -> delta [N,1,h,w], the
        correction of t (the expected offset; at the band's clamped ends the warped candidate
        sits inside (0, 1) but the offset is the unclamped one, which the refiner's clamp
        bounds)."""
        hid = F.interpolate(
            self.reduce(hidden), size=cost.shape[-2:], mode="bilinear", align_corners=False
        )  # [N,c,h,w]
        feat = self.body(torch.cat([cost, hid, fine], dim=1))  # [N,c,h,w]
        prob = torch.softmax(self.logits(feat) + self.cost_gain * cost, dim=1)  # [N,Dc,h,w]
        return (prob * self.offsets[None, :, None, None]).sum(1, keepdim=True)  # [N,1,h,w]
