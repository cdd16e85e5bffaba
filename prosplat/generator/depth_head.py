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

Optional (``GeneratorConfig.convex_upsampling``): the x4 step reweights, per full-resolution
pixel, the four low-resolution samples that bilinear interpolation reads, with weights a
convolution of the refiner's features predicts (a softmax around the bilinear weights, which
it reproduces exactly at zero). Why: a bilinear ramp between a foreground and a background
cell puts every pixel of a 1/4-resolution edge at an in-between depth, which other views see as
a skirt from the object down to the floor. Blender's true depth averaged to 1/4 resolution and
upsampled bilinearly loses 2.0 dB of the true-depth bound at 128 px (21.76 -> 19.77 dB, raw
views filled); picking the best of the same four samples per pixel loses 0.7 (21.08).
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
    ) -> tuple[Tensor, Tensor, Tensor]:
        """cost [N,D,h,w], mono [N,Cm,h,w], feats [N,C,h,w], fine [N,D,2h,2w] or None, image
        [N,D,h,w] or None -> t [N,1,h,w] normalised inverse depth, confidence [N,1,h,w],
        hidden [N,U0,h,w]."""
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
        return t, conf, hidden


def bilinear_support(n_low: int, n_high: int, device=None) -> tuple[Tensor, Tensor, Tensor]:
    """Along one axis, where ``F.interpolate(mode="bilinear", align_corners=False)`` from
    ``n_low`` to ``n_high`` samples reads: ``i0, i1 [n_high]`` (long) the two source indices
    and ``frac [n_high]`` the weight of ``i1`` (source coordinates below 0 clamp to 0, indices
    above ``n_low - 1`` to it, as torch does)."""
    src = ((torch.arange(n_high, device=device) + 0.5) * (n_low / n_high) - 0.5).clamp(min=0)
    i0 = src.floor().long().clamp(max=n_low - 1)
    i1 = (i0 + 1).clamp(max=n_low - 1)
    return i0, i1, src - i0


def convex_upsample(t: Tensor, logits: Tensor) -> Tensor:
    """t [N,1,h,w], logits [N,4,H,W] -> [N,1,H,W]: each full-resolution pixel a convex
    combination of the four samples of ``t`` that bilinear interpolation reads (rows i0/i1 x
    columns i0/i1, in that order), weighted by ``softmax(log w_bilinear + logits)``. Zero
    logits give bilinear interpolation (to ~1e-6 where a bilinear weight is 0)."""
    h, w = t.shape[-2:]
    big_h, big_w = logits.shape[-2:]
    y0, y1, fy = bilinear_support(h, big_h, t.device)
    x0, x1, fx = bilinear_support(w, big_w, t.device)
    wy = torch.stack([1 - fy, fy]).to(t.dtype)  # [2,H]
    wx = torch.stack([1 - fx, fx]).to(t.dtype)  # [2,W]
    prior = (wy[:, None, :, None] * wx[None, :, None, :]).reshape(4, big_h, big_w)  # [4,H,W]
    weights = torch.softmax(prior.clamp(min=1e-6).log() + logits, dim=1)  # [N,4,H,W]
    samples = torch.cat(
        [t[:, :, ys][:, :, :, xs] for ys in (y0, y1) for xs in (x0, x1)], dim=1
    )  # [N,4,H,W]
    return (weights * samples).sum(1, keepdim=True)


class DepthRefiner(nn.Module):
    """Upsample t and confidence to full resolution and correct t with a learned residual;
    ``convex``: t's upsampling weights are learned too (:func:`convex_upsample`)."""

    def __init__(self, hidden_channels: int, channels: int, convex: bool = False) -> None:
        super().__init__()
        self.reduce = nn.Conv2d(hidden_channels, channels, 1)
        self.body = nn.Sequential(ConvNormAct(3 + 2 + channels, channels), ResBlock(channels))
        self.delta = nn.Conv2d(channels, 1, 3, padding=1)
        with torch.no_grad():  # start close to plain bilinear upsampling
            self.delta.weight.mul_(0.1)
            self.delta.bias.zero_()
        self.mask = nn.Conv2d(channels, 4, 3, padding=1) if convex else None
        if self.mask is not None:  # zero: exactly bilinear until training opens it
            nn.init.zeros_(self.mask.weight)
            nn.init.zeros_(self.mask.bias)

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
        if self.mask is not None:
            t_up = convex_upsample(t, self.mask(feat))  # [N,1,H,W]
        eps = 1e-4  # t of exactly 0 or 1 (all mass on the end candidate) has an infinite logit
        t_ref = torch.sigmoid(torch.logit(t_up.clamp(eps, 1 - eps)) + self.delta(feat))
        return t_ref, conf_up, feat
