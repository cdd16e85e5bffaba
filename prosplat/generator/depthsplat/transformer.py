"""The multi-view feature transformer: 6 blocks of windowed self-attention and windowed
cross-attention to the other views (or, above 3 views, to each view's ``local_mv_match``
nearest cameras), Swin-style shifted windows on every odd block, single head."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def sine_position(h: int, w: int, channels: int, device, dtype=torch.float32) -> Tensor:
    """DETR's normalised sine encoding of an h x w grid -> [channels, h, w]
    (first half encodes the row, second half the column)."""
    npf = channels // 2
    rows = torch.arange(1, h + 1, device=device, dtype=torch.float32)
    cols = torch.arange(1, w + 1, device=device, dtype=torch.float32)
    rows = rows / (h + 1e-6) * 2 * math.pi
    cols = cols / (w + 1e-6) * 2 * math.pi
    k = torch.arange(npf, device=device, dtype=torch.float32)
    freq = 10000 ** (2 * torch.div(k, 2, rounding_mode="floor") / npf)  # [npf]

    def enc(t: Tensor) -> Tensor:  # [n] -> [n, npf], sin on even, cos on odd features
        a = t[:, None] / freq
        return torch.where(k.long() % 2 == 0, a.sin(), a.cos())

    pos_y = enc(rows)[:, None, :].expand(h, w, npf)
    pos_x = enc(cols)[None, :, :].expand(h, w, npf)
    return torch.cat([pos_y, pos_x], dim=-1).permute(2, 0, 1).to(dtype)


def add_window_position(x: Tensor, splits: int) -> Tensor:
    """x [N,C,H,W] + the sine encoding of one window, tiled over the splits x splits windows."""
    _, c, h, w = x.shape
    pos = sine_position(h // splits, w // splits, c, x.device, x.dtype)
    return x + pos.repeat(1, splits, splits)


def to_windows(x: Tensor, s: int) -> Tensor:
    """[N,H,W,C] -> [N,s*s,(H/s)*(W/s),C], windows in row-major order."""
    n, h, w, c = x.shape
    x = x.view(n, s, h // s, s, w // s, c).permute(0, 1, 3, 2, 4, 5)
    return x.reshape(n, s * s, (h // s) * (w // s), c)


def from_windows(x: Tensor, s: int, h: int, w: int) -> Tensor:
    """Inverse of :func:`to_windows`: [N,s*s,L,C] -> [N,H,W,C]."""
    n, _, _, c = x.shape
    x = x.view(n, s, s, h // s, w // s, c).permute(0, 1, 3, 2, 4, 5)
    return x.reshape(n, h, w, c)


def shifted_window_mask(h: int, w: int, s: int, device) -> Tensor:
    """Additive mask [s*s, L, L] for shifted windows (L = (h/s)(w/s)): -100 between tokens that
    came from different regions of the rolled map, 0 within one region."""
    wh, ww = h // s, w // s
    region = torch.zeros(h, w, device=device)
    bounds_h = ((0, h - wh), (h - wh, h - wh // 2), (h - wh // 2, h))
    bounds_w = ((0, w - ww), (w - ww, w - ww // 2), (w - ww // 2, w))
    label = 0
    for r0, r1 in bounds_h:
        for c0, c1 in bounds_w:
            region[r0:r1, c0:c1] = label
            label += 1
    win = to_windows(region[None, :, :, None], s)[0, :, :, 0]  # [s*s, L]
    diff = win[:, None, :] - win[:, :, None]  # [s*s, L(query), L(key)]
    return torch.where(
        diff != 0, torch.tensor(-100.0, device=device), torch.tensor(0.0, device=device)
    )


def window_attention(
    q: Tensor, k: Tensor, v: Tensor, h: int, w: int, s: int, mask: Tensor | None
) -> Tensor:
    """Single-head attention inside s x s windows, with keys from M views per query.

    q: [N,L,C] with L = h*w; k, v: [N,M,L,C]. With ``mask`` ([s*s,Lw,Lw]) the maps are rolled
    by half a window first and back after. Within a window the keys are ordered
    (position, view) and the mask is tiled M times along the key axis, position-major -- the
    reference's layout, kept so that results agree also where M > 1.
    Returns [N,L,C].
    """
    n, m, _, c = k.shape
    q = q.view(n, h, w, c)
    k = k.view(n, m, h, w, c)
    v = v.view(n, m, h, w, c)
    if mask is not None:
        sh, sw = (h // s) // 2, (w // s) // 2
        q = torch.roll(q, (-sh, -sw), (1, 2))
        k = torch.roll(k, (-sh, -sw), (2, 3))
        v = torch.roll(v, (-sh, -sw), (2, 3))
    qw = to_windows(q, s)  # [N,s*s,Lw,C]
    # [N,M,H,W,C] -> [N,H,W,M*C] -> windows [N,s*s,Lw,M*C] -> [N,s*s,Lw*M,C] (position-major)
    kw = to_windows(k.permute(0, 2, 3, 1, 4).reshape(n, h, w, m * c), s)
    vw = to_windows(v.permute(0, 2, 3, 1, 4).reshape(n, h, w, m * c), s)
    lw = kw.shape[2]
    kw = kw.reshape(n, s * s, lw * m, c)
    vw = vw.reshape(n, s * s, lw * m, c)
    bias = None
    if mask is not None:
        bias = mask.repeat(1, 1, m)  # [s*s, Lw, Lw*M]: key j gets mask column j mod Lw
    out = F.scaled_dot_product_attention(qw, kw, vw, attn_mask=bias)  # [N,s*s,Lw,C]
    out = from_windows(out, s, h, w)
    if mask is not None:
        out = torch.roll(out, (sh, sw), (1, 2))
    return out.reshape(n, h * w, c)


class AttentionLayer(nn.Module):
    """One attention (+ optional FFN) layer: source + norm(FFN([source, norm(attn)]))."""

    def __init__(self, dim: int, ffn: bool, expansion: int = 4):
        super().__init__()
        self.q_proj = nn.Linear(dim, dim, bias=False)
        self.k_proj = nn.Linear(dim, dim, bias=False)
        self.v_proj = nn.Linear(dim, dim, bias=False)
        self.merge = nn.Linear(dim, dim, bias=False)
        self.norm1 = nn.LayerNorm(dim)
        self.has_ffn = ffn
        if ffn:
            hidden = 2 * dim * expansion
            self.mlp = nn.Sequential(
                nn.Linear(2 * dim, hidden, bias=False),
                nn.GELU(),
                nn.Linear(hidden, dim, bias=False),
            )
            self.norm2 = nn.LayerNorm(dim)

    def forward(self, source: Tensor, target: Tensor, h: int, w: int, s: int, mask) -> Tensor:
        # source [N,L,C]; target [N,M,L,C]
        msg = window_attention(
            self.q_proj(source), self.k_proj(target), self.v_proj(target), h, w, s, mask
        )
        msg = self.norm1(self.merge(msg))
        if self.has_ffn:
            msg = self.norm2(self.mlp(torch.cat([source, msg], dim=-1)))
        return source + msg


class TransformerBlock(nn.Module):
    def __init__(self, dim: int, expansion: int = 4):
        super().__init__()
        self.self_attn = AttentionLayer(dim, ffn=False, expansion=expansion)
        self.cross_attn_ffn = AttentionLayer(dim, ffn=True, expansion=expansion)


def neighbour_index(c2w: Tensor, local_mv_match: int) -> Tensor | None:
    """For V > 3 views: [B,V,local_mv_match] indices of each view's nearest cameras (by centre
    distance, the view itself excluded); None for V <= 3 (every other view is used)."""
    v = c2w.shape[1]
    if v <= 3:
        return None
    centres = c2w[:, :, :3, 3]
    order = torch.argsort(torch.cdist(centres, centres, p=2))  # [B,V,V], self first
    return order[:, :, 1 : local_mv_match + 1]


def gather_views(x: Tensor, index: Tensor | None) -> Tensor:
    """x [B,V,...] -> [B,V,M,...]: for each view, the views it attends to / matches against.
    index None: all other views in order (M = V-1); else index [B,V,M]."""
    b, v = x.shape[:2]
    if index is None:
        others = [[j for j in range(v) if j != i] for i in range(v)]
        index = torch.tensor(others, device=x.device).expand(b, v, v - 1)
    flat = index.reshape(b, -1)  # [B,V*M]
    picked = x[torch.arange(b, device=x.device)[:, None], flat]  # [B,V*M,...]
    return picked.view(b, v, index.shape[-1], *x.shape[2:])


class MultiViewTransformer(nn.Module):
    """features [B,V,C,H,W] (position already added) -> [B,V,C,H,W]."""

    def __init__(self, dim: int = 128, layers: int = 6, expansion: int = 4):
        super().__init__()
        self.layers = nn.ModuleList([TransformerBlock(dim, expansion) for _ in range(layers)])

    def forward(self, x: Tensor, splits: int, index: Tensor | None) -> Tensor:
        b, v, c, h, w = x.shape
        mask = shifted_window_mask(h, w, splits, x.device) if splits > 1 else None
        tokens = x.flatten(3).transpose(2, 3)  # [B,V,L,C]
        for i, block in enumerate(self.layers):
            m = mask if i % 2 == 1 else None
            target = gather_views(tokens, index)  # [B,V,M,L,C], last block's output
            src = tokens.reshape(b * v, h * w, c)
            src = block.self_attn(src, src[:, None], h, w, splits, m)
            src = block.cross_attn_ffn(src, target.flatten(0, 1), h, w, splits, m)
            tokens = src.view(b, v, h * w, c)
        return tokens.transpose(2, 3).reshape(b, v, c, h, w)
