"""Rolled cameras for free: a view turned by a quarter turn, its camera turned to match.

Why: every rendered training view is upright (Blender's cameras look at the scene with the sky
up), while photos come rolled: the Middlebury rings ship turned by 90 degrees, hand-held phones
tilt, portrait shots are stored on their side. A generator that has only seen upright views
matches rolled ones badly (BENCHMARKS "Real photos: eight posed sets": temple and dino).

A quarter turn of a square image is exact: no resampling, depth unchanged (the roll is about the
optical axis, so z stays), and the camera that sees the turned image is the old one rolled about
its axis with its intrinsics permuted. So one rendered scene serves every roll by a multiple of
90 degrees, for inputs and targets alike, each view on its own (views of one scene then disagree
in roll, as hand-held photos do).

Pixel convention: continuous coordinates, pixel ``c`` spans ``[c, c+1)`` (as everywhere here);
``torch.rot90(x, k, dims=(-2, -1))`` with ``k = 1`` maps the input pixel ``(x, y)`` of a
``W``-wide image to ``(y, W - x)`` and ``k = 3`` maps it to ``(H - y, x)``.
"""

from __future__ import annotations

import torch
from torch import Tensor


def quarter_turn_pixels(k: int, width: int, height: int) -> Tensor:
    """[3,3] float64 map of homogeneous pixel coordinates, input image -> ``torch.rot90(.., k)``
    of it (k in 0..3)."""
    k %= 4
    w, h = float(width), float(height)
    if k == 0:
        return torch.eye(3, dtype=torch.float64)
    if k == 1:
        return torch.tensor([[0.0, 1, 0], [-1, 0, w], [0, 0, 1]], dtype=torch.float64)
    if k == 2:
        return torch.tensor([[-1.0, 0, w], [0, -1, h], [0, 0, 1]], dtype=torch.float64)
    return torch.tensor([[0.0, -1, h], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)


def quarter_turn_camera(
    K: Tensor, w2c: Tensor, k: int, width: int, height: int
) -> tuple[Tensor, Tensor]:
    """The camera that sees ``torch.rot90(image, k, dims=(-2, -1))``: ``K [...,3,3]``,
    ``w2c [...,4,4]`` (OpenCV axes) -> the turned pair, same dtype.

    With ``A`` the pixel map and ``Q`` its 2x2 rotation embedded in 3x3, ``A K = K' Q``; so
    ``K' = A K Q^T`` (still upper triangular: fx and fy swap places, as do cx and cy), and the
    camera axes turn by ``Q``: ``w2c' = diag(Q, 1) w2c``.
    """
    A = quarter_turn_pixels(k, width, height).to(K.device)
    Q = torch.eye(3, dtype=torch.float64, device=K.device)
    Q[:2, :2] = A[:2, :2]
    K_new = (A @ K.double() @ Q.T).to(K.dtype)
    Q4 = torch.eye(4, dtype=torch.float64, device=w2c.device)
    Q4[:3, :3] = Q
    w2c_new = (Q4 @ w2c.double()).to(w2c.dtype)
    return K_new, w2c_new


def draw_quarter_turns(n: int, prob: float, generator: torch.Generator) -> list[int]:
    """``n`` turns: each view is turned with probability ``prob``, then by +90 or -90 degrees
    (never 180: an upside-down photo is rare, a portrait one is not)."""
    pick = torch.rand(n, generator=generator) < prob
    sign = torch.rand(n, generator=generator) < 0.5
    return [(1 if s else 3) if p else 0 for p, s in zip(pick.tolist(), sign.tolist())]


def roll_views(
    batch: dict[str, Tensor], prob: float, generator: torch.Generator
) -> dict[str, Tensor]:
    """Each view of a square batch (inputs and targets, each on its own) turned by a quarter
    turn with probability ``prob``, with its intrinsics, extrinsics and depth to match.

    ``batch``: ``{group}_images [B,V,3,S,S]``, ``{group}_K [B,V,3,3]``, ``{group}_w2c
    [B,V,4,4]`` and optionally ``{group}_depths [B,V,S,S]`` for group in input, target. A batch
    of non-square views is returned as it is (a turned view would not stack with the others).
    """
    h, w = batch["input_images"].shape[-2:]
    if prob <= 0 or h != w or batch["target_images"].shape[-2] != batch["target_images"].shape[-1]:
        return batch
    out = dict(batch)
    for group in ("input", "target"):
        images = batch[f"{group}_images"]  # [B,V,3,S,S]
        size = images.shape[-1]
        b, v = images.shape[:2]
        turns = draw_quarter_turns(b * v, prob, generator)
        if not any(turns):
            continue
        new = {key: batch[key].clone() for key in (f"{group}_images", f"{group}_K", f"{group}_w2c")}
        depths = batch.get(f"{group}_depths")
        new_depths = depths.clone() if depths is not None else None
        for idx, k in enumerate(turns):
            if k == 0:
                continue
            i, j = divmod(idx, v)
            new[f"{group}_images"][i, j] = torch.rot90(images[i, j], k, dims=(-2, -1))
            K, w2c = quarter_turn_camera(
                batch[f"{group}_K"][i, j], batch[f"{group}_w2c"][i, j], k, size, size
            )
            new[f"{group}_K"][i, j], new[f"{group}_w2c"][i, j] = K, w2c
            if new_depths is not None:
                new_depths[i, j] = torch.rot90(depths[i, j], k, dims=(-2, -1))
        out.update(new)
        if new_depths is not None:
            out[f"{group}_depths"] = new_depths
    return out
