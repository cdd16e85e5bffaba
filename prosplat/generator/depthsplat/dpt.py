"""The DPT heads: one upsamples the low-resolution inverse depth to full resolution (a
residual added to the bilinear upsampling), the other produces full-resolution features for
the Gaussian head. Both fuse the four ViT taps (reassembled at 1/2, 1/4, 1/8, 1/16) with the
CNN and multi-view features at the matching resolutions.

Which features join at which level depends on (upsample_factor, num_scales):

| case  | 1/2 (or full/2)                 | 1/4                        | 1/8                 |
|-------|---------------------------------|----------------------------|---------------------|
| (4,1) | cnn64, cnn96, vit               | cnn128, vit, mv128, depth  | vit                 |
| (2,2) | cnn64, cnn96, mv64, depth, vit  | cnn128, vit, mv128         | vit                 |
| (4,2) | cnn64, vit                      | cnn96, vit, mv64, depth    | cnn128, vit, mv128  |
| (8,1) | cnn64, vit                      | cnn96, vit                 | cnn128, vit, mv128, depth |

("depth" only in the depth upsampler.)
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.depthsplat.ops import cat_channels


class ResidualConvUnit(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.conv1 = nn.Conv2d(c, c, 3, padding=1)
        self.conv2 = nn.Conv2d(c, c, 3, padding=1)

    def forward(self, x: Tensor) -> Tensor:
        return x + self.conv2(F.relu(self.conv1(F.relu(x))))


class FusionBlock(nn.Module):
    """(coarser path [+ this level's features]) -> refine -> bilinear resize -> 1x1 conv."""

    def __init__(self, c: int, has_skip: bool = True):
        super().__init__()
        if has_skip:
            self.resConfUnit1 = ResidualConvUnit(c)
        self.resConfUnit2 = ResidualConvUnit(c)
        self.out_conv = nn.Conv2d(c, c, 1)

    def forward(self, x: Tensor, skip: Tensor | None = None, size=None) -> Tensor:
        if skip is not None:
            x = x + self.resConfUnit1(skip)
        x = self.resConfUnit2(x)
        if size is None:
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=True)
        else:
            x = F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=True)
        return self.out_conv(x)


# per case: the extra inputs concatenated at each level, in order; "vit" is the reassembled tap
LEVEL_INPUTS = {
    (4, 1): (("cnn0", "cnn1", "vit"), ("cnn2", "vit", "mv", "depth"), ("vit",)),
    (2, 2): (("cnn0", "cnn1", "mv0", "depth", "vit"), ("cnn2", "vit", "mv1"), ("vit",)),
    (4, 2): (("cnn0", "vit"), ("cnn1", "vit", "mv0", "depth"), ("cnn2", "vit", "mv1")),
    (8, 1): (("cnn0", "vit"), ("cnn1", "vit"), ("cnn2", "vit", "mv", "depth")),
}
WIDTHS = {"cnn0": 64, "cnn1": 96, "cnn2": 128, "mv": 128, "mv0": 64, "mv1": 128, "depth": 1}


class DPTHead(nn.Module):
    """Args:
    vit_dim: ViT width; features: fusion width; out: per-level widths (4);
    upsample_factor, num_scales: pick the case above; with_depth: the depth upsampler
    (inputs include the coarse depth, output 1 channel) rather than the feature one.
    """

    def __init__(
        self,
        vit_dim: int,
        features: int,
        out: tuple[int, ...],
        upsample_factor: int,
        num_scales: int,
        with_depth: bool,
    ):
        super().__init__()
        key = (upsample_factor, num_scales)
        if key not in LEVEL_INPUTS:
            raise ValueError(
                f"no DPT layout for upsample_factor={upsample_factor}, num_scales={num_scales}"
            )
        self.levels = [
            tuple(n for n in names if with_depth or n != "depth") for names in LEVEL_INPUTS[key]
        ]
        self.with_depth = with_depth
        self.concat_projects = nn.ModuleList(
            nn.Conv2d(sum(out[i] if n == "vit" else WIDTHS[n] for n in names), out[i], 1)
            for i, names in enumerate(self.levels)
        )
        self.projects = nn.ModuleList(nn.Conv2d(vit_dim, c, 1) for c in out)
        self.resize_layers = nn.ModuleList(
            [
                nn.ConvTranspose2d(out[0], out[0], 4, 4),
                nn.ConvTranspose2d(out[1], out[1], 2, 2),
                nn.Identity(),
                nn.Conv2d(out[3], out[3], 3, stride=2, padding=1),
            ]
        )
        self.scratch = nn.Module()
        for i in range(4):
            setattr(
                self.scratch,
                f"layer{i + 1}_rn",
                nn.Conv2d(out[i], features, 3, padding=1, bias=False),
            )
        for i in range(4):
            setattr(self.scratch, f"refinenet{i + 1}", FusionBlock(features, has_skip=i != 3))
        if with_depth:
            self.scratch.output_conv = nn.Sequential(
                nn.Conv2d(features, features // 2, 3, padding=1, padding_mode="replicate"),
                nn.GELU(),
                nn.Conv2d(features // 2, 16, 3, padding=1, padding_mode="replicate"),
                nn.GELU(),
                nn.Conv2d(16, 1, 1),
            )

    def forward(
        self,
        taps: list[Tensor],
        cnn: list[Tensor],
        mv: Tensor | list[Tensor],
        depth: Tensor | None = None,
    ) -> Tensor:
        """taps: 4 x [N,vit_dim,H/8,W/8]; cnn: [64ch, 96ch, 128ch] high to low resolution;
        mv: [N,128,..] (1 scale) or [64ch, 128ch] high to low (2 scales); depth [N,1,..]
        (coarse inverse depth, depth head only). Returns [N,1,H,W] or [N,features,H,W]."""
        layers = [rs(pr(x)) for x, pr, rs in zip(taps, self.projects, self.resize_layers)]
        named = {"cnn0": cnn[0], "cnn1": cnn[1], "cnn2": cnn[2], "depth": depth}
        if isinstance(mv, (list, tuple)):
            named["mv0"], named["mv1"] = mv
        else:
            named["mv"] = mv
        for i, names in enumerate(self.levels):
            parts = [layers[i] if n == "vit" else named[n] for n in names]
            layers[i] = self.concat_projects[i](cat_channels(parts))
        s = self.scratch
        r1, r2, r3, r4 = (getattr(s, f"layer{i + 1}_rn")(x) for i, x in enumerate(layers))
        p = s.refinenet4(r4, size=r3.shape[2:])
        p = s.refinenet3(p, r3, size=r2.shape[2:])
        p = s.refinenet2(p, r2, size=r1.shape[2:])
        p = s.refinenet1(p, r1)
        return s.output_conv(p) if self.with_depth else p
