"""Detecting a fixed, content-independent pattern in what stage 2 adds to renders.

A model can learn to stamp the same picture on every output (a row of blobs, a grid, a
border): PSNR averages hide it, eyes do not. The test: average the changes ``enhanced - raw``
of many views of different scenes. Content-dependent changes point different ways in
different views and average towards zero; a fixed pattern adds up. Per pixel and channel,
``t = mean / (std / sqrt(N))`` over the views says how far the average stands above what
chance gives; the statistic is the mean ``t^2`` of the top 1 % of pixels (a pattern can be a
small row of blobs). The control computes the same after moving each view's change by a
random circular shift and flips, which keeps every view's content and energy but breaks any
position-locked pattern. Each view's constant offset per channel (a global brightening) is
removed first: it is not a pattern. The score is statistic / control: about 1 means no fixed
pattern; above 2 is a pattern (the v1 model: see BENCHMARKS).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class PatternScore:
    """``ratio`` = ``structure / control``: the top-1 % mean ``t^2`` of the changes, over the
    median of ``controls`` shuffled copies'. ``views`` averaged."""

    ratio: float
    structure: float
    control: float
    views: int


#: The fraction of pixel-channels whose t^2 the statistic averages.
TOP_FRACTION = 0.01


def _structure(changes: Tensor) -> float:
    """Mean of the top :data:`TOP_FRACTION` of per-pixel ``t^2`` over ``changes [N,3,H,W]``."""
    n = changes.shape[0]
    mean, std = changes.mean(0), changes.std(0).clamp_min(1e-12)
    t2 = (mean / (std / n**0.5)).pow(2).flatten()
    k = max(1, int(TOP_FRACTION * t2.numel()))
    return float(t2.topk(k).values.mean())


def fixed_pattern_score(changes: Tensor, controls: int = 16, seed: int = 0) -> PatternScore:
    """How much of the average of ``changes [N,3,H,W]`` (enhanced - raw, one view each, the
    same size) is locked to image position (module docstring)."""
    if changes.ndim != 4 or changes.shape[1] != 3 or changes.shape[0] < 2:
        raise ValueError(f"changes must be [N>=2,3,H,W], got {list(changes.shape)}")
    _, _, h, w = changes.shape
    changes = changes.double()
    changes = changes - changes.mean(dim=(2, 3), keepdim=True)  # no global offsets
    structure = _structure(changes)
    g = torch.Generator().manual_seed(seed)
    shuffled = []
    for _ in range(controls):
        moved = []
        for x in changes:
            dy, dx = (int(v) for v in torch.randint(0, max(h, w), (2,), generator=g))
            y = torch.roll(x, shifts=(dy % h, dx % w), dims=(1, 2))
            if bool(torch.randint(0, 2, (1,), generator=g)):
                y = y.flip(2)
            if bool(torch.randint(0, 2, (1,), generator=g)):
                y = y.flip(1)
            moved.append(y)
        shuffled.append(_structure(torch.stack(moved)))
    control = float(torch.tensor(shuffled).median())
    ratio = structure / control if control > 0 else (float("inf") if structure > 0 else 1.0)
    return PatternScore(ratio=ratio, structure=structure, control=control, views=changes.shape[0])


@dataclass(frozen=True)
class LatticeScore:
    """``ratio``: the mean power of the changes at the lattice frequencies over the mean
    power at the frequencies around them; ``period`` in pixels; ``views`` averaged."""

    ratio: float
    period: int
    views: int


def lattice_score(changes: Tensor, period: int = 16) -> LatticeScore:
    """How much of what stage 2 adds repeats every ``period`` pixels, in any phase.

    :func:`fixed_pattern_score` misses a lattice whose phase follows the image (v3 paints blobs
    on a 16-px lattice wherever a render is washed out, BENCHMARKS "Stage 2 v3"): averaging the
    changes cancels it. Averaging their *power spectra* does not, since a shift only changes a
    spectrum's phase. The statistic: the mean power of ``changes [N,3,H,W]`` at the lattice's
    harmonics ``(i·H/period, j·W/period)`` (not both 0), over the mean power of the bins
    around each. About 1: no lattice; a lattice of the period gives a large ratio.

    Around a harmonic on an axis (``i`` or ``j`` 0) means the 4 nearest bins on that axis,
    not the 8-bin ring: structure that varies along one image axis only (a sky-to-floor
    gradient, a table edge) puts its power on that axis and nowhere else, so a ring that is
    mostly off the axis would call any such image a lattice. With the ring everywhere the
    probe's own ideal change (sharp view minus hazed render) scored 1.35, above the shipped
    v7 and close to the bar; BENCHMARKS "Stage 2 v10".
    """
    if changes.ndim != 4 or changes.shape[1] != 3 or changes.shape[0] < 1:
        raise ValueError(f"changes must be [N>=1,3,H,W], got {list(changes.shape)}")
    _, _, h, w = changes.shape
    if period < 2 or h % period or w % period:
        raise ValueError(f"the views ({w}x{h}) must be a multiple of the period ({period})")
    x = changes.double()
    x = x - x.mean(dim=(2, 3), keepdim=True)
    power = torch.fft.fft2(x).abs().pow(2).mean(dim=(0, 1))  # [H,W] mean over views, channels
    fy, fx = h // period, w // period
    ring8 = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
    along_y, along_x = [(d, 0) for d in (-2, -1, 1, 2)], [(0, d) for d in (-2, -1, 1, 2)]
    peaks, around = [], []
    for i in range(period):
        for j in range(period):
            if i == 0 and j == 0:
                continue
            y, xx = i * fy, j * fx
            peaks.append(power[y, xx])
            ring = along_x if i == 0 else along_y if j == 0 else ring8
            around.append(
                torch.stack([power[(y + dy) % h, (xx + dx) % w] for dy, dx in ring]).mean()
            )
    ratio = float(torch.stack(peaks).mean() / torch.stack(around).mean().clamp_min(1e-30))
    return LatticeScore(ratio=ratio, period=period, views=changes.shape[0])
