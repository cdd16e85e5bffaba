"""Depth from the cost volume and monocular cues, then up to full resolution.

A 2D U-Net over ``concat(cost volume, monocular features, matching features)`` at 1/4
resolution gives logits over the D candidates; their softmax is a per-pixel distribution and
depth is its expectation. The expectation is taken in **normalised inverse depth**
``t = (1/z - 1/far) / (1/near - 1/far)`` (1 at near, 0 at far): candidates are uniform in 1/z,
so the expectation interpolates between neighbouring candidates linearly in disparity, and
``t`` stays in [0, 1] so depth always lies in [near, far]. Confidence is the largest
probability (1/D when the volume is flat, 1 when one candidate wins).

Upsampling: bilinear x4 of ``t`` (smooth, in the space where it is linear in pixel shifts) plus
a learned full-resolution correction added in logit(t) space (keeps t in (0, 1)), predicted by
a small conv net that sees the image, so depth edges can snap to colour edges. That net's
features also feed the Gaussian adapter.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.layers import ConvNormAct, ResBlock


class UNet(nn.Module):
    """[N,c_in,h,w] -> [N,channels[0],h,w]; level i runs at 1/2^i of the input size."""

    def __init__(self, c_in: int, channels: tuple[int, ...]) -> None:
        super().__init__()
        ch = channels
        self.inc = nn.Sequential(ConvNormAct(c_in, ch[0]), ResBlock(ch[0]))
        self.downs = nn.ModuleList(
            nn.Sequential(ConvNormAct(ch[i], ch[i + 1], stride=2), ResBlock(ch[i + 1]))
            for i in range(len(ch) - 1)
        )
        self.ups = nn.ModuleList(
            nn.Sequential(ConvNormAct(ch[i + 1] + ch[i], ch[i]), ResBlock(ch[i]))
            for i in range(len(ch) - 1)
        )

    def forward(self, x: Tensor) -> Tensor:
        skips = [self.inc(x)]  # level 0: [N,ch0,h,w]
        for down in self.downs:
            skips.append(down(skips[-1]))  # level i+1 at half the size
        y = skips.pop()
        for up, skip in zip(reversed(self.ups), reversed(skips)):
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = up(torch.cat([y, skip], dim=1))
        return y  # [N,ch0,h,w]


class DepthHead(nn.Module):
    """Cost volume + monocular + matching features -> depth distribution at 1/4 resolution.

    With ``fine_cost`` a second, 1/2-resolution cost volume over the same candidates comes in
    through a stride-2 conv (learned pooling that keeps the peak's position along D) and, average
    pooled, as a second matching prior on the logits. With ``image_cost`` the images' own ZNCC
    plane sweep (1/4 resolution, the same candidates) comes in as D more U-Net channels and a
    third prior.
    """

    def __init__(
        self,
        depth_candidates: int,
        mono_channels: int,
        feature_channels: int,
        unet,
        fine_cost: bool = False,
        image_cost: bool = False,
    ):
        super().__init__()
        d = depth_candidates
        self.fine_pool = (
            nn.Sequential(nn.Conv2d(d, d, 3, stride=2, padding=1), nn.GELU()) if fine_cost else None
        )
        c_in = d * (1 + int(fine_cost) + int(image_cost)) + mono_channels + feature_channels
        self.unet = UNet(c_in, unet)
        self.logits = nn.Conv2d(unet[0], d, 3, padding=1)
        # The raw correlation is also added to the logits: a matching prior from step one. A flat
        # (zero-baseline) volume shifts all logits equally, so softmax ignores it.
        self.cost_gain = nn.Parameter(torch.ones(()))
        self.fine_gain = nn.Parameter(torch.ones(())) if fine_cost else None
        self.image_gain = nn.Parameter(torch.ones(())) if image_cost else None

    def forward(
        self,
        cost: Tensor,
        mono: Tensor,
        feats: Tensor,
        fine: Tensor | None = None,
        image: Tensor | None = None,
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """cost [N,D,h,w], mono [N,Cm,h,w], feats [N,C,h,w], fine [N,D,2h,2w] or None, image
        [N,D,h,w] or None -> t [N,1,h,w] normalised inverse depth, confidence [N,1,h,w],
        hidden [N,U0,h,w], logits [N,D,h,w] (candidates near to far, the prior included: what
        a loss on the distribution itself needs)."""
        d = cost.shape[1]
        if (fine is None) != (self.fine_pool is None):
            raise ValueError("DepthHead: pass the fine cost volume exactly when built with it")
        if (image is None) != (self.image_gain is None):
            raise ValueError("DepthHead: pass the image cost volume exactly when built with it")
        parts = [cost]  # the order the U-Net's first conv (and grow.py) expects
        prior = self.cost_gain * cost  # [N,D,h,w]
        if fine is not None:
            parts.append(self.fine_pool(fine))  # [N,D,h,w]
            prior = prior + self.fine_gain * F.avg_pool2d(fine, 2)
        if image is not None:
            parts.append(image)  # [N,D,h,w]
            prior = prior + self.image_gain * image
        parts += [mono, feats]
        hidden = self.unet(torch.cat(parts, dim=1))  # [N,U0,h,w]
        logits = self.logits(hidden) + prior  # [N,D,h,w]
        prob = torch.softmax(logits, dim=1)  # [N,D,h,w]
        t_cand = torch.linspace(1.0, 0.0, d, dtype=cost.dtype, device=cost.device)  # near->far
        t = (prob * t_cand[None, :, None, None]).sum(1, keepdim=True)  # [N,1,h,w] in [0,1]
        conf = prob.amax(1, keepdim=True)  # [N,1,h,w] in [1/D,1]
        return t, conf, hidden, logits


class DepthRefiner(nn.Module):
    """Upsample t and confidence to full resolution and correct t with a learned residual."""

    def __init__(self, hidden_channels: int, channels: int) -> None:
        super().__init__()
        self.reduce = nn.Conv2d(hidden_channels, channels, 1)
        self.body = nn.Sequential(ConvNormAct(3 + 2 + channels, channels), ResBlock(channels))
        self.delta = nn.Conv2d(channels, 1, 3, padding=1)
        with torch.no_grad():  # start close to plain bilinear upsampling
            self.delta.weight.mul_(0.1)
            self.delta.bias.zero_()

    def forward(
        self, image: Tensor, t: Tensor, conf: Tensor, hidden: Tensor
    ) -> tuple[Tensor, Tensor, Tensor]:
        """image [N,3,H,W] in [-1,1]; t, conf [N,1,h,w]; hidden [N,U0,h,w] ->
        t [N,1,H,W] in (0,1), confidence [N,1,H,W], features [N,R,H,W]."""
        size = image.shape[-2:]

        def up(x: Tensor) -> Tensor:
            return F.interpolate(x, size=size, mode="bilinear", align_corners=False)

        t_up, conf_up = up(t), up(conf)  # [N,1,H,W] each
        f_up = up(self.reduce(hidden))  # [N,R,H,W]
        feat = self.body(torch.cat([image, t_up, conf_up, f_up], dim=1))  # [N,R,H,W]
        eps = 1e-4  # t of exactly 0 or 1 (all mass on the end candidate) has an infinite logit
        t_ref = torch.sigmoid(torch.logit(t_up.clamp(eps, 1 - eps)) + self.delta(feat))
        return t_ref, conf_up, feat
