"""Augmenting curated stage-2 samples without breaking their epipolar geometry.

A model trained on whole, unshifted 64-px views can tie what it adds to the pixel position
(the v1 model stamps the same blobs on every view: ``prosplat.improve.pattern``). Random crops
move the content across the frame, and random flips mirror it; the render, its alpha and the
ground truth move together, the reference with them, and the fundamental matrix between render
and reference is transformed to match, so DWEA still sees the true epipolar lines.

For pixel maps ``x' = T x`` applied to both images, ``x_ref'^T F' x' = 0`` holds with
``F' = T^-T F T^-1``.
"""

from __future__ import annotations

import torch
from torch import Tensor


def _translation(ox: float, oy: float) -> Tensor:
    """x' = x - o (a crop starting at column ox, row oy)."""
    return torch.tensor([[1.0, 0.0, -ox], [0.0, 1.0, -oy], [0.0, 0.0, 1.0]], dtype=torch.float64)


def _hflip(width: int) -> Tensor:
    """x' = W - x (continuous pixel coordinates: pixel c spans [c, c+1))."""
    return torch.tensor([[-1.0, 0.0, width], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def transform_fundamental(F: Tensor, T: Tensor, T_ref: Tensor) -> Tensor:
    """F [3,3] between render and reference after the pixel maps T (render) and T_ref."""
    Fd = F.double()
    return (torch.linalg.inv(T_ref).T @ Fd @ torch.linalg.inv(T)).to(F.dtype)


def augment_samples(
    render: Tensor,
    reference: Tensor,
    fundamental: Tensor,
    target: Tensor,
    alpha: Tensor | None,
    crop: int,
    flip: bool,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """Randomly crop (``crop`` px squares; 0 = none) and flip each sample of a batch.

    ``render``/``reference``/``target`` [B,3,H,W], ``alpha`` [B,C,H,W] (the render's alpha,
    and any other channels pixel-aligned with the render) or None, ``fundamental`` [B,3,3].
    Render, alpha and target share one window; the reference gets
    its own random window (it is another camera: what it shows is not pixel-aligned with the
    render anyway). Returns the same five, cropped to ``crop``.
    """
    b, _, h, w = render.shape
    size_h, size_w = (crop, crop) if crop else (h, w)
    if size_h > h or size_w > w:
        raise ValueError(f"crop {crop} is larger than the samples ({w}x{h})")
    outs: list[list[Tensor]] = [[], [], [], [], []]
    for i in range(b):
        oy, ox, ry, rx = (
            int(torch.randint(0, n + 1, (1,), generator=generator))
            for n in (h - size_h, w - size_w, h - size_h, w - size_w)
        )
        sl = (slice(None), slice(oy, oy + size_h), slice(ox, ox + size_w))
        rsl = (slice(None), slice(ry, ry + size_h), slice(rx, rx + size_w))
        r, t, ref = render[i][sl], target[i][sl], reference[i][rsl]
        a = None if alpha is None else alpha[i][sl]
        T, T_ref = _translation(ox, oy), _translation(rx, ry)
        if flip and bool(torch.randint(0, 2, (1,), generator=generator)):
            r, t, ref = r.flip(-1), t.flip(-1), ref.flip(-1)
            a = None if a is None else a.flip(-1)
            T, T_ref = _hflip(size_w) @ T, _hflip(size_w) @ T_ref
        outs[0].append(r)
        outs[1].append(ref)
        outs[2].append(transform_fundamental(fundamental[i], T, T_ref))
        outs[3].append(t)
        if a is not None:
            outs[4].append(a)
    r, ref, f, t = (torch.stack(x) for x in outs[:4])
    return r, ref, f, t, (torch.stack(outs[4]) if alpha is not None else None)
