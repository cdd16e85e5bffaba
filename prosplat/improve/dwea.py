"""DWEA: Distance-Weighted Epipolar Attention between target and reference U-Net features.

The improvement model's U-Net sees the rendered target view and, through this module, the
reference view MORI picked. Each target feature attends over the reference features, and
the attention is modulated by how far each reference position lies from the target
position's epipolar line, so texture is borrowed from geometrically plausible places.
:class:`DWEAInjection` then carries the fused bottleneck features up the expansive path.

Paper (ProSplat, Sec. DWEA): ``attn = sigmoid(QKᵀ/√d · Norm(exp(−d_epi)))``, times V, added
to the target features; Norm is min-max to [0, 1] over the reference positions. Taken
literally this cannot concentrate on the line: a position far from the line gets
``score · 0 = 0`` and ``sigmoid(0) = 0.5``, the same weight as an on-line position with a
neutral score, and the unnormalised sum of sigmoids grows with the number of tokens. We keep
the ingredients but apply the modulation after the sigmoid and normalise each row::

    w_ij = sigmoid(q_i·k_j / √d) · Norm_j(exp(−d_ij / σ))
    a_ij = w_ij / max(Σ_j w_ij, 1e-12)

so off-line positions get weight → 0 and a row is a weighted mean of V. ``d_ij`` is measured
in feature cells (pixels / stride), not pixels: at a bottleneck stride of 64 px,
``exp(−d_pixels)`` would be a hard one-cell mask. σ defaults to half a cell, so a cell one
stride off the line gets e⁻² ≈ 0.14 of an on-line cell's weight.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as tF
from torch import Tensor, nn

from prosplat.improve.epipolar import epipolar_distances, work_dtype

__all__ = ["DWEA", "DWEAInjection", "DepthwiseSeparableConv", "epipolar_modulation"]

# h·w·h'·w'·heads·B above this (~64M, 256 MiB of float32 per tensor) is refused: DWEA is meant
# for the bottleneck (16×16 at 512² input); larger maps need a windowed variant.
_MAX_ATTENTION_ELEMENTS = 1 << 26
# A row whose modulation spans less than this (all positions equally far from the line, as at
# the epipole) is left flat (1 everywhere) instead of min-max-amplifying rounding noise.
_FLAT_SPAN = 1e-6


def _groups(channels: int) -> int:
    """GroupNorm groups: 32 as in Stable Diffusion's U-Net, or a divisor for small C."""
    return math.gcd(channels, 32)


def epipolar_modulation(
    F: Tensor,
    target_hw: tuple[int, int],
    ref_hw: tuple[int, int],
    stride: float,
    sigma: float = 0.5,
    device: torch.device | str | None = None,
) -> Tensor:
    """The paper's ``Norm(exp(−d))`` per (target i, reference j), d in feature cells.

    ``m_ij = exp(−d_ij / σ)`` min-max normalised over j (computed as
    ``exp(−(d_ij − min_j d)/σ)`` so it never underflows: the nearest position gets 1, the
    farthest 0). Batch elements with a vanishing F (pure rotation, coincident cameras) and
    rows that are flat (degenerate lines, where every distance is 0) get 1 everywhere, i.e.
    plain attention.

    Args:
        F: [B, 3, 3] fundamental matrices in full-image pixels.
        target_hw, ref_hw: feature map sizes (h, w).
        stride: image pixels per feature cell.
        sigma: decay length in feature cells.
        device: where to compute (default F's device).
    Returns:
        [B, h_t*w_t, h_r*w_r] float32 in [0, 1].
    """
    if not sigma > 0:
        raise ValueError(f"epipolar_modulation: sigma must be > 0 (feature cells), got {sigma}")
    device = torch.device(device) if device is not None else F.device
    F = F.detach().to(work_dtype(device)).to(device)
    d, valid = epipolar_distances(F, target_hw, ref_hw, stride)  # pixels
    d = d / float(stride)
    m = torch.exp(-(d - d.amin(-1, keepdim=True)) / sigma)  # max 1 per row
    m_min = m.amin(-1, keepdim=True)
    span = 1.0 - m_min
    flat = span <= _FLAT_SPAN
    m = torch.where(flat, torch.ones_like(m), (m - m_min) / torch.where(flat, 1.0, span))
    m = torch.where(valid[:, None, None], m, torch.ones_like(m))
    return m.float()


class DWEA(nn.Module):
    """Distance-Weighted Epipolar Attention (see the module docstring for the formula).

    Q from the GroupNorm'd target, K and V from the GroupNorm'd reference (1×1 projections),
    per-head dim ``C / heads``. The output projection starts at zero, so an untrained DWEA
    returns the target features unchanged and can be inserted into a pretrained U-Net.
    Attention is computed in at least float32.
    """

    def __init__(self, channels: int, heads: int = 1, sigma: float = 0.5) -> None:
        super().__init__()
        if channels < 1 or heads < 1 or channels % heads != 0:
            raise ValueError(
                f"DWEA: channels ({channels}) must be a positive multiple of heads ({heads})"
            )
        if not sigma > 0:
            raise ValueError(f"DWEA: sigma must be > 0 (feature cells), got {sigma}")
        self.channels, self.heads, self.sigma = channels, heads, float(sigma)
        self.norm_q = nn.GroupNorm(_groups(channels), channels, eps=1e-6)
        self.norm_kv = nn.GroupNorm(_groups(channels), channels, eps=1e-6)
        self.to_q = nn.Conv2d(channels, channels, 1)
        self.to_k = nn.Conv2d(channels, channels, 1)
        self.to_v = nn.Conv2d(channels, channels, 1)
        self.to_out = nn.Conv2d(channels, channels, 1)
        nn.init.zeros_(self.to_out.weight)
        nn.init.zeros_(self.to_out.bias)

    def _split(self, x: Tensor) -> Tensor:
        """[B, C, h, w] -> [B, heads, h*w, C/heads]."""
        B, C, h, w = x.shape
        return x.reshape(B, self.heads, C // self.heads, h * w).transpose(2, 3)

    def forward(
        self,
        target: Tensor,
        ref: Tensor,
        F: Tensor | None,
        stride: float,
        return_weights: bool = False,
    ) -> Tensor | tuple[Tensor, Tensor]:
        """Fuse reference features into the target features.

        Args:
            target: [B, C, h, w] target-view features.
            ref: [B, C, h', w'] reference-view features.
            F: [B, 3, 3] fundamental matrices (``x_refᵀ F x_tgt = 0`` in full-image pixels), or
                None for plain attention; all-zero rows (vanishing baseline) also get plain
                attention.
            stride: image pixels per feature cell (the same for both maps).
            return_weights: also return the attention weights.
        Returns:
            [B, C, h, w] = target + out_proj(attention · V); with ``return_weights`` also the
            weights [B, heads, h*w, h'*w'] (rows sum to 1).
        """
        if target.dim() != 4 or ref.dim() != 4:
            raise ValueError(
                f"DWEA: target and ref must be [B, C, h, w], got {tuple(target.shape)} and {tuple(ref.shape)}"
            )
        B, C, h, w = target.shape
        if ref.shape[:2] != (B, C) or C != self.channels:
            raise ValueError(
                f"DWEA({self.channels}): target {tuple(target.shape)} and ref {tuple(ref.shape)} "
                f"must share batch and have {self.channels} channels"
            )
        hr, wr = ref.shape[2:]
        n_elem = B * self.heads * h * w * hr * wr
        if n_elem > _MAX_ATTENTION_ELEMENTS:
            raise ValueError(
                f"DWEA: attention of {h}x{w} over {hr}x{wr} (x{B * self.heads}) has {n_elem} elements, "
                f"over {_MAX_ATTENTION_ELEMENTS}; apply it at the bottleneck or downsample the features"
            )
        if F is not None and (F.dim() != 3 or tuple(F.shape) != (B, 3, 3)):
            raise ValueError(f"DWEA: F must be [B={B}, 3, 3] or None, got {tuple(F.shape)}")

        q = self._split(self.to_q(self.norm_q(target)))  # [B, H, Nt, d]
        ref_n = self.norm_kv(ref)
        k = self._split(self.to_k(ref_n))  # [B, H, Nr, d]
        v = self._split(self.to_v(ref_n))  # [B, H, Nr, d]
        work = torch.promote_types(q.dtype, torch.float32)
        scores = q.to(work) @ k.to(work).transpose(2, 3) / math.sqrt(C // self.heads)  # [B,H,Nt,Nr]
        weights = torch.sigmoid(scores)
        if F is not None:
            m = epipolar_modulation(F, (h, w), (hr, wr), stride, self.sigma, target.device)
            weights = weights * m.to(work)[:, None]  # [B, 1, Nt, Nr] broadcast over heads
        weights = weights / weights.sum(-1, keepdim=True).clamp_min(1e-12)
        fused = weights @ v.to(work)  # [B, H, Nt, d]
        fused = fused.transpose(2, 3).reshape(B, C, h, w).to(target.dtype)
        out = target + self.to_out(fused)
        return (out, weights) if return_weights else out


class DepthwiseSeparableConv(nn.Module):
    """Depthwise k×k then pointwise 1×1 (Xception), as the paper uses to adapt fused features.

    ``zero_init`` zeroes the pointwise conv so the branch outputs exactly 0 until trained.
    """

    def __init__(
        self, in_channels: int, out_channels: int, kernel_size: int = 3, zero_init: bool = False
    ) -> None:
        super().__init__()
        if in_channels < 1 or out_channels < 1 or kernel_size < 1 or kernel_size % 2 == 0:
            raise ValueError(
                f"DepthwiseSeparableConv: channels must be >= 1 and kernel_size odd, got "
                f"in={in_channels}, out={out_channels}, kernel_size={kernel_size}"
            )
        self.depthwise = nn.Conv2d(
            in_channels, in_channels, kernel_size, padding=kernel_size // 2, groups=in_channels
        )
        self.pointwise = nn.Conv2d(in_channels, out_channels, 1)
        if zero_init:
            nn.init.zeros_(self.pointwise.weight)
            nn.init.zeros_(self.pointwise.bias)

    def forward(self, x: Tensor) -> Tensor:
        """[B, C_in, h, w] -> [B, C_out, h, w]."""
        return self.pointwise(self.depthwise(x))


class DWEAInjection(nn.Module):
    """Carries DWEA's fused bottleneck features into the U-Net's expansive path.

    Branch k upsamples the fused features by ``scales[k]`` (nearest, like the U-Net's own
    upsamplers, so the grids line up) and maps them to ``out_channels[k]`` with a
    :class:`DepthwiseSeparableConv` whose pointwise conv starts at zero: adding the outputs
    to the up-blocks' inputs is a no-op until trained.
    """

    def __init__(
        self, in_channels: int, out_channels: Sequence[int], scales: Sequence[int] = (1, 2, 4)
    ) -> None:
        super().__init__()
        if len(out_channels) != len(scales) or len(scales) == 0:
            raise ValueError(
                f"DWEAInjection: out_channels {list(out_channels)} and scales {list(scales)} "
                "must be non-empty and of equal length (one per injected up-block)"
            )
        if any(int(s) != s or s < 1 for s in scales):
            raise ValueError(f"DWEAInjection: scales must be positive integers, got {list(scales)}")
        self.scales = tuple(int(s) for s in scales)
        self.branches = nn.ModuleList(
            DepthwiseSeparableConv(in_channels, int(c), zero_init=True) for c in out_channels
        )

    def forward(
        self, fused: Tensor, sizes: Sequence[tuple[int, int]] | None = None
    ) -> list[Tensor]:
        """[B, C, h, w] -> [[B, out_channels[k], h·s_k, w·s_k] for each branch k].

        ``sizes`` optionally gives each branch's exact (h, w) instead of ``scales`` (for maps
        whose sizes were rounded up when the U-Net downsampled odd sizes).
        """
        if fused.dim() != 4:
            raise ValueError(f"DWEAInjection: fused must be [B, C, h, w], got {tuple(fused.shape)}")
        if sizes is not None and len(sizes) != len(self.branches):
            raise ValueError(
                f"DWEAInjection: sizes has {len(sizes)} entries, expected {len(self.branches)}"
            )
        outs = []
        for k, (scale, branch) in enumerate(zip(self.scales, self.branches)):
            size = tuple(sizes[k]) if sizes is not None else None
            if size == tuple(fused.shape[2:]) or (size is None and scale == 1):
                x = fused
            elif size is not None:
                x = tF.interpolate(fused, size=size, mode="nearest")
            else:
                x = tF.interpolate(fused, scale_factor=scale, mode="nearest")
            outs.append(branch(x))
        return outs
