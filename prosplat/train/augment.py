"""Augmenting curated stage-2 samples without breaking their epipolar geometry.

A model trained on whole, unshifted 64-px views can tie what it adds to the pixel position
(the v1 model stamps the same blobs on every view: ``prosplat.improve.pattern``). Random crops
move the content across the frame, and random flips mirror it; the render, its alpha and the
ground truth move together, the reference with them, and the fundamental matrix between render
and reference is transformed to match, so DWEA still sees the true epipolar lines.

For pixel maps ``x' = T x`` applied to both images, ``x_ref'^T F' x' = 0`` holds with
``F' = T^-T F T^-1``.

Crops alone do not stop a stage-2 model from tying a pattern to its own grid: its VAE works
on 8-px latent cells, and what it adds can depend on where a pixel sits in its cell (v7 and v9
fill the generator's holes with a grid of such cells: BENCHMARKS "Stage 2 v10").
:func:`shifted_pairs` gives the same window twice, the second moved by a few pixels, so
training can ask for the same answer at both places.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def _translation(ox: float, oy: float) -> Tensor:
    """x' = x - o (a crop starting at column ox, row oy)."""
    return torch.tensor([[1.0, 0.0, -ox], [0.0, 1.0, -oy], [0.0, 0.0, 1.0]], dtype=torch.float64)


def _hflip(width: int) -> Tensor:
    """x' = W - x (continuous pixel coordinates: pixel c spans [c, c+1))."""
    return torch.tensor([[-1.0, 0.0, width], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def transform_fundamental(F: Tensor, T: Tensor, T_ref: Tensor) -> Tensor:
    """F [3,3] between render and reference after the pixel maps T (render) and T_ref."""
    Fd = F.double()  # the pixel maps are built on the CPU; F may live on a GPU
    T, T_ref = T.to(Fd.device), T_ref.to(Fd.device)
    return (torch.linalg.inv(T_ref).T @ Fd @ torch.linalg.inv(T)).to(F.dtype)


def _window(
    render: Tensor,
    reference: Tensor,
    fundamental: Tensor,
    target: Tensor,
    alpha: Tensor | None,
    at: tuple[int, int, int, int],
    size: tuple[int, int],
    flipped: bool,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """One sample ([3,H,W] images, [3,3] F, [C,H,W] alpha or None) cropped to ``size`` (h, w)
    at ``at`` = (render row, column, reference row, column), flipped if ``flipped``."""
    (oy, ox, ry, rx), (size_h, size_w) = at, size
    sl = (slice(None), slice(oy, oy + size_h), slice(ox, ox + size_w))
    rsl = (slice(None), slice(ry, ry + size_h), slice(rx, rx + size_w))
    r, t, ref = render[sl], target[sl], reference[rsl]
    a = None if alpha is None else alpha[sl]
    T, T_ref = _translation(ox, oy), _translation(rx, ry)
    if flipped:
        r, t, ref = r.flip(-1), t.flip(-1), ref.flip(-1)
        a = None if a is None else a.flip(-1)
        T, T_ref = _hflip(size_w) @ T, _hflip(size_w) @ T_ref
    return r, ref, transform_fundamental(fundamental, T, T_ref), t, a


def _stack(
    outs: list[tuple], with_alpha: bool
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    r, ref, f, t, a = zip(*outs, strict=True)
    return (torch.stack(r), torch.stack(ref), torch.stack(f), torch.stack(t),
            torch.stack(a) if with_alpha else None)  # fmt: skip


def _randint(n: int, generator: torch.Generator) -> int:
    """Uniform in [0, n]."""
    return int(torch.randint(0, n + 1, (1,), generator=generator))


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
    outs = []
    for i in range(b):
        at = tuple(_randint(n, generator) for n in (h - size_h, w - size_w, h - size_h, w - size_w))
        flipped = flip and bool(torch.randint(0, 2, (1,), generator=generator))
        a = None if alpha is None else alpha[i]
        outs.append(_window(render[i], reference[i], fundamental[i], target[i], a, at,
                            (size_h, size_w), flipped))  # fmt: skip
    return _stack(outs, alpha is not None)


#: The largest shift between a window and its twin (px): with 1-7 px every phase of the VAE's
#: 8-px cells is met.
MAX_SHIFT = 7


def shifted_pairs(
    render: Tensor,
    reference: Tensor,
    fundamental: Tensor,
    target: Tensor,
    alpha: Tensor | None,
    crop: int,
    flip: bool,
    generator: torch.Generator,
    max_shift: int = MAX_SHIFT,
) -> tuple[tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None], Tensor, Tensor]:
    """Each sample as two ``crop``-px windows, the second ``(dy, dx)`` px further down and
    right (each in ``[0, max_shift]``, not both 0), with one flip and one reference window.

    Inputs as :func:`augment_samples`. Returns the five tensors with ``2B`` samples (the
    first windows, then the shifted ones), ``shifts`` [B,2] (dy, dx): pixel ``(y, x)`` of a
    first window is pixel ``(y - dy, x - dx)`` of its twin, in unflipped coordinates, and
    ``flipped`` [B] bool.
    """
    b, _, h, w = render.shape
    if crop + max_shift > min(h, w):
        raise ValueError(f"crop {crop} + shift {max_shift} is larger than the samples ({w}x{h})")
    firsts, seconds, shifts, flips = [], [], [], []
    for i in range(b):
        dy, dx = 0, 0
        while dy == dx == 0:
            dy, dx = _randint(max_shift, generator), _randint(max_shift, generator)
        oy, ox = _randint(h - crop - dy, generator), _randint(w - crop - dx, generator)
        ry, rx = _randint(h - crop, generator), _randint(w - crop, generator)
        flipped = flip and bool(torch.randint(0, 2, (1,), generator=generator))
        a = None if alpha is None else alpha[i]
        sample = (render[i], reference[i], fundamental[i], target[i], a)
        firsts.append(_window(*sample, (oy, ox, ry, rx), (crop, crop), flipped))
        seconds.append(_window(*sample, (oy + dy, ox + dx, ry, rx), (crop, crop), flipped))
        shifts.append((dy, dx))
        flips.append(flipped)
    pairs = _stack(firsts + seconds, alpha is not None)
    return pairs, torch.tensor(shifts, dtype=torch.long), torch.tensor(flips)


def subpixel_translate(x: Tensor, delta: Tensor) -> Tensor:
    """``x [B,C,H,W]`` resampled (bilinear, edges repeated) so that pixel ``p`` of the result is
    ``x`` at ``p + delta[b]`` (``delta [B,2]``: dy, dx in pixels, fractional): what a camera
    moved by a fraction of a pixel would see. Used to make the shift term's twins differ by
    a sub-pixel motion as well (``ImproveTrainConfig.subpixel_shift``): enhancing must not
    invent detail that jumps when the render is resampled, which is what flickers along a
    camera path."""
    b, _, h, w = x.shape
    ys = torch.arange(h, dtype=x.dtype, device=x.device)[None, :, None] + delta[:, :1, None]
    xs = torch.arange(w, dtype=x.dtype, device=x.device)[None, None, :] + delta[:, 1:, None]
    grid = torch.stack(  # [B,H,W,2] in grid_sample's (x, y), align_corners=True coordinates
        [
            (2 * xs / max(w - 1, 1) - 1).expand(b, h, w),
            (2 * ys / max(h - 1, 1) - 1).expand(b, h, w),
        ],
        dim=-1,
    )
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=True)


#: Pixels this close to a window's edge are left out of :func:`shift_disagreement`: the
#: padding there is where a window may rightly differ from its twin.
SHIFT_MARGIN = 8


def shift_disagreement(
    out: Tensor, shifts: Tensor, flipped: Tensor, margin: int = SHIFT_MARGIN
) -> Tensor:
    """Mean squared difference between what the model made of each window and of its shifted
    twin, where both show the same pixels at least ``margin`` px inside both windows.

    ``out`` [2B,3,S,S] (firsts then twins, as :func:`shifted_pairs` orders them), ``shifts``
    [B,2], ``flipped`` [B] bool (whether the pair was flipped: compared unflipped).
    A model whose output moves with its input scores 0; the 8-px-cell pattern does not.
    """
    b = shifts.shape[0]
    size = out.shape[-1]
    if size - 2 * margin - int(shifts.max()) < 1:
        raise ValueError(f"{size}-px windows moved {int(shifts.max())} px share no pixels "
                         f"{margin} px inside both")  # fmt: skip
    diffs = []
    for i in range(b):
        a, t = out[i], out[b + i]
        if bool(flipped[i]):
            a, t = a.flip(-1), t.flip(-1)
        dy, dx = (int(v) for v in shifts[i])
        # first-window pixel y <-> twin pixel y - dy; keep y - dy >= margin, y < size - margin
        ys, xs = slice(dy + margin, size - margin), slice(dx + margin, size - margin)
        yt, xt = slice(margin, size - margin - dy), slice(margin, size - margin - dx)
        diffs.append((a[:, ys, xs] - t[:, yt, xt]).square().mean())
    return torch.stack(diffs).mean()
