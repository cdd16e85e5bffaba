"""Training the stage-1 generator on Blender-rendered scenes.

One script for the CPU, one GPU, or several. The loss renders the target views from the
predicted Gaussians with the differentiable rasterizer: MSE + λ·LPIPS (+ optional SSIM and
depth terms against Blender's depth). Every step is logged to ``log.jsonl``; seeds are fixed.

Launch commands (the same script; re-running with the same ``--out`` resumes)::

    # CPU (or the one GPU if CUDA is available; --device picks explicitly)
    prosplat train generator --data data/train128 --val data/val128 --out runs/tiny128 \\
        --config tiny --inputs 2,4,6 --batch 2
    # one GPU
    prosplat train generator --device cuda --data ... --out ... --batch 4
    # several GPUs on one machine (NCCL): K processes, each its own GPU and shard
    torchrun --standalone --nproc_per_node K -m prosplat train generator --data ... --batch 4
    # several CPU processes (gloo), e.g. to check a distributed setup without a GPU
    torchrun --standalone --nproc_per_node 2 -m prosplat train generator --device cpu ...

What K processes compute: ``--batch`` is per process, so one step trains on ``K·batch``
scenes. Step ``s`` uses a seeded permutation of the scenes cut into global batches of
``K·batch`` (:func:`prosplat.train.common.step_indices`); rank ``r`` takes the ``r``-th slice and
DDP averages the gradients, so K processes with ``--batch B`` take the same steps as one process
with ``--batch K·B`` (up to float summation order; tests/train/test_train.py checks this with 2 gloo
processes). The learning rate is not scaled with K. Only rank 0 writes checkpoints, the log and
the progress bar; the logged loss is the mean over ranks.

Variable input views: ``--inputs 2,4,6`` draws each step's view count from the set with a RNG
seeded by (seed, step) (all items of a step share it, every rank draws the same); ``--inputs 2``
fixes it. Validation scores every count and logs the mean plus ``val_psnr_<N>v`` per count.

Fine-tuning DepthSplat: ``--init depthsplat-gs-*.pth`` trains only its Gaussian regressor and
head on the scenes, the rest frozen, and writes ``<init stem>-prosplat-ft.pth`` (DepthSplat's
released layout, loadable with ``ProSplat.from_pretrained(generator=...)``) beside the usual
resumable checkpoint pair; see :mod:`prosplat.train.depthsplat_heads`::

    prosplat train generator --init ~/models/depthsplat-gs-small-re10k-256x256-view2-cfeab6b1.pth \\
        --data data/train --val data/val --out runs/ds-small-ft --inputs 2,4

Checkpoints (:func:`prosplat.train.common.save_checkpoint`): ``checkpoint.safetensors`` (the
weights, loadable with ``ProSplat.from_pretrained``; the step is in its metadata) and
``state.pt`` (optimiser, step, RNG), each written atomically, with the previous weights kept as
``checkpoint.prev.safetensors``. A resume takes the newest pair whose steps agree, so a kill
between the two writes continues from the last consistent step, never a mix. Data order and
view counts are functions of (seed, step), so a resumed run continues the same sequence.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.generator.config import MAX_ALEXNET_LAYERS
from prosplat.render import render
from prosplat.render.hole_fill import fill_holes
from prosplat.train.common import (
    Dist,
    changed_settings,
    check_intervals,
    claim_run_folder,
    draw_count,
    load_checkpoint,
    pick_device,
    save_checkpoint,
    setup_distributed,
    step_indices,
    steps_per_epoch,
    truncate_log,
)
from prosplat.train.ema import WeightAverage

if TYPE_CHECKING:
    from prosplat.data import SceneDataset

__all__ = [
    "TrainConfig",
    "batch_cameras",
    "input_counts",
    "lr_at",
    "parse_inputs",
    "pick_device",
    "render_loss",
    "train",
    "validate",
]


def input_counts(value: int | str | Sequence[int]) -> tuple[int, ...]:
    """The set of input-view counts a run trains on, sorted and de-duplicated.

    Accepts an int (``2``), a comma-separated string (``"2,4,6"``) or a sequence of ints.

    Raises:
        ValueError: a count outside 2-6 (the generator's range) or text that is not integers.
    """
    if isinstance(value, str):
        try:
            items = [int(v) for v in value.replace(" ", "").split(",") if v]
        except ValueError:
            raise ValueError(
                f"inputs must be a count 2-6 or a comma-separated set like 2,4,6, got {value!r}"
            ) from None
    elif isinstance(value, int):
        items = [value]
    else:
        items = [int(v) for v in value]
    if not items or any(not 2 <= n <= 6 for n in items):
        raise ValueError(f"input-view counts must each be 2-6, got {value!r}")
    return tuple(sorted(set(items)))


def parse_inputs(text: str) -> int | tuple[int, ...]:
    """argparse type for ``--inputs``: ``"4"`` → 4, ``"2,4,6"`` → (2, 4, 6)."""
    try:
        counts = input_counts(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return counts[0] if len(counts) == 1 else counts


def train_sizes(text: str) -> tuple[int, ...]:
    """``"64,128"`` -> (64, 128); each a multiple of 32 (the generator's stride)."""
    try:
        sizes = tuple(sorted({int(v) for v in str(text).replace(" ", "").split(",") if v}))
    except ValueError:
        raise ValueError(
            f"sizes must be comma-separated integers like 64,128, got {text!r}"
        ) from None
    if any(v < 32 or v % 32 for v in sizes):
        raise ValueError(f"training sizes must be multiples of 32, got {text!r}")
    return sizes


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


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on; saved beside its checkpoints as ``train_config.json``."""

    data: str
    out: str
    config: str = "tiny"  # generator preset: "tiny" | "base"
    val: str | None = None
    steps: int = 20_000
    # stop (with a checkpoint) after this step, the schedule still following ``steps``: a long
    # run taken in bounded parts, each part the same steps a single run would take
    stop_at: int | None = None
    batch: int = 1  # scenes per step per process
    inputs: int | str | tuple[int, ...] = 2  # a count, or a set drawn from per step
    targets: int = 2
    lr: float = 2e-4
    weight_decay: float = 0.01
    lpips_weight: float = 0.05
    ssim_weight: float = 0.0
    depth_weight: float = 0.0  # rendered vs Blender depth at the targets (see depth_loss)
    # the generator's per-input-view depth maps vs Blender's: direct supervision of the depth
    # head (DepthSplat gets it from a pretrained depth model; see depth_loss)
    input_depth_weight: float = 0.0
    # cross-entropy of the depth head's distribution (its 1/4-resolution logits) against
    # Blender's input depth as a two-hot over the bracketing candidates (see depth_ce): the L1
    # terms above reach the head through the softmax's expectation, whose gradient on a
    # candidate is proportional to that candidate's probability, so a confident wrong peak
    # (an object flattened into the floor behind it) gets almost none; this term pushes the
    # true candidate up whatever mass it has. 0: off
    input_depth_ce_weight: float = 0.0
    # how both depth terms compare depths: "inverse" (L1 of 1/z, in scene units, so scenes of
    # small depth weigh most) or "log" (L1 of log z: the relative error AbsRel scores, the same
    # for a scene at any scale)
    depth_loss: str = "inverse"
    # the input cameras re-rendered from ALL views' Gaussians, scored like targets (colour, and
    # depth with depth_weight): makes the views' Gaussians agree where they see one surface
    input_render_weight: float = 0.0
    # score every render with its holes filled by pull-push (prosplat.render.hole_fill), as the
    # product shows a raw render and stage 2 sees it: a black hole costs more than any surface
    # gains (BENCHMARKS "Holes"), which pushes Gaussians out over what no input saw; filled,
    # a hole costs what the continuation of its surroundings misses
    fill_holes: bool = False
    # image sizes drawn per step (e.g. "64,128"; empty = the data's size): one set of weights
    # for every size; data is downsampled, never upsampled
    sizes: str = ""
    # targets at this multiple of the step's size (at most the data's): the pipeline runs the
    # generator at its trained size and renders its Gaussians for cameras with more pixels,
    # so Gaussians trained only at the input size leave pinholes there
    target_scale: int = 1
    any_view: bool = False  # draw inputs/targets from all of a scene's views (SceneDataset)
    # at a size below the data's, this share of steps crops a window instead of downsampling
    crop_prob: float = 0.0
    # at the data's size, this share of steps crops a window of another shape (see
    # frame_window): other aspect ratios and narrower fields of view than the square renders
    frame_prob: float = 0.0
    cache_scenes: int = 32  # decoded scenes kept in memory (raise it where memory allows)
    # start from these weights (a fresh optimiser, step 0): prosplat's .safetensors trains
    # the whole generator; a DepthSplat .pth fine-tunes its Gaussian heads only, the rest
    # frozen (prosplat.train.depthsplat_heads; ``config`` is then unused)
    init: str | None = None
    # with a prosplat ``init`` without fine matching: add a 1/2-resolution cost volume of this
    # many channels, entering through zero weights so step 0 is the init's generator
    # (prosplat.generator.grow); 0 = the network of ``config``
    grow_fine_matching: int = 0
    # with a prosplat ``init`` without them: add frozen AlexNet relu1..relu<n> features to the
    # monocular branch through zero weights (prosplat.generator.grow.grow_alexnet); 0 = off
    grow_alexnet: int = 0
    # with a prosplat ``init`` without it: add the images' own ZNCC plane sweep with this odd
    # window to the depth head through zero weights (grow.grow_image_matching); 0 = off
    grow_image_matching: int = 0
    # with a prosplat ``init`` without it: add the learned depth sweep over this many band
    # depths after the depth refiner, through a zero convolution (grow.grow_band); 0 = off
    grow_band: int = 0
    grad_clip: float = 0.5
    # > 0: the saved weights are an exponential moving average of the trained ones with this
    # decay (prosplat.train.ema: about the last tenth of its updates, up to 1 / (1 - decay)
    # steps once warmed up, 500 for 0.998 after ~4,500 updates); the raw weights
    # travel in state.pt for resuming, and validation scores the raw ones. 0: off
    ema: float = 0.0
    warmup: int = 500
    log_every: int = 10
    val_every: int = 1000
    val_scenes: int = 8
    save_every: int = 500
    seed: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        check_intervals(self, "log_every", "val_every", "save_every")
        input_counts(self.inputs)  # fail at construction, not at the first step
        if self.depth_loss not in DEPTH_LOSSES:
            raise ValueError(
                f"depth_loss must be one of {list(DEPTH_LOSSES)}, got {self.depth_loss!r}"
            )
        train_sizes(self.sizes)
        if self.stop_at is not None and self.stop_at < 1:
            raise ValueError(f"stop_at must be >= 1, got {self.stop_at}")
        if self.target_scale < 1:
            raise ValueError(f"target_scale must be >= 1, got {self.target_scale}")
        if self.grow_fine_matching < 0:
            raise ValueError(f"grow_fine_matching must be >= 0, got {self.grow_fine_matching}")
        if self.input_depth_ce_weight < 0:
            raise ValueError(
                f"input_depth_ce_weight must be >= 0, got {self.input_depth_ce_weight}"
            )
        for name in ("crop_prob", "frame_prob"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if not 0 <= self.ema < 1:
            raise ValueError(f"ema is a decay in [0, 1) (0: off), got {self.ema}")
        if self.frame_prob > 0 and not self.sizes:
            raise ValueError("frame_prob frames the steps drawn at the data's size: give sizes")
        if not 0 <= self.grow_alexnet <= MAX_ALEXNET_LAYERS:
            raise ValueError(
                f"grow_alexnet must be 0-{MAX_ALEXNET_LAYERS}, got {self.grow_alexnet}"
            )
        if self.grow_image_matching < 0 or (
            self.grow_image_matching and self.grow_image_matching % 2 == 0
        ):
            raise ValueError(
                f"grow_image_matching is an odd window (0: off), got {self.grow_image_matching}"
            )
        if self.grow_band < 0 or self.grow_band == 1:
            raise ValueError(f"grow_band is a candidate count >= 2 (0: off), got {self.grow_band}")
        for name in ("grow_fine_matching", "grow_alexnet", "grow_image_matching", "grow_band"):
            if getattr(self, name) and not (self.init or "").endswith(".safetensors"):
                raise ValueError(f"{name} needs --init with prosplat generator weights")

    @property
    def last_step(self) -> int:
        """The step this invocation trains to: ``stop_at`` when set, else ``steps``."""
        return self.steps if self.stop_at is None else min(self.stop_at, self.steps)

    @property
    def size_choices(self) -> tuple[int, ...]:
        """The image sizes steps draw from (empty: the data's own size)."""
        return train_sizes(self.sizes)

    @property
    def view_counts(self) -> tuple[int, ...]:
        """The view counts steps draw from (one element for a fixed count)."""
        return input_counts(self.inputs)


def batch_cameras(K: Tensor, w2c: Tensor, width: int, height: int) -> list[Camera]:
    """[V,3,3], [V,4,4] -> cameras (float64 so poses stay orthonormal to 1e-4)."""
    return [Camera(K[v].double(), w2c[v].double(), width, height) for v in range(K.shape[0])]


def _render_views(
    gaussians, cams: list[Camera], bg: Tensor, cpu_backend: str = "cpu-fused"
) -> tuple[Tensor, Tensor, Tensor]:
    """Render the loss's cameras (one size): rgb [C,3,H,W], alpha [C,H,W], depth [C,H,W].

    With gsplat on CUDA all cameras go in one call (:func:`render_gsplat_views`). On CUDA
    without gsplat the Gaussians go to the CPU rasterizer and the outputs come back (autograd
    follows both copies), so a GPU still trains the network. On the CPU the projection is
    the fused C++ kernel (``cpu_backend``): the torch projection computes the same float64
    numbers (the render tests hold them together) through ~100 ops whose autograd cost ~20 %
    of a training step (``benchmarks/generator_step.py``).
    """
    from prosplat.render import _gsplat_available

    device = gaussians.device
    if device.type == "cuda" and _gsplat_available(device):
        from prosplat.render.gsplat_backend import render_gsplat_views

        return render_gsplat_views(gaussians, cams, bg)
    # the CPU path moves non-CPU Gaussians to the CPU and its outputs back
    outs = [render(gaussians, cam, background=bg, backend=cpu_backend) for cam in cams]
    rgb, alpha, depth = (
        torch.stack([getattr(o, k) for o in outs]) for k in ("rgb", "alpha", "depth")
    )
    return rgb, alpha, depth


def render_loss(
    output,
    batch: dict[str, Tensor],
    cfg: TrainConfig,
    lpips_fn=None,
    cpu_backend: str = "cpu-fused",
) -> tuple[Tensor, dict[str, float]]:
    """Render every target view of every scene in the batch and compare with ground truth.

    With ``input_render_weight`` the input cameras are rendered too (from all views'
    Gaussians) and scored the same way, weighted by it.

    Returns the loss (a mean over the batch's views, so DDP's gradient average over
    ranks equals one process's mean over the union) and its parts (floats, for the log).
    """
    from prosplat.metrics import ssim

    targets = batch["target_images"]  # [B,M,3,H,W] (inputs may be smaller: target_scale)
    b_size, m = targets.shape[:2]
    bg = torch.zeros(3, device=targets.device)
    groups = [("target", 1.0)]
    if cfg.input_render_weight > 0:
        groups.append(("input", cfg.input_render_weight))
    zero = targets.new_zeros(())
    sums = {k: zero for k in ("mse", "lpips", "ssim", "depth", "input_mse")}
    for b in range(b_size):
        gaussians = output.gaussians(b)
        for group, weight in groups:
            images, depths = batch[f"{group}_images"][b], batch.get(f"{group}_depths")
            h, w = images.shape[-2:]
            cams = batch_cameras(batch[f"{group}_K"][b], batch[f"{group}_w2c"][b], w, h)
            rgb, alpha, depth = _render_views(gaussians, cams, bg, cpu_backend)  # [C,3,H,W]
            if cfg.fill_holes:
                rgb = fill_holes(rgb, alpha)  # [C,3,H,W], covered pixels unchanged
            mse = ((rgb - images) ** 2).mean(dim=(1, 2, 3))  # [C]
            if group == "input":
                sums["input_mse"] = sums["input_mse"] + mse.detach().sum()
            sums["mse"] = sums["mse"] + weight * mse.sum()
            if lpips_fn is not None and cfg.lpips_weight > 0:
                sums["lpips"] = sums["lpips"] + weight * lpips_fn(rgb, images).sum()
            for j in range(len(cams)):
                if cfg.ssim_weight > 0:
                    sums["ssim"] = sums["ssim"] + weight * (1 - ssim(rgb[j], images[j]))
                if cfg.depth_weight > 0 and depths is not None:
                    gt_d = depths[b, j]
                    valid = (gt_d > 0) & (alpha[j] > 0.5)
                    if valid.any():
                        err = depth_error(depth[j][valid], gt_d[valid], cfg.depth_loss)
                        sums["depth"] = sums["depth"] + weight * err
    n = b_size * m
    parts = {k: v / n for k, v in sums.items()}
    if cfg.input_render_weight > 0:
        parts["input_mse"] = sums["input_mse"] / (b_size * batch["input_images"].shape[1])
    parts["input_depth"] = zero
    if cfg.input_depth_weight > 0 and "input_depths" in batch:
        gt_d = batch["input_depths"]  # [B,V,H,W], 0 = no surface
        valid = gt_d > 0
        if valid.any():
            parts["input_depth"] = depth_error(output.depths[valid], gt_d[valid], cfg.depth_loss)
    parts["input_depth_ce"] = zero
    if cfg.input_depth_ce_weight > 0 and "input_depths" in batch:
        if output.depth_logits is None:
            raise ValueError("--input-depth-ce-weight needs a generator with a depth head")
        parts["input_depth_ce"] = depth_ce(
            output.depth_logits, batch["input_depths"], batch["near"], batch["far"]
        )
    loss = (
        parts["mse"]
        + cfg.lpips_weight * parts["lpips"]
        + cfg.ssim_weight * parts["ssim"]
        + cfg.depth_weight * parts["depth"]
        + cfg.input_depth_weight * parts["input_depth"]
        + cfg.input_depth_ce_weight * parts["input_depth_ce"]
    )
    return loss, {k: float(v.detach()) for k, v in parts.items()}


DEPTH_LOSSES = ("inverse", "log")


def depth_error(pred: Tensor, gt: Tensor, kind: str) -> Tensor:
    """Mean L1 between predicted and Blender depths ``[K]`` (gt > 0): of inverse depth
    (``"inverse"``) or of log depth (``"log"``, scale-free: ``|log(pred / gt)|`` is the
    relative error to first order, what the AbsRel score measures). Predictions are clamped
    to 1e-3 so that a depth of 0 stays finite."""
    pred = pred.clamp_min(1e-3)
    if kind == "log":
        return (pred.log() - gt.log()).abs().mean()
    return (1 / pred - 1 / gt).abs().mean()


def depth_ce(logits: Tensor, depths: Tensor, near: Tensor, far: Tensor) -> Tensor:
    """Cross-entropy of the depth head's distribution against Blender's depth.

    ``logits [B,V,D,h,w]`` over D candidates uniform in inverse depth from ``near`` to
    ``far`` ([B] each; candidate 0 at near), ``depths [B,V,H,W]`` (0 = no surface) with H, W
    a multiple k of h, w. Each k x k cell's target is its mean inverse depth, split between
    the two candidates that bracket it (a two-hot whose expectation is that depth, so the
    term agrees with the L1 terms' optimum). Cells whose footprint is not one surface (sky,
    or depths more than 5 % apart: a silhouette, where no single candidate is right) are left
    out; 0 when no cell is left.
    """
    b, v, d, h, w = logits.shape
    k = depths.shape[-1] // w
    if depths.shape[-2:] != (h * k, w * k) or k < 1:
        raise ValueError(
            f"depth_ce: depths {list(depths.shape)} are not a whole multiple of the logits' "
            f"{h}x{w} cells"
        )
    g = depths.reshape(b * v, 1, h * k, w * k)  # [BV,1,H,W]
    one = one_surface(g, k)[:, 0]  # [BV,h,w]
    if not one.any():
        return logits.sum() * 0.0
    inv = F.avg_pool2d(1.0 / g.clamp_min(1e-6), k)[:, 0]  # [BV,h,w] mean 1/z
    inv_near = (1.0 / near).repeat_interleave(v)[:, None, None]  # [BV,1,1]
    inv_far = (1.0 / far).repeat_interleave(v)[:, None, None]
    t = ((inv - inv_far) / (inv_near - inv_far)).clamp(0, 1)  # 1 at near, 0 at far
    pos = (1 - t) * (d - 1)  # [BV,h,w] fractional candidate index
    below = pos.floor().clamp(max=d - 2)
    frac = (pos - below)[:, None]  # [BV,1,h,w] weight of the candidate above
    target = torch.zeros_like(logits.reshape(b * v, d, h, w))
    idx = below.long()[:, None]  # [BV,1,h,w]
    target.scatter_(1, idx, 1 - frac)
    target.scatter_(1, idx + 1, frac)
    logp = torch.log_softmax(logits.reshape(b * v, d, h, w), dim=1)  # [BV,D,h,w]
    ce = -(target * logp).sum(1)  # [BV,h,w]
    return ce[one].mean()


def _check_packs_have_depth(ds: SceneDataset, cfg: TrainConfig) -> None:
    """A pack made with ``scenes pack --no-depth`` would silently drop the depth terms: refuse
    it when they are asked for (folders without depth are the scene's own matter)."""
    names = ("depth_weight", "input_depth_weight", "input_depth_ce_weight")
    wanted = [n for n in names if getattr(cfg, n) > 0]
    if not wanted:
        return
    for pack in {s[0] for s in ds.folders if isinstance(s, tuple)}:
        if not pack.has_depth:
            raise ValueError(
                f"{pack.path} was packed without depth (`scenes pack --no-depth`), but "
                f"{', '.join('--' + n.replace('_', '-') for n in wanted)} need it: pack the "
                "scenes again without --no-depth"
            )


def lr_at(step: int, cfg) -> float:
    """Linear warm-up, then cosine decay to 10 % of the peak; ``cfg`` is any training config
    with ``lr``, ``warmup`` and ``steps`` (the generator's and the stage-2 ones)."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


def _to(batch: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    return {k: v.to(device) for k, v in batch.items()}


def _model_inputs(batch: dict[str, Tensor]) -> tuple[Tensor, ...]:
    return batch["input_images"], batch["input_K"], batch["input_w2c"], batch["near"], batch["far"]


@torch.no_grad()
def validate(model, cfg: TrainConfig, device: torch.device, ds=None) -> dict[str, float]:
    """PSNR / SSIM / LPIPS on the first ``val_scenes`` validation scenes (fixed subsets).

    With several input-view counts every count is scored on the same scenes: ``val_psnr`` etc.
    are means over all of them and ``val_psnr_<N>v`` the per-count means, so a curve stays
    comparable however the counts are drawn in training. ``ds`` reuses a loaded dataset.
    """
    from prosplat.data import SceneDataset
    from prosplat.data.dataset import ItemKey
    from prosplat.metrics import lpips, psnr, ssim

    counts = cfg.view_counts
    if ds is None:
        ds = SceneDataset(cfg.val, n_inputs=counts[0], n_targets=cfg.targets, seed=12345)
    result: dict[str, float] = {}
    totals: dict[str, list[float]] = {"psnr": [], "ssim": [], "lpips": []}
    was_training = model.training
    model.eval()
    for n in counts:
        scores: dict[str, list[float]] = {"psnr": [], "ssim": [], "lpips": []}
        for i in range(min(cfg.val_scenes, len(ds))):
            item = _to({k: v[None] for k, v in ds[ItemKey(i, 0, n)].items()}, device)
            item = _val_view(item, cfg)
            out = model(*_model_inputs(item))
            g = out.gaussians(0)
            h, w = item["target_images"].shape[-2:]
            cams = batch_cameras(item["target_K"][0], item["target_w2c"][0], w, h)
            rgbs = _render_views(g, cams, torch.zeros(3, device=device))[0].clamp(0, 1)
            for j, pred in enumerate(rgbs):
                gt = item["target_images"][0, j]
                scores["psnr"].append(float(psnr(pred, gt)))
                scores["ssim"].append(float(ssim(pred, gt)))
                lp = float(lpips(pred, gt)) if min(h, w) >= 32 else float("nan")
                scores["lpips"].append(lp)
        for k, v in scores.items():
            totals[k] += v
            if len(counts) > 1:
                result[f"val_{k}_{n}v"] = sum(v) / max(1, len(v))
    model.train(was_training)
    return {**{f"val_{k}": sum(v) / max(1, len(v)) for k, v in totals.items()}, **result}


class _StepBatches:
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


def _step_view(batch: dict[str, Tensor], cfg: TrainConfig, step: int) -> dict[str, Tensor]:
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


def _val_view(item: dict[str, Tensor], cfg: TrainConfig) -> dict[str, Tensor]:
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


def _weights_metadata(pipe, trained_size: int | None = None) -> dict[str, str]:
    """The metadata ``ProSplat.save`` writes, so a training checkpoint loads with
    ``ProSplat.from_pretrained`` like any other; ``trained_size`` (the largest image height
    trained at) makes the pipeline run the weights at that size (``ProSplat.trained_size``)."""
    from prosplat.pipeline.model import CHECKPOINT_FORMAT

    meta = {
        "format": CHECKPOINT_FORMAT,
        "config": pipe.config.to_json(),
        "parameters": json.dumps(pipe.generator.num_parameters()),
    }
    if trained_size:
        meta["trained_size"] = str(int(trained_size))
    return meta


def train(cfg: TrainConfig, model_config=None, progress: bool = True) -> Path:
    """Train (or resume) into ``cfg.out``; returns the path of the final checkpoint.

    Under torchrun every process calls this; see the module docstring for what they share.
    """
    dist = setup_distributed(cfg.device)
    try:
        return _train(cfg, model_config, progress, dist)
    finally:
        dist.close()


def _train(cfg: TrainConfig, model_config, progress: bool, dist: Dist) -> Path:
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from prosplat.data import SceneDataset
    from prosplat.generator.config import preset
    from prosplat.pipeline.model import ProSplat, is_depthsplat_file

    device = dist.device
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg_path, log_path = out / "train_config.json", out / "log.jsonl"
    random.seed(cfg.seed)
    torch.manual_seed(cfg.seed)  # the same initial weights on every rank (DDP also broadcasts)

    heads = is_depthsplat_file(cfg.init)  # fine-tune a DepthSplat checkpoint's heads
    if heads:
        if cfg.ema > 0:
            raise ValueError("--ema averages prosplat generator weights, not DepthSplat heads")
        if cfg.input_depth_weight > 0 or cfg.input_depth_ce_weight > 0:
            raise ValueError(
                "--input-depth-weight / --input-depth-ce-weight supervise the depth predictor, "
                "which stays frozen when fine-tuning a DepthSplat checkpoint; drop them "
                "(--depth-weight still works)"
            )
        from prosplat.train.depthsplat_heads import load_for_tuning

        model = load_for_tuning(cfg.init).to(device).train()
        params = model.trainable_parameters()
        pipe = None
    else:
        init_state = None
        if cfg.grow_fine_matching or cfg.grow_alexnet or cfg.grow_image_matching or cfg.grow_band:
            model_config, init_state = _grown_init(cfg)
        elif cfg.init and model_config is None:
            model_config, init_state = _init_weights(cfg)
        pipe = ProSplat(model_config or preset(cfg.config))
        model = pipe.generator.to(device).train()
        params = list(model.parameters())
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    ckpt = load_checkpoint(out, map_location=device)  # every rank reads before rank 0 writes
    if ckpt is None:
        claim_run_folder(out, asdict(cfg), per_call=_PER_CALL, is_main=dist.is_main)
    step = 0
    if ckpt is None and cfg.init and not heads:
        from prosplat.core.checkpoints import read_checkpoint

        if init_state is None:
            init_state = read_checkpoint(Path(cfg.init), "generator")[0]
        model.load_state_dict(init_state)
    if ckpt is not None:
        if heads:
            model.load_trainable(ckpt.weights, str(ckpt.weights_path))
        else:
            model.load_state_dict(ckpt.weights)
        if "raw_weights" in ckpt.state:  # a run with --ema saved its average as the weights
            model.load_state_dict(ckpt.state["raw_weights"])
        opt.load_state_dict(ckpt.state["optimizer"])
        step = ckpt.step
        torch.set_rng_state(ckpt.state["rng"].cpu())
        if ckpt.weights_path.name != "checkpoint.safetensors" and dist.is_main:
            warnings.warn(
                f"{out}: the newest weights have no matching state (interrupted save); "
                f"resuming from {ckpt.weights_path.name} at step {step}",
                stacklevel=2,
            )
    average = None
    if cfg.ema > 0:
        average = WeightAverage(model, cfg.ema)  # a run that turns --ema on starts it here
        if ckpt is not None and "raw_weights" in ckpt.state:
            average.load_state_dict(ckpt.weights, ckpt.state["ema_updates"])
    dist.barrier()
    if dist.is_main:
        if ckpt is None:
            cfg_path.write_text(json.dumps(asdict(cfg), indent=1))
        else:
            truncate_log(log_path, step)
            _record_resumed_config(cfg_path, cfg, step)
    ddp_model = dist.wrap(model)

    lpips_fn = None
    if cfg.lpips_weight > 0:
        from prosplat.metrics import LPIPS

        lpips_fn = LPIPS().to(device)

    counts = cfg.view_counts
    ds = SceneDataset(
        cfg.data.split(","),
        n_inputs=counts[0],
        n_targets=cfg.targets,
        seed=cfg.seed,
        any_view=cfg.any_view,
        cache_size=cfg.cache_scenes,
    )
    steps_per_epoch(len(ds), cfg.batch, dist.world_size)  # a clear error if a step cannot fill
    _check_packs_have_depth(ds, cfg)
    val_ds = None
    if cfg.val and dist.is_main:
        val_ds = SceneDataset(cfg.val, n_inputs=counts[0], n_targets=cfg.targets, seed=12345)
    loader = DataLoader(ds, batch_sampler=_StepBatches(len(ds), cfg, step, dist))
    log = open(log_path, "a") if dist.is_main else None
    bar = tqdm(
        total=cfg.last_step,
        initial=step,
        desc="train generator",
        disable=not progress or not dist.is_main,
    )
    t_start = time.perf_counter()
    saved, saving, interrupted = step, False, False  # saved: the step the checkpoint is at

    def save() -> None:
        nonlocal saved, saving
        saving = True
        if heads:
            _save_heads(model, opt, step, out, cfg.init)
        else:
            _save(pipe, opt, step, out, average)
        saved, saving = step, False

    try:
        for batch in loader:
            n_views = int(batch["input_images"].shape[1])
            batch = _to(batch, device)
            if cfg.size_choices:  # a size per step, seeded apart from the view count's draw
                batch = _step_view(batch, cfg, step)
            if pipe is not None:  # the size the weights are for: the largest drawn, else the data's
                pipe.trained_size = max(cfg.size_choices or (int(batch["input_images"].shape[-2]),))
            for group in opt.param_groups:
                group["lr"] = lr_at(step, cfg)
            output = ddp_model(*_model_inputs(batch))
            loss, parts = render_loss(output, batch, cfg, lpips_fn)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = float(torch.nn.utils.clip_grad_norm_(params, cfg.grad_clip))
            if not math.isfinite(float(loss.detach())):
                raise FloatingPointError(
                    f"loss became {float(loss.detach())} at step {step}; lower --lr"
                )
            opt.step()
            if average is not None:
                average.update(model)
            step += 1
            bar.update(1)
            bar.set_postfix(loss=f"{float(loss.detach()):.4f}", views=n_views)
            if step % cfg.log_every == 0:
                means = dist.mean_all({"loss": float(loss.detach()), **parts})  # all ranks
                if log is not None:
                    rec = {
                        "step": step,
                        **means,
                        "inputs": n_views,
                        "grad_norm": grad_norm,
                        "lr": lr_at(step - 1, cfg),
                        "seconds": round(time.perf_counter() - t_start, 1),
                    }
                    if val_ds is not None and step % cfg.val_every == 0:
                        rec.update(validate(model, cfg, device, val_ds))
                    log.write(json.dumps(rec) + "\n")
                    log.flush()
            if dist.is_main and (step % cfg.save_every == 0 or step == cfg.last_step):
                save()
    except KeyboardInterrupt:  # Ctrl-C, or `timeout --signal=INT` on a time-boxed machine
        if saving:  # stopped mid-save: the checkpoint pair's own recovery resumes (load_checkpoint)
            raise
        interrupted = True
        if dist.is_main and step > saved:  # the same command resumes from here
            save()
    finally:
        bar.close()
        if log is not None:
            log.close()
    if interrupted and dist.is_main:
        where = "no checkpoint yet"
        if saved:
            where = f"its checkpoint is at step {saved}: the same command resumes from there"
        print(
            f"train generator: interrupted at step {step} of {cfg.last_step}; {where}",
            file=sys.stderr,
        )
    dist.barrier()  # the final checkpoint exists before any rank returns its path
    if heads:
        from prosplat.train.depthsplat_heads import finetuned_path

        return finetuned_path(out, cfg.init)
    return out / "checkpoint.safetensors"


def _save(pipe, opt, step: int, out: Path, average: WeightAverage | None = None) -> None:
    """Checkpoint: weights (safetensors with the config and step) and optimiser state, written
    so that a crash at any point leaves a consistent pair (see ``save_checkpoint``). With a
    weight average the safetensors holds the average (what is evaluated and shipped) and the
    state the raw weights and the average's update count (what a resume continues from)."""
    state = {"optimizer": opt.state_dict(), "rng": torch.get_rng_state()}
    weights = pipe.generator.state_dict()
    metadata = _weights_metadata(pipe, pipe.trained_size)
    if average is not None:
        state.update(raw_weights=weights, ema_updates=average.updates)
        weights = average.state_dict(like=pipe.generator)
        metadata["ema"] = json.dumps({"decay": average.decay, "updates": average.updates})
    save_checkpoint(out, step, weights, state, metadata=metadata)


#: Settings of one invocation, not of how the steps were trained (where this call stops).
_PER_CALL = ("stop_at",)


def _record_resumed_config(cfg_path: Path, cfg: TrainConfig, step: int) -> None:
    """A run resumed with other settings (``--ema`` turned on, a longer ``--steps``) writes
    them to ``train_config.json`` and keeps what it ran with before as
    ``train_config.before_<step>.json``, so the folder says how every step was trained."""
    if not cfg_path.exists():
        return
    old = cfg_path.read_text()
    if not changed_settings(json.loads(old), asdict(cfg), _PER_CALL):
        return
    kept = cfg_path.with_name(f"train_config.before_{step}.json")
    if not kept.exists():
        kept.write_text(old)
    cfg_path.write_text(json.dumps(asdict(cfg), indent=1))


def _init_weights(cfg: TrainConfig):
    """(config, weights) of the prosplat weights ``cfg.init``: the architecture comes from the
    file's metadata, not from ``--config``, so fine-tuning a grown model (v3 has a fine cost
    volume that ``tiny`` lacks) builds the network the weights were saved from. The config is
    None for a file without one (then ``--config`` must match it)."""
    from prosplat.core.checkpoints import read_checkpoint
    from prosplat.generator.config import GeneratorConfig

    state, meta = read_checkpoint(Path(cfg.init), "generator")
    config = GeneratorConfig.from_json(meta["config"]) if "config" in meta else None
    return config, state


def _grown_init(cfg: TrainConfig):
    """(config, weights) of ``cfg.init`` grown by ``cfg.grow_fine_matching`` fine-matching
    channels, then by ``cfg.grow_alexnet`` AlexNet layers, then by the image cost volume of
    ``cfg.grow_image_matching``, then by the band of ``cfg.grow_band``; on a resume only the
    config is used (the checkpoint holds the weights)."""
    from prosplat.core.checkpoints import read_checkpoint
    from prosplat.generator.config import GeneratorConfig
    from prosplat.generator.grow import (
        grow_alexnet,
        grow_band,
        grow_fine_matching,
        grow_image_matching,
    )

    state, meta = read_checkpoint(Path(cfg.init), "generator")
    if "config" not in meta:
        raise ValueError(f"{cfg.init} has no generator config in its metadata to grow")
    config = GeneratorConfig.from_json(meta["config"])
    if cfg.grow_fine_matching:
        config, state = grow_fine_matching(config, state, cfg.grow_fine_matching)
    if cfg.grow_alexnet:
        config, state = grow_alexnet(config, state, cfg.grow_alexnet)
    if cfg.grow_image_matching:
        config, state = grow_image_matching(config, state, cfg.grow_image_matching)
    if cfg.grow_band:
        config, state = grow_band(config, state, cfg.grow_band)
    return config, state


def _save_heads(model, opt, step: int, out: Path, init: str) -> None:
    """A DepthSplat fine-tune: the trainable tensors and optimiser as a resumable pair (as
    :func:`_save`), then the whole encoder as a released-layout ``.pth`` that
    ``ProSplat.from_pretrained(generator=...)`` loads (:mod:`prosplat.train.depthsplat_heads`)."""
    from prosplat.train.depthsplat_heads import FORMAT, finetuned_path

    save_checkpoint(
        out,
        step,
        model.trainable_state(),
        {"optimizer": opt.state_dict(), "rng": torch.get_rng_state()},
        metadata={"format": FORMAT, "init": str(init)},
    )
    model.save_full(finetuned_path(out, init), init, step)
