"""Matching features: a per-view CNN to 1/4 resolution, then cross-view attention.

The CNN gives local features; the transformer lets every view see the others (as DepthSplat's
multi-view Swin Transformer does), so the features that the cost volume correlates are already
aware of what the other views contain. Attention is kept cheap by windows: the 1/4-resolution
map is cut into ``splits x splits`` windows, tokens attend only within their window in their
own view (self-attention) and in the same window of the other views (cross-attention), and odd
layers shift the windows by half a window so information crosses window borders.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.layers import ConvNormAct, ResBlock


class ConvEncoder(nn.Module):
    """[N,3,H,W] images in [-1,1] -> [N,C,H/4,W/4] features (two stride-2 stages), plus the
    1/2-resolution stage's [N,C/2,H/2,W/2] for fine matching."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        half = max(channels // 2, 8)
        self.half_channels = half
        self.stage1 = nn.Sequential(ConvNormAct(3, half, stride=2), ResBlock(half))  # 1/2
        self.stage2 = nn.Sequential(
            ConvNormAct(half, channels, stride=2), ResBlock(channels), ResBlock(channels)
        )  # 1/4
        self.out = nn.Conv2d(channels, channels, 1)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        half = self.stage1(x)  # [N,C/2,H/2,W/2]
        return self.out(self.stage2(half)), half  # [N,C,H/4,W/4], [N,C/2,H/2,W/2]


def sine_position_encoding(h: int, w: int, channels: int, like: Tensor) -> Tensor:
    """[h,w,channels] fixed 2D sinusoidal encoding (feature-pixel units), zero-padded to fit.

    The transformer is otherwise permutation-invariant inside a window; position lets a token
    prefer matches near where the geometry puts them.
    """
    quarter = channels // 4
    pe = like.new_zeros(h, w, channels)
    if quarter == 0:
        return pe
    freq = torch.exp(
        torch.arange(quarter, dtype=like.dtype, device=like.device) * (-math.log(1e4) / quarter)
    )  # [q]
    ys = (torch.arange(h, dtype=like.dtype, device=like.device) + 0.5)[:, None] * freq  # [h,q]
    xs = (torch.arange(w, dtype=like.dtype, device=like.device) + 0.5)[:, None] * freq  # [w,q]
    pe[..., 0 * quarter : 1 * quarter] = xs.sin()[None, :, :]
    pe[..., 1 * quarter : 2 * quarter] = xs.cos()[None, :, :]
    pe[..., 2 * quarter : 3 * quarter] = ys.sin()[:, None, :]
    pe[..., 3 * quarter : 4 * quarter] = ys.cos()[:, None, :]
    return pe


def _to_windows(x: Tensor, splits: int) -> Tensor:
    """[B,V,h,w,C] -> [B,V,S*S,T,C] with T = (h/S)*(w/S) tokens per window."""
    b, v, h, w, c = x.shape
    wh, ww = h // splits, w // splits
    x = x.view(b, v, splits, wh, splits, ww, c).permute(0, 1, 2, 4, 3, 5, 6)
    return x.reshape(b, v, splits * splits, wh * ww, c)


def _from_windows(x: Tensor, splits: int, h: int, w: int) -> Tensor:
    """Inverse of :func:`_to_windows`: [B,V,S*S,T,C] -> [B,V,h,w,C]."""
    b, v, _, _, c = x.shape
    wh, ww = h // splits, w // splits
    x = x.view(b, v, splits, splits, wh, ww, c).permute(0, 1, 2, 4, 3, 5, 6)
    return x.reshape(b, v, h, w, c)


class _Attention(nn.Module):
    """Multi-head attention through ``scaled_dot_product_attention`` (flash/memory-efficient
    kernels where the device has them)."""

    def __init__(self, channels: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(channels, channels)
        self.kv = nn.Linear(channels, 2 * channels)
        self.proj = nn.Linear(channels, channels)

    def forward(self, x: Tensor, context: Tensor) -> Tensor:
        """x [N,T,C] queries, context [N,S,C] keys/values -> [N,T,C]."""
        n, t, c = x.shape
        s = context.shape[1]
        dh = c // self.heads
        q = self.q(x).view(n, t, self.heads, dh).transpose(1, 2)  # [N,h,T,dh]
        k, v = self.kv(context).view(n, s, 2, self.heads, dh).permute(2, 0, 3, 1, 4)  # [N,h,S,dh]
        out = F.scaled_dot_product_attention(q, k, v)  # [N,h,T,dh]
        return self.proj(out.transpose(1, 2).reshape(n, t, c))


class CrossViewBlock(nn.Module):
    """Window self-attention, window cross-attention to the other views, then an MLP."""

    def __init__(self, channels: int, heads: int, mlp_ratio: int) -> None:
        super().__init__()
        self.norm_self = nn.LayerNorm(channels)
        self.self_attn = _Attention(channels, heads)
        self.norm_cross = nn.LayerNorm(channels)
        self.cross_attn = _Attention(channels, heads)
        self.norm_mlp = nn.LayerNorm(channels)
        self.mlp = nn.Sequential(
            nn.Linear(channels, mlp_ratio * channels),
            nn.GELU(),
            nn.Linear(mlp_ratio * channels, channels),
        )

    def forward(self, x: Tensor, others: Tensor) -> Tensor:
        """x [B,V,W,T,C] windowed tokens; others [V,V-1] indices of the other views."""
        b, v, nw, t, c = x.shape
        y = self.norm_self(x).reshape(b * v * nw, t, c)
        x = x + self.self_attn(y, y).view(b, v, nw, t, c)
        y = self.norm_cross(x)  # [B,V,W,T,C]
        ctx = y[:, others]  # [B,V,V-1,W,T,C]: the same window in every other view
        ctx = ctx.permute(0, 1, 3, 2, 4, 5).reshape(b * v * nw, (v - 1) * t, c)
        x = x + self.cross_attn(y.reshape(b * v * nw, t, c), ctx).view(b, v, nw, t, c)
        return x + self.mlp(self.norm_mlp(x))


class CrossViewTransformer(nn.Module):
    """[B,V,C,h,w] per-view features -> [B,V,C,h,w] multi-view-aware features.

    Shifted windows are rolled without an attention mask: tokens that wrap round the border
    share a window for that layer. This costs a little purity (Swin masks them) and buys a
    simpler, faster layer; the next unshifted layer is exact again.
    """

    def __init__(self, channels: int, layers: int, heads: int, splits: int, mlp_ratio: int):
        super().__init__()
        self.splits = splits
        self.blocks = nn.ModuleList(
            CrossViewBlock(channels, heads, mlp_ratio) for _ in range(layers)
        )
        self.norm_out = nn.LayerNorm(channels)

    def forward(self, feats: Tensor) -> Tensor:
        b, v, c, h, w = feats.shape
        if h % self.splits or w % self.splits:
            raise ValueError(
                f"feature map {h}x{w} is not divisible into {self.splits} windows per side; "
                "use an image size that is a multiple of 32"
            )
        x = feats.permute(0, 1, 3, 4, 2)  # [B,V,h,w,C]
        x = x + sine_position_encoding(h, w, c, x)
        idx = torch.arange(v, device=feats.device)
        others = torch.stack([torch.cat([idx[:i], idx[i + 1 :]]) for i in range(v)])  # [V,V-1]
        sh, sw = (h // self.splits) // 2, (w // self.splits) // 2
        for layer, block in enumerate(self.blocks):
            shift = layer % 2 == 1 and self.splits > 1
            if shift:
                x = torch.roll(x, shifts=(-sh, -sw), dims=(2, 3))
            x = _from_windows(block(_to_windows(x, self.splits), others), self.splits, h, w)
            if shift:
                x = torch.roll(x, shifts=(sh, sw), dims=(2, 3))
        return self.norm_out(x).permute(0, 1, 4, 2, 3).contiguous()  # [B,V,C,h,w]


class FeatureEncoder(nn.Module):
    """Images [B,V,3,H,W] in [-1,1] -> matching features [B,V,C,H/4,W/4], and with
    ``fine_channels`` > 0 also per-view fine features [B,V,Cf,H/2,W/2].

    The fine features skip the transformer: they are for the 1/2-resolution cost volume, where
    a wide-baseline match needs pixels small enough to find a peak, and local appearance
    (which transfers from synthetic scenes to photos) is what matches there.
    """

    def __init__(
        self,
        channels: int,
        layers: int,
        heads: int,
        splits: int,
        mlp_ratio: int,
        fine_channels: int = 0,
    ):
        super().__init__()
        self.cnn = ConvEncoder(channels)
        self.transformer = CrossViewTransformer(channels, layers, heads, splits, mlp_ratio)
        self.fine = (
            nn.Conv2d(self.cnn.half_channels, fine_channels, 1) if fine_channels > 0 else None
        )

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor | None]:
        b, v = images.shape[:2]
        f, half = self.cnn(images.flatten(0, 1))  # [B*V,C,h,w], [B*V,C/2,2h,2w]
        coarse = self.transformer(f.view(b, v, *f.shape[1:]))  # [B,V,C,h,w]
        if self.fine is None:
            return coarse, None
        fine = self.fine(half)  # [B*V,Cf,2h,2w]
        return coarse, fine.view(b, v, *fine.shape[1:])
