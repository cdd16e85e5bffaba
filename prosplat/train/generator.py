"""Training the stage-1 generator on Blender-rendered scenes.

One script for the CPU, one GPU, or several (``torchrun --nproc_per_node K -m prosplat
train generator ...``: torch.distributed with DDP; each process takes its own shard of the
scenes). The loss renders the target views from the predicted Gaussians with the
differentiable rasterizer: MSE + λ·LPIPS (+ optional SSIM and depth terms against Blender's
depth). Checkpoints are resumable; every step is logged to ``log.jsonl``; seeds are fixed.
"""

from __future__ import annotations

import json
import math
import os
import random
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import Tensor

from prosplat.camera import Camera
from prosplat.render import render


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on; saved beside its checkpoints as ``train_config.json``."""

    data: str
    out: str
    config: str = "tiny"  # generator preset: "tiny" | "base"
    val: str | None = None
    steps: int = 20_000
    batch: int = 1
    inputs: int = 2
    targets: int = 2
    lr: float = 2e-4
    weight_decay: float = 0.01
    lpips_weight: float = 0.05
    ssim_weight: float = 0.0
    depth_weight: float = 0.0  # L1 on inverse depth of rendered vs Blender depth
    grad_clip: float = 0.5
    warmup: int = 500
    log_every: int = 10
    val_every: int = 1000
    val_scenes: int = 8
    save_every: int = 500
    seed: int = 0
    device: str = "auto"


def pick_device(name: str) -> torch.device:
    if name != "auto":
        return torch.device(name)
    if torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    return torch.device("cpu")


def batch_cameras(K: Tensor, w2c: Tensor, width: int, height: int) -> list[Camera]:
    """[V,3,3], [V,4,4] -> cameras (float64 so poses stay orthonormal to 1e-4)."""
    return [Camera(K[v].double(), w2c[v].double(), width, height) for v in range(K.shape[0])]


def render_loss(
    output, batch: dict[str, Tensor], cfg: TrainConfig, lpips_fn=None
) -> tuple[Tensor, dict[str, float]]:
    """Render every target view of every scene in the batch and compare with ground truth.

    Returns the loss and its parts (floats, for the log).
    """
    from prosplat.metrics import ssim

    targets = batch["target_images"]  # [B,M,3,H,W]
    b_size, m, _, h, w = targets.shape
    bg = torch.zeros(3, device=targets.device)
    mse_sum = lp_sum = ss_sum = dp_sum = targets.new_zeros(())
    for b in range(b_size):
        gaussians = output.gaussians(b)
        cams = batch_cameras(batch["target_K"][b], batch["target_w2c"][b], w, h)
        for j, cam in enumerate(cams):
            out = render(gaussians, cam, background=bg)
            gt = targets[b, j]
            mse_sum = mse_sum + torch.mean((out.rgb - gt) ** 2)
            if lpips_fn is not None and cfg.lpips_weight > 0:
                lp_sum = lp_sum + lpips_fn(out.rgb[None], gt[None]).mean()
            if cfg.ssim_weight > 0:
                ss_sum = ss_sum + (1 - ssim(out.rgb, gt))
            if cfg.depth_weight > 0 and "target_depths" in batch:
                gt_d = batch["target_depths"][b, j]
                valid = (gt_d > 0) & (out.alpha > 0.5)
                if valid.any():
                    inv = 1 / out.depth[valid].clamp_min(1e-3)
                    dp_sum = dp_sum + (inv - 1 / gt_d[valid]).abs().mean()
    n = b_size * m
    parts = {"mse": mse_sum / n, "lpips": lp_sum / n, "ssim": ss_sum / n, "depth": dp_sum / n}
    loss = (
        parts["mse"]
        + cfg.lpips_weight * parts["lpips"]
        + cfg.ssim_weight * parts["ssim"]
        + cfg.depth_weight * parts["depth"]
    )
    return loss, {k: float(v.detach()) for k, v in parts.items()}


def lr_at(step: int, cfg: TrainConfig) -> float:
    """Linear warm-up, then cosine decay to 10 % of the peak."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


def _to(batch: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    return {k: v.to(device) for k, v in batch.items()}


def _model_inputs(batch: dict[str, Tensor]) -> tuple[Tensor, ...]:
    return batch["input_images"], batch["input_K"], batch["input_w2c"], batch["near"], batch["far"]


@torch.no_grad()
def validate(model, cfg: TrainConfig, device: torch.device) -> dict[str, float]:
    """PSNR / SSIM / LPIPS on the first ``val_scenes`` validation scenes (fixed subsets)."""
    from prosplat.data import SceneDataset
    from prosplat.metrics import lpips, psnr, ssim

    ds = SceneDataset(cfg.val, n_inputs=cfg.inputs, n_targets=cfg.targets, seed=12345)
    scores: dict[str, list[float]] = {"psnr": [], "ssim": [], "lpips": []}
    was_training = model.training
    model.eval()
    for i in range(min(cfg.val_scenes, len(ds))):
        item = _to({k: v[None] for k, v in ds[i].items()}, device)
        out = model(*_model_inputs(item))
        g = out.gaussians(0)
        h, w = item["target_images"].shape[-2:]
        for j, cam in enumerate(batch_cameras(item["target_K"][0], item["target_w2c"][0], w, h)):
            pred = render(g, cam).rgb.clamp(0, 1)
            gt = item["target_images"][0, j]
            scores["psnr"].append(float(psnr(pred, gt)))
            scores["ssim"].append(float(ssim(pred, gt)))
            scores["lpips"].append(float(lpips(pred, gt)) if min(h, w) >= 32 else float("nan"))
    model.train(was_training)
    return {f"val_{k}": sum(v) / max(1, len(v)) for k, v in scores.items()}


def train(cfg: TrainConfig, model_config=None, progress: bool = True) -> Path:
    """Train (or resume) into ``cfg.out``; returns the path of the final checkpoint."""
    from safetensors.torch import load_file
    from torch.utils.data import DataLoader, DistributedSampler, RandomSampler
    from tqdm import tqdm

    from prosplat.data import SceneDataset
    from prosplat.generator.config import preset
    from prosplat.pipeline import ProSplat

    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if distributed:
        torch.distributed.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    rank = torch.distributed.get_rank() if distributed else 0
    device = pick_device(cfg.device)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    state_path, ckpt_path = out / "state.pt", out / "checkpoint.safetensors"
    cfg_path = out / "train_config.json"
    if cfg_path.exists() and not state_path.exists() and rank == 0:
        raise FileExistsError(
            f"{out} holds another run's config but no checkpoint; pick a new --out"
        )
    random.seed(cfg.seed)
    torch.manual_seed(cfg.seed + rank)

    pipe = ProSplat(model_config or preset(cfg.config))
    model = pipe.generator.to(device).train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    step = 0
    if state_path.exists():  # resume
        state = torch.load(state_path, map_location=device, weights_only=True)
        model.load_state_dict(load_file(str(ckpt_path), device=str(device)))
        opt.load_state_dict(state["optimizer"])
        step = int(state["step"])
        torch.set_rng_state(state["rng"])
    elif rank == 0:
        cfg_path.write_text(json.dumps(asdict(cfg), indent=1))
    ddp_model = (
        torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None
        )
        if distributed
        else model
    )

    lpips_fn = None
    if cfg.lpips_weight > 0:
        from prosplat.metrics import LPIPS

        lpips_fn = LPIPS().to(device)

    ds = SceneDataset(cfg.data, n_inputs=cfg.inputs, n_targets=cfg.targets, seed=cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    epoch = step // max(1, len(ds) // cfg.batch)
    log = open(out / "log.jsonl", "a") if rank == 0 else None
    bar = tqdm(
        total=cfg.steps, initial=step, desc="train generator", disable=not progress or rank != 0
    )
    t_start = time.perf_counter()
    while step < cfg.steps:
        ds.set_epoch(epoch)
        sampler = (
            DistributedSampler(ds, seed=cfg.seed)
            if distributed
            else RandomSampler(ds, generator=gen)
        )
        if distributed:
            sampler.set_epoch(epoch)
        for batch in DataLoader(ds, batch_size=cfg.batch, sampler=sampler, drop_last=True):
            if step >= cfg.steps:
                break
            batch = _to(batch, device)
            for group in opt.param_groups:
                group["lr"] = lr_at(step, cfg)
            output = ddp_model(*_model_inputs(batch))
            loss, parts = render_loss(output, batch, cfg, lpips_fn)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = float(torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip))
            if not math.isfinite(float(loss.detach())):
                raise FloatingPointError(
                    f"loss became {float(loss.detach())} at step {step}; lower --lr"
                )
            opt.step()
            step += 1
            bar.update(1)
            bar.set_postfix(loss=f"{float(loss.detach()):.4f}")
            if log is not None and step % cfg.log_every == 0:
                rec = {
                    "step": step,
                    "loss": float(loss.detach()),
                    **parts,
                    "grad_norm": grad_norm,
                    "lr": lr_at(step - 1, cfg),
                    "seconds": round(time.perf_counter() - t_start, 1),
                }
                if cfg.val and step % cfg.val_every == 0:
                    rec.update(validate(model, cfg, device))
                log.write(json.dumps(rec) + "\n")
                log.flush()
            if rank == 0 and (step % cfg.save_every == 0 or step == cfg.steps):
                _save(pipe, opt, step, out)
        epoch += 1
    bar.close()
    if log is not None:
        log.close()
    if distributed:
        torch.distributed.destroy_process_group()
    return ckpt_path


def _save(pipe, opt, step: int, out: Path) -> None:
    """Checkpoint atomically: weights (safetensors, with the config) and optimiser state."""
    tmp_state = out / ".state.pt.tmp"
    pipe.save(out / "checkpoint.safetensors", overwrite=True)
    torch.save(
        {"optimizer": opt.state_dict(), "step": step, "rng": torch.get_rng_state()}, tmp_state
    )
    os.replace(tmp_state, out / "state.pt")
