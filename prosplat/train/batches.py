"""A training batch reshaped for one generator step: downsampled or cropped to the step's
size (the depths kept only where they mean one surface), framed in windows of other shapes,
turned into cameras; and the batch sampler that makes every step a function of (seed, step).

A batch is a dict of ``[B,V,...]`` tensors from :class:`prosplat.data.SceneDataset`:
``input_images``/``target_images`` ``[B,V,3,H,W]``, ``*_K`` ``[B,V,3,3]``, ``*_w2c``
``[B,V,4,4]``, optional ``*_depths`` ``[B,V,H,W]`` (0 = no surface), ``near``/``far`` ``[B]``.
"""

from __future__ import annotations

import random
from collections.abc import Iterator

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.train.common import Dist, draw_count, step_indices
from prosplat.train.generator_config import TrainConfig


def one_surface(depths: Tensor, k: int) -> Tensor:
    """depths [N,1,H,W] (0 = no surface) -> [N,1,H/k,W/k]: True where every ray of the k x k
    cell hit a surface and their depths lie within 5 % of each other, i.e. the cell sees one
    surface and its depth means something (not a blend with the sky or across an edge)."""
    hi = F.max_pool2d(depths, k)
    lo = -F.max_pool2d(-depths, k)  # 0 where any ray of the cell hit nothing
    return (lo > 0) & (hi <= lo * 1.05)


def resize_batch(
    batch: dict[str, Tensor], size: int, target_size: int | None = None
) -> dict[str, Tensor]:
    """Downsample a square batch's images, depths and intrinsics to ``size`` px: the inputs to
    ``size``, the targets to ``target_size`` (default ``size``).

    Images: antialiased bilinear (what a lower-resolution camera integrates). Depths: the
    bilinear value at the new pixel centre where the 2x2 (or larger) footprint agrees within
    5 %, else 0 (no supervision across depth edges or where part of it hit nothing, where a
    blend is no surface at all).
    """
    from prosplat.generator.cost_volume import scale_intrinsics

    h, w = batch["input_images"].shape[-2:]
    sizes = {"input": size, "target": size if target_size is None else target_size}
    if max(sizes.values()) > min(h, w):
        raise ValueError(
            f"cannot train at {max(sizes.values())} px on {w}x{h} data: render larger scenes"
        )
    out = dict(batch)
    for group, s in sizes.items():
        if (h, w) == (s, s):
            continue
        x = batch[f"{group}_images"]  # [B,M,3,H,W]
        y = F.interpolate(
            x.flatten(0, 1), size=(s, s), mode="bilinear", antialias=True, align_corners=False
        )
        out[f"{group}_images"] = y.clamp(0, 1).view(*x.shape[:2], 3, s, s)
        out[f"{group}_K"] = scale_intrinsics(batch[f"{group}_K"], s / w, s / h)
        if f"{group}_depths" not in batch:
            continue
        d = batch[f"{group}_depths"].flatten(0, 1)[:, None]  # [BM,1,H,W]
        mid = F.interpolate(d, size=(s, s), mode="bilinear", align_corners=False)
        ok = one_surface(d, h // s)  # a blend with the sky or across an edge is no depth
        shape = (*batch[f"{group}_depths"].shape[:2], s, s)
        out[f"{group}_depths"] = torch.where(ok, mid, torch.zeros_like(mid))[:, 0].view(shape)
    return out


def crop_batch(
    batch: dict[str, Tensor], size: int | tuple[int, int], top: int, left: int
) -> dict[str, Tensor]:
    """The ``size`` window (px, or (height, width)) at (top, left) of every image and depth of
    a batch, the intrinsics shifted to match: the same scene seen by narrower cameras, at the
    data's own pixel scale (no resampling, so depth stays exact). A cheap augmentation that
    makes one rendered scene serve several framings."""
    h, w = batch["input_images"].shape[-2:]
    ch, cw = (size, size) if isinstance(size, int) else size
    if not (0 <= top <= h - ch and 0 <= left <= w - cw):
        raise ValueError(f"crop {cw}x{ch} at ({top}, {left}) does not fit {w}x{h} images")
    out = dict(batch)
    for key in ("input_images", "target_images", "input_depths", "target_depths"):
        if key in batch:
            out[key] = batch[key][..., top : top + ch, left : left + cw]
    for key in ("input_K", "target_K"):
        if key not in batch:
            continue
        K = batch[key].clone()
        K[..., 0, 2] -= left
        K[..., 1, 2] -= top
        out[key] = K
    return out


#: The shortest side of a framing window (frame_window): the generator's 1/4-resolution
#: features need 16 cells across to match in.
MIN_FRAME = 64


def frame_window(h: int, w: int, rng: random.Random) -> tuple[int, int, int, int]:
    """A window (top, left, height, width) of an h x w frame that is not the whole frame:
    height and width drawn apart from the multiples of 32 in [:data:`MIN_FRAME`, the side],
    the place uniform.

    Why: every rendered scene is a square frame of one field of view, so a generator trained
    on them alone learns that shape. Generator v6 on the test scenes' 2:1 centre crops
    (the cameras' principal points moved to match) had twice the median input-depth AbsRel
    of the same pixels seen in the square frame (0.31 against 0.16), and 0.33 on a 64-px
    centre crop at the same focal length: users' cameras (16:9 in Blender, portrait phone
    photos) are not square.
    """
    hs = list(range(MIN_FRAME, h + 1, 32))
    ws = list(range(MIN_FRAME, w + 1, 32))
    if len(hs) * len(ws) < 2:
        raise ValueError(f"framing needs frames larger than {MIN_FRAME} px, got {w}x{h}")
    while True:
        ch, cw = rng.choice(hs), rng.choice(ws)
        if (ch, cw) != (h, w):
            return rng.randint(0, h - ch), rng.randint(0, w - cw), ch, cw


def step_view(batch: dict[str, Tensor], cfg: TrainConfig, step: int) -> dict[str, Tensor]:
    """This step's image size, and a crop or a downsample to reach it (seeded by the step).

    A crop takes the targets' window (``target_scale`` x the size, at most the data's); the
    inputs are then downsampled to the size. At the data's own size, ``frame_prob`` of the
    steps take a window of another shape (:func:`frame_window`) for inputs and targets."""
    size = draw_count(cfg.size_choices, cfg.seed + 7919, step)
    h, w = batch["input_images"].shape[-2:]
    big = min(size * cfg.target_scale, h, w)
    rng = random.Random(f"prosplat-crop/{cfg.seed}/{step}")
    if size == h == w and cfg.frame_prob > 0:
        frame = random.Random(f"prosplat-frame/{cfg.seed}/{step}")
        if frame.random() < cfg.frame_prob:
            top, left, ch, cw = frame_window(h, w, frame)
            return crop_batch(batch, (ch, cw), top, left)
    if size < min(h, w) and rng.random() < cfg.crop_prob:
        batch = crop_batch(batch, big, rng.randint(0, h - big), rng.randint(0, w - big))
    return resize_batch(batch, size, big)


def val_view(item: dict[str, Tensor], cfg: TrainConfig) -> dict[str, Tensor]:
    """A validation item as the pipeline sees it: the inputs at the largest training size
    (the size the weights run at), the targets ``target_scale`` x that (at most the data's).
    Without ``sizes``, the data's own size."""
    if not cfg.size_choices:
        return item
    size = max(cfg.size_choices)
    h, w = item["input_images"].shape[-2:]
    if size > min(h, w):
        return item
    return resize_batch(item, size, min(size * cfg.target_scale, h, w))


def batch_cameras(K: Tensor, w2c: Tensor, width: int, height: int) -> list[Camera]:
    """[V,3,3], [V,4,4] -> cameras (float64 so poses stay orthonormal to 1e-4)."""
    return [Camera(K[v].double(), w2c[v].double(), width, height) for v in range(K.shape[0])]


def to_device(batch: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    return {k: v.to(device) for k, v in batch.items()}


def model_inputs(batch: dict[str, Tensor]) -> tuple[Tensor, ...]:
    return batch["input_images"], batch["input_K"], batch["input_w2c"], batch["near"], batch["far"]


class StepBatches:
    """Batch sampler over global steps ``first..last-1``: each batch is this rank's
    :class:`~prosplat.data.dataset.ItemKey` list for that step (scenes from
    :func:`step_indices`, one view count from :func:`draw_count`)."""

    def __init__(self, n_items: int, cfg: TrainConfig, first: int, dist: Dist) -> None:
        self.n_items, self.cfg, self.first, self.dist = n_items, cfg, first, dist

    def __len__(self) -> int:
        return max(0, self.cfg.last_step - self.first)

    def __iter__(self) -> Iterator[list]:
        from prosplat.data.dataset import ItemKey

        cfg, d = self.cfg, self.dist
        for step in range(self.first, cfg.last_step):
            epoch, idx = step_indices(self.n_items, cfg.batch, cfg.seed, step, d.rank, d.world_size)
            n = draw_count(cfg.view_counts, cfg.seed, step)
            yield [ItemKey(i, epoch, n) for i in idx]
