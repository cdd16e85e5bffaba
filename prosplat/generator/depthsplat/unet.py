"""The cost-volume U-Net (an LDM-style U-Net without timestep input): pre-norm residual blocks,
strided-conv downsampling, nearest + conv upsampling, and at the coarsest levels a
multi-head attention in which every view attends to the tokens of all the views."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.depthsplat.ops import cat_channels


def group_norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(8 if channels % 8 == 0 else 4, channels)


class ResBlock(nn.Module):
    """GN-SiLU-conv twice (dropout slot at index 2, as in the key layout) + skip."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.in_layers = nn.Sequential(
            group_norm(cin), nn.SiLU(), nn.Conv2d(cin, cout, 3, padding=1)
        )
        self.out_layers = nn.Sequential(
            group_norm(cout), nn.SiLU(), nn.Identity(), nn.Conv2d(cout, cout, 3, padding=1)
        )
        self.skip_connection = nn.Identity() if cin == cout else nn.Conv2d(cin, cout, 1)

    def forward(self, x: Tensor) -> Tensor:
        return self.skip_connection(x) + self.out_layers(self.in_layers(x))


class CrossViewAttention(nn.Module):
    """Multi-head self-attention over the tokens of all V views of a scene (32 channels per
    head; heads split before q/k/v, the "legacy" order)."""

    def __init__(self, channels: int, head_channels: int = 32):
        super().__init__()
        self.heads = channels // head_channels
        self.norm = group_norm(channels)
        self.qkv = nn.Conv1d(channels, 3 * channels, 1)
        self.proj_out = nn.Conv1d(channels, channels, 1)
        self.num_views = 1

    def forward(self, x: Tensor) -> Tensor:
        n, c, h, w = x.shape
        v = self.num_views
        b = n // v
        flat = x.reshape(n, c, h * w)
        qkv = self.qkv(self.norm(flat))  # [B*V,3C,T]
        # [B*V,3C,T] -> [B,3C,V*T] -> [B*heads,3*hc,V*T]
        qkv = (
            qkv.view(b, v, 3 * c, h * w)
            .permute(0, 2, 1, 3)
            .reshape(b * self.heads, 3 * c // self.heads, v * h * w)
        )
        q, k, val = qkv.chunk(3, dim=1)  # each [B*heads,hc,V*T]
        a = F.scaled_dot_product_attention(
            q.transpose(1, 2), k.transpose(1, 2), val.transpose(1, 2)
        )
        a = a.transpose(1, 2).reshape(b, c, v, h * w).permute(0, 2, 1, 3).reshape(n, c, h * w)
        return (flat + self.proj_out(a)).reshape(n, c, h, w)


class Downsample(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.op = nn.Conv2d(channels, channels, 3, stride=2, padding=1)

    def forward(self, x: Tensor) -> Tensor:
        return self.op(x)


class Upsample(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.conv = nn.Conv2d(channels, channels, 3, padding=1)

    def forward(self, x: Tensor) -> Tensor:
        return self.conv(F.interpolate(x, scale_factor=2, mode="nearest"))


class UNet(nn.Module):
    """x [B*V,C,H,W] -> [B*V,C,H,W]; one residual block per level, ``len(mult)-1``
    downsamplings, attention at the downsampling factors in ``attn_at``."""

    def __init__(self, channels: int, mult: tuple[int, ...], attn_at: tuple[int, ...]):
        super().__init__()
        ch = channels
        self.input_blocks = nn.ModuleList(
            [nn.Sequential(nn.Conv2d(channels, channels, 3, padding=1))]
        )
        skips = [ch]
        ds = 1
        for level, m in enumerate(mult):
            layers: list[nn.Module] = [ResBlock(ch, m * channels)]
            ch = m * channels
            if ds in attn_at:
                layers.append(CrossViewAttention(ch))
            self.input_blocks.append(nn.Sequential(*layers))
            skips.append(ch)
            if level != len(mult) - 1:
                self.input_blocks.append(nn.Sequential(Downsample(ch)))
                skips.append(ch)
                ds *= 2
        self.middle_block = nn.Sequential(ResBlock(ch, ch), nn.Identity(), ResBlock(ch, ch))
        self.output_blocks = nn.ModuleList()
        for level, m in reversed(list(enumerate(mult))):
            for i in range(2):
                layers = [ResBlock(ch + skips.pop(), m * channels)]
                ch = m * channels
                if ds in attn_at:
                    layers.append(CrossViewAttention(ch))
                if level and i == 1:
                    layers.append(Upsample(ch))
                    ds //= 2
                self.output_blocks.append(nn.Sequential(*layers))
        self.out = nn.Sequential(group_norm(ch), nn.SiLU(), nn.Conv2d(ch, channels, 3, padding=1))

    def set_num_views(self, v: int) -> None:
        for mod in self.modules():
            if isinstance(mod, CrossViewAttention):
                mod.num_views = v

    def forward(self, x: Tensor) -> Tensor:
        hs = []
        for blk in self.input_blocks:
            x = blk(x)
            hs.append(x)
        x = self.middle_block(x)
        for blk in self.output_blocks:
            x = blk(cat_channels([x, hs.pop()]))
        return self.out(x)
