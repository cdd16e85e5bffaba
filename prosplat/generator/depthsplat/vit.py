"""The monocular branch: a DINOv2 ViT/14 (Depth Anything V2's encoder) returning the normalised
patch tokens of four blocks. Parameter names follow facebookresearch/dinov2, whose hub
model the reference builds (``mask_token`` removed)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class LayerScale(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.gamma = nn.Parameter(torch.ones(dim))

    def forward(self, x: Tensor) -> Tensor:
        return x * self.gamma


class SelfAttention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor) -> Tensor:
        n, t, c = x.shape
        q, k, v = self.qkv(x).view(n, t, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v)  # [N,heads,T,c/heads]
        return self.proj(out.transpose(1, 2).reshape(n, t, c))


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: Tensor) -> Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class Block(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = SelfAttention(dim, heads)
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, 4 * dim)
        self.ls2 = LayerScale(dim)

    def forward(self, x: Tensor) -> Tensor:
        x = x + self.ls1(self.attn(self.norm1(x)))
        return x + self.ls2(self.mlp(self.norm2(x)))


class PatchEmbed(nn.Module):
    def __init__(self, dim: int, patch: int = 14):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, patch, patch)

    def forward(self, x: Tensor) -> Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)  # [N,T,dim]


class DinoViT(nn.Module):
    """DINOv2 ViT/14 at a 518-pixel training grid (37 x 37 position embeddings)."""

    def __init__(self, dim: int, depth: int, heads: int, patch: int = 14, grid: int = 37):
        super().__init__()
        self.patch = patch
        self.patch_embed = PatchEmbed(dim, patch)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, grid * grid + 1, dim))
        self.blocks = nn.ModuleList([Block(dim, heads) for _ in range(depth)])
        self.norm = nn.LayerNorm(dim, eps=1e-6)

    def position(self, h: int, w: int) -> Tensor:
        """Position embeddings for an h x w patch grid [1,1+h*w,dim]: bicubic resampling of the
        37 x 37 grid with DINOv2's scale factors ((n + 0.1) / 37, no antialiasing)."""
        pe = self.pos_embed.float()
        n = pe.shape[1] - 1
        g = int(math.sqrt(n))
        if h * w == n and h == w:
            return self.pos_embed
        grid = pe[:, 1:].reshape(1, g, g, -1).permute(0, 3, 1, 2)
        grid = F.interpolate(
            grid, scale_factor=((h + 0.1) / g, (w + 0.1) / g), mode="bicubic", antialias=False
        )
        if grid.shape[-2:] != (h, w):
            raise ValueError(
                f"position grid resampled to {tuple(grid.shape[-2:])}, expected {(h, w)}"
            )
        grid = grid.permute(0, 2, 3, 1).reshape(1, h * w, -1)
        return torch.cat([pe[:, :1], grid], dim=1).to(self.pos_embed.dtype)

    def intermediate(self, x: Tensor, taps: tuple[int, ...]) -> list[Tensor]:
        """x [N,3,H,W] (H, W multiples of 14) -> for each tapped block, the final-norm patch
        tokens as maps [N,dim,H/14,W/14]."""
        n, _, hh, ww = x.shape
        h, w = hh // self.patch, ww // self.patch
        t = self.patch_embed(x)
        t = torch.cat([self.cls_token.expand(n, -1, -1), t], dim=1)
        t = t + self.position(h, w)
        out = []
        for i, blk in enumerate(self.blocks):
            t = blk(t)
            if i in taps:
                y = self.norm(t)[:, 1:]  # [N,h*w,dim]
                out.append(y.transpose(1, 2).reshape(n, -1, h, w))
            if i >= max(taps):
                break
        return out
