"""The multi-view feature transformer: 6 blocks of windowed self-attention and windowed
cross-attention to the other views (or, above 3 views, to each view's ``local_mv_match``
nearest cameras), Swin-style shifted windows on every odd block, single head."""

from __future__ import annotations

import functools
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


def shifted_window_regions(h: int, w: int, s: int) -> Tensor:
    """[s*s, Lw] region label of every token of every window of the half-window-rolled map
    (Lw = (h/s)(w/s)): tokens that were neighbours before the roll share a label."""
    wh, ww = h // s, w // s
    region = torch.zeros(h, w)
    bounds_h = ((0, h - wh), (h - wh, h - wh // 2), (h - wh // 2, h))
    bounds_w = ((0, w - ww), (w - ww, w - ww // 2), (w - ww // 2, w))
    label = 0
    for r0, r1 in bounds_h:
        for c0, c1 in bounds_w:
            region[r0:r1, c0:c1] = label
            label += 1
    return to_windows(region[None, :, :, None], s)[0, :, :, 0].long()


def shifted_window_mask(h: int, w: int, s: int, device) -> Tensor:
    """Additive mask [s*s, Lw, Lw] for shifted windows: -100 between tokens of different
    regions, 0 within one (the reference's values)."""
    win = shifted_window_regions(h, w, s).to(device)
    diff = win[:, None, :] != win[:, :, None]  # [s*s, L(query), L(key)]
    return diff.float() * -100.0


def window_attention(
    q: Tensor, k: Tensor, v: Tensor, h: int, w: int, s: int, shifted: bool, exact: bool = True
) -> Tensor:
    """The reference's form of the windowed attention (the slow twin of
    :func:`grouped_attention`, used by the tests and for odd window sizes): single-head
    attention inside s x s windows, with keys from M views per query.

    q: [N,L,C] with L = h*w; k, v: [N,M,L,C]. ``shifted``: the maps are rolled by half a
    window first and back after, and tokens attend only within their region (the reference
    adds -100 to the other scores; within a window the keys are ordered (position, view) and
    its mask is tiled M times along the key axis, position-major, which for M > 1 pairs key
    (p, view) with the mask column of position (p*M + view) mod Lw -- reproduced here).

    :func:`grouped_attention` instead groups each region's queries with the keys this mask
    admits and runs one unmasked attention per region: the same as the masked softmax up to
    the exp(-100) weights the reference leaves on masked keys. ``exact`` is accepted for
    symmetry (this form is always exact). Returns [N,L,C].
    """
    n, m, _, c = k.shape
    q = q.reshape(n, h, w, c)
    k = k.reshape(n, m, h, w, c)
    v = v.reshape(n, m, h, w, c)
    if shifted:
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
    if shifted:
        bias = shifted_window_mask(h, w, s, q.device).repeat(1, 1, m)  # [s*s,Lw,Lw*M]
    out = F.scaled_dot_product_attention(qw, kw, vw, attn_mask=bias)  # [N,s*s,Lw,C]
    out = from_windows(out, s, h, w)
    if shifted:
        out = torch.roll(out, (sh, sw), (1, 2))
    return out.reshape(n, h * w, c)


@functools.lru_cache(maxsize=32)
def _token_plan(h: int, w: int, s: int, m: int, shifted: bool):
    """One gather for the whole windowed attention: the order that puts every window's
    tokens (after the half-window roll when ``shifted``) region by region, and the matching
    order of the keys (position-major (p, view) within a window, region of the mask column
    (p*M + view) mod Lw, as :func:`window_attention` explains).

    Returns (q_index [L], inverse [L], k_view [L*M], k_pos [L*M], segments) where segments
    are (q_start, k_start, regions, Lw) per window, or None when a window's regions differ
    in size (then the masked path is used)."""
    grid = torch.arange(h * w).view(h, w)
    if shifted:
        grid = torch.roll(grid, (-((h // s) // 2), -((w // s) // 2)), (0, 1))
    win = to_windows(grid[None, :, :, None], s)[0, :, :, 0]  # [s*s,Lw] original token index
    lw = win.shape[1]
    labels = shifted_window_regions(h, w, s) if shifted else torch.zeros_like(win)
    q_index, k_view, k_pos, segments = [], [], [], []
    j = torch.arange(lw * m)
    for i in range(s * s):
        lab = labels[i]
        counts = torch.bincount(lab)
        counts = counts[counts > 0]
        if bool((counts != counts[0]).any()):
            return None
        qo = torch.argsort(lab, stable=True)
        ko = torch.argsort(lab[j % lw], stable=True)  # key j = (p = j // M, view = j % M)
        segments.append((i * lw, i * lw * m, len(counts), lw))
        q_index.append(win[i][qo])
        k_pos.append(win[i][ko // m])
        k_view.append(ko % m)
    q_index = torch.cat(q_index)
    return q_index, torch.argsort(q_index), torch.cat(k_view), torch.cat(k_pos), segments


def grouped_attention(
    q: Tensor, k: Tensor, v: Tensor, nb: Tensor, h: int, w: int, s: int, shifted: bool
) -> Tensor:
    """The fast form of :func:`window_attention` for all views at once.

    q, k, v: [B,V,L,C] projected tokens of every view; nb: [B,V,M] the views each view
    attends to. One gather builds every window's (region-grouped) queries and keys straight
    from the per-view tokens, one unmasked attention runs per window (per region inside a
    shifted window), one gather puts the result back. Returns [B,V,L,C]."""
    b, v_, l, c = q.shape
    m = nb.shape[-1]
    plan = _token_plan(h, w, s, m, shifted)
    if plan is None:  # unequal regions (odd window sizes): the masked form
        kk = gather_views(k, nb).flatten(0, 1)
        vv = gather_views(v, nb).flatten(0, 1)
        out = window_attention(q.flatten(0, 1), kk, vv, h, w, s, shifted, exact=True)
        return out.view(b, v_, l, c)
    q_index, inverse, k_view, k_pos, segments = (
        t.to(q.device) if isinstance(t, Tensor) else t for t in plan
    )
    full = nb[:, :, k_view] * l + k_pos  # [B,V,L*M] index into the V*L tokens of a scene
    bi = torch.arange(b, device=q.device)[:, None, None]
    kg = k.reshape(b, v_ * l, c)[bi, full].flatten(0, 1)  # [N,L*M,C]
    vg = v.reshape(b, v_ * l, c)[bi, full].flatten(0, 1)
    qg = q[:, :, q_index].flatten(0, 1)  # [N,L,C]
    n = qg.shape[0]
    if all(seg[2] == 1 for seg in segments):  # plain windows: one call for all of them
        lw = segments[0][3]
        og = F.scaled_dot_product_attention(
            qg.view(n, -1, lw, c), kg.view(n, -1, lw * m, c), vg.view(n, -1, lw * m, c)
        ).reshape(n, l, c)
    else:
        parts = []
        for qs, ks, r, lw in segments:
            parts.append(
                F.scaled_dot_product_attention(
                    qg[:, qs : qs + lw].reshape(n, r, lw // r, c),
                    kg[:, ks : ks + lw * m].reshape(n, r, lw * m // r, c),
                    vg[:, ks : ks + lw * m].reshape(n, r, lw * m // r, c),
                ).reshape(n, lw, c)
            )
        og = torch.cat(parts, dim=1)
    return og[:, inverse].view(b, v_, l, c)


def other_views(b: int, v: int, device) -> Tensor:
    """[B,V,V-1]: every other view, in index order (the reference's choice for V <= 3)."""
    others = [[j for j in range(v) if j != i] for i in range(v)]
    return torch.tensor(others, device=device, dtype=torch.long).expand(b, v, v - 1)


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

    def forward(
        self,
        source: Tensor,
        target: Tensor,
        h: int,
        w: int,
        s: int,
        shifted: bool,
        index: Tensor | None = None,
        exact: bool = False,
    ) -> Tensor:
        """source [B,V,L,C]; target [B,V,L,C], each view attending to the views ``index``
        picks ([B,V,M]; "self": its own tokens; None: all other views). Keys and values are
        projected once per view, then gathered (the projection is per token)."""
        b, v, l, c = source.shape
        if isinstance(index, str):
            nb = torch.arange(v, device=source.device).view(1, v, 1).expand(b, v, 1)
        elif index is None:
            nb = other_views(b, v, source.device)
        else:
            nb = index
        k, val, q = self.k_proj(target), self.v_proj(target), self.q_proj(source)
        if exact:
            msg = window_attention(
                q.flatten(0, 1),
                gather_views(k, nb).flatten(0, 1),
                gather_views(val, nb).flatten(0, 1),
                h,
                w,
                s,
                shifted,
                exact=True,
            ).view(b, v, l, c)
        else:
            msg = grouped_attention(q, k, val, nb, h, w, s, shifted)
        msg = self.norm1(self.merge(msg))
        if self.has_ffn:
            # mlp(cat([source, msg])) with the first layer's weight split: no concatenation
            w1 = self.mlp[0].weight
            hidden = F.linear(source, w1[:, :c]).add_(F.linear(msg, w1[:, c:]))
            msg = self.norm2(self.mlp[2](self.mlp[1](hidden)))
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

    def forward(self, x: Tensor, splits: int, index: Tensor | None, exact: bool = False) -> Tensor:
        b, v, c, h, w = x.shape
        tokens = x.flatten(3).transpose(2, 3)  # [B,V,L,C]
        for i, block in enumerate(self.layers):
            shifted = splits > 1 and i % 2 == 1
            prev = tokens  # the cross-attention's keys: the previous block's output
            tokens = block.self_attn(tokens, tokens, h, w, splits, shifted, "self", exact)
            tokens = block.cross_attn_ffn(tokens, prev, h, w, splits, shifted, index, exact)
        return tokens.transpose(2, 3).reshape(b, v, c, h, w)
