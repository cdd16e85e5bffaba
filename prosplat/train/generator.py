"""Training the stage-1 generator on Blender-rendered scenes: the loop (DDP, weight average,
resume, Ctrl-C). Its pieces live beside it: the settings in :mod:`prosplat.train.generator_config`,
the batch reshaping in :mod:`prosplat.train.batches`, the loss in :mod:`prosplat.train.losses`.

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

Camera effects: ``--camera-effects P`` gives that share of the input views (after the step's
resize or crop) exposure, white balance, vignetting, blur, sensor noise and JPEG, drawn by
(seed, step), the targets left clean (:mod:`prosplat.train.camera_effects`), so the generator
learns to see through what photographs add to the noise-free renders. ``--roll-prob P`` turns
that share of the views (inputs and targets) by a quarter turn with their cameras
(:mod:`prosplat.train.view_rotation`): rolled photos, from upright renders.

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

import json
import math
import random
import sys
import time
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from prosplat.core.paths import write_text_atomic
from prosplat.train.batches import (
    StepBatches,
    batch_cameras,
    model_inputs,
    step_view,
    to_device,
    val_view,
)
from prosplat.train.camera_effects import input_camera_effects
from prosplat.train.common import (
    Dist,
    changed_settings,
    claim_run_folder,
    load_checkpoint,
    lr_at,
    save_checkpoint,
    seeded_generator,
    setup_distributed,
    steps_per_epoch,
    truncate_log,
)
from prosplat.train.ema import WeightAverage
from prosplat.train.generator_config import TrainConfig
from prosplat.train.losses import render_loss, render_views
from prosplat.train.view_rotation import roll_views

if TYPE_CHECKING:
    from prosplat.data import SceneDataset

__all__ = ["TrainConfig", "train", "validate"]


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
            item = to_device({k: v[None] for k, v in ds[ItemKey(i, 0, n)].items()}, device)
            item = val_view(item, cfg)
            out = model(*model_inputs(item))
            g = out.gaussians(0)
            h, w = item["target_images"].shape[-2:]
            cams = batch_cameras(item["target_K"][0], item["target_w2c"][0], w, h)
            rgbs = render_views(g, cams, torch.zeros(3, device=device))[0].clamp(0, 1)
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
            write_text_atomic(cfg_path, json.dumps(asdict(cfg), indent=1))
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
    loader = DataLoader(ds, batch_sampler=StepBatches(len(ds), cfg, step, dist))
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
            batch = to_device(batch, device)
            if cfg.size_choices:  # a size per step, seeded apart from the view count's draw
                batch = step_view(batch, cfg, step)
            # each process turns its own part of the batch: its own stream by (seed, step, rank)
            turns = seeded_generator(f"prosplat-roll/{cfg.seed}/{step}/{dist.rank}")
            batch = roll_views(batch, cfg.roll_prob, turns)
            # the inputs only, at the step's pixel scale; the targets stay the clean truth
            batch = input_camera_effects(batch, cfg, step, dist.rank, dist.world_size)
            if pipe is not None:  # the size the weights are for: the largest drawn, else the data's
                pipe.trained_size = max(cfg.size_choices or (int(batch["input_images"].shape[-2]),))
            for group in opt.param_groups:
                group["lr"] = lr_at(step, cfg)
            output = ddp_model(*model_inputs(batch))
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
    write_text_atomic(cfg_path, json.dumps(asdict(cfg), indent=1))


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
