"""Training stage 2, divide and conquer: the improvement model alone on curated renders
(``prosplat train improve``), then jointly with the generator (``prosplat train joint``).

Independent training: MSE + 5·LPIPS between the enhanced curated render and the ground truth.
Joint training (the paper's Sec. III-D): the generator is frozen except its Gaussian adapter,
the improvement model frozen except its VAE encoder (and, with ``train_decoder``, its decoder,
as the paper's implementation section says); the loss is summed over the target views of one
forward pass of the generator, rendered differentiably and enhanced.

Both loops run on the CPU, one GPU, or several under torchrun (see
:mod:`prosplat.train.common`), resume from ``out`` and log every step to ``log.jsonl``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import Tensor

from prosplat.core.paths import write_text_atomic
from prosplat.improve.config import preset
from prosplat.improve.io import load_improver, save_improver
from prosplat.improve.model import ImproveModel
from prosplat.train.augment import (
    MAX_SHIFT,
    SHIFT_MARGIN,
    augment_samples,
    shift_disagreement,
    shifted_pairs,
    subpixel_translate,
)
from prosplat.train.common import (
    Dist,
    check_intervals,
    claim_run_folder,
    load_checkpoint,
    lr_at,
    save_checkpoint,
    setup_distributed,
    step_indices,
    truncate_log,
)
from prosplat.train.curate import curated_alpha, curated_batch, curated_warp, load_curated


@dataclass(frozen=True)
class ImproveTrainConfig:
    """An independent stage-2 run; saved beside its checkpoints as ``train_config.json``."""

    # curated file (prosplat train curate), or several joined by commas (e.g. one per size):
    # each step takes its batch from one of them in turn
    data: str
    out: str  # run folder (checkpoints, log.jsonl); the same folder again resumes
    config: str = "tiny"  # architecture preset of a new model (prosplat.improve.config)
    init: str | None = None  # start from this improvement checkpoint instead of random
    # a local diffusers-format SD-Turbo folder: build on its VAE/U-Net with LoRA adapters
    # (only LoRA and the new modules train); the saved improve.safetensors has them merged
    pretrained: str | None = None
    val: str | None = None  # curated validation file
    steps: int = 3000  # steps of the run (the learning-rate schedule ends here)
    batch: int = 8  # curated samples per step per process
    lr: float = 5e-4  # peak learning rate (linear warm-up, then cosine decay to 10 %)
    lpips_weight: float = 5.0  # weight of LPIPS beside the MSE to the ground truth
    timestep: int = 199  # the one diffusion timestep the U-Net denoises at
    # x0 from the U-Net's noise prediction (one-step diffusion); off: the U-Net's output is
    # the new latent (the paper's "VAE + U-Net" ablation row)
    denoise: bool = True
    reference: bool = True  # the MORI reference through DWEA (off: the ablation row)
    # DWEA's epipolar weighting (off: plain attention, the ablation row; ImproveConfig.epipolar)
    epipolar: bool = True
    reference_method: str = "paper"  # "paper" | "overlap"
    grad_clip: float = 1.0  # gradient norm clip
    warmup: int = 100  # steps of linear learning-rate warm-up
    log_every: int = 10  # steps between log.jsonl records
    val_every: int = 500  # steps between validations (with val)
    save_every: int = 500  # steps between checkpoints
    seed: int = 0  # seeds the weights, the data order and the augmentations
    device: str = "auto"  # auto | cpu | cuda | cuda:N | mps
    crop: int = 0  # random square crops of this size (0: whole views; prosplat.train.augment)
    flip: bool = False  # random horizontal flips (the fundamental matrices follow)
    alpha: bool = False  # give the model the render's alpha (needs a set curated with alpha)
    # give the model the reference warped through the rendered depth + its validity (needs
    # sets curated with the warp; prosplat.improve.warp)
    warp: bool = False
    # fill the render's holes from its own colours before the model sees it
    # (ImproveConfig.fill_input; needs --alpha). A model trained with it keeps it
    fill: bool = False
    padding: str = ""  # set the convolutions' padding ("zeros" | "replicate"; "": the model's)
    # weight of the shift term: half of each batch is the other half's crops moved 1-7 px, and
    # the two outputs must agree where they overlap (augment.shifted_pairs; needs --crop).
    # Against a pattern tied to the VAE's 8-px cells (0: off)
    shift_weight: float = 0.0
    # the shift term's twins also moved by a random fraction of a pixel (their render, alpha
    # and warp resampled; augment.subpixel_translate), the first outputs compared after the
    # same resampling: against detail that jumps when the render is resampled, i.e. flicker
    # along a camera path (needs --shift-weight)
    subpixel_shift: bool = False
    # the largest view the saved model runs on directly (ImproveConfig.working_size); -1: the
    # largest training view, 0: every view at its own size. Larger than the training views
    # only where the ladder measured it better (BENCHMARKS "Stage 2 v10 at 256 px")
    working_size: int = -1

    def __post_init__(self) -> None:
        check_intervals(self, "log_every", "val_every", "save_every")
        if self.subpixel_shift and not self.shift_weight:
            raise ValueError("--subpixel-shift needs --shift-weight (it changes the shift term)")
        if self.working_size < -1:
            raise ValueError(f"--working-size must be -1, 0 or a size, got {self.working_size}")


@dataclass(frozen=True)
class JointTrainConfig:
    """A joint run: generator adapter + improvement VAE encoder (and decoder)."""

    data: str  # scene folders
    out: str  # run folder (checkpoints, log.jsonl); the same folder again resumes
    generator: str  # generator checkpoint
    improver: str  # improvement checkpoint (independently trained)
    steps: int = 500  # steps of the run (the learning-rate schedule ends here)
    inputs: int = 2  # input views per scene
    targets: int = 4  # target views per scene, the loss summed over them
    lr: float = 5e-5  # peak learning rate (linear warm-up, then cosine decay to 10 %)
    lpips_weight: float = 5.0  # weight of LPIPS beside the MSE to the ground truth
    train_decoder: bool = True  # train the VAE decoder too (the paper's implementation)
    reference_method: str = "paper"  # "paper" | "overlap"
    grad_clip: float = 1.0  # gradient norm clip
    warmup: int = 20  # steps of linear learning-rate warm-up
    log_every: int = 10  # steps between log.jsonl records
    save_every: int = 100  # steps between checkpoints
    seed: int = 0  # seeds the data order
    device: str = "auto"  # auto | cpu | cuda | cuda:N | mps

    def __post_init__(self) -> None:
        check_intervals(self, "log_every", "save_every")


def enhance_loss(pred: Tensor, target: Tensor, lpips_fn, weight: float) -> tuple[Tensor, dict]:
    """Mean MSE + ``weight`` · mean LPIPS over the batch [B,3,H,W]."""
    mse = (pred - target).square().mean()
    lp = lpips_fn(pred, target).mean() if weight > 0 else mse.new_zeros(())
    return mse + weight * lp, {"mse": float(mse.detach()), "lpips": float(lp.detach())}


class _Run:
    """The bookkeeping both loops share: resume, log, progress bar, checkpoints."""

    def __init__(self, cfg, dist: Dist, params, weights_fn, progress: bool, desc: str):
        from tqdm import tqdm

        self.cfg, self.dist, self.weights_fn = cfg, dist, weights_fn
        self.out = Path(cfg.out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=0.0)
        self.step = 0
        ckpt = load_checkpoint(self.out, map_location=dist.device)
        cfg_path = self.out / "train_config.json"
        if ckpt is None:
            claim_run_folder(self.out, asdict(cfg), is_main=dist.is_main)
        self.resumed = ckpt
        if ckpt is not None:
            self.opt.load_state_dict(ckpt.state["optimizer"])
            self.step = ckpt.step
            if dist.is_main:
                truncate_log(self.out / "log.jsonl", self.step)
        elif dist.is_main:
            write_text_atomic(cfg_path, json.dumps(asdict(cfg), indent=1))
        self.log = open(self.out / "log.jsonl", "a") if dist.is_main else None
        self.bar = tqdm(
            total=cfg.steps, initial=self.step, desc=desc, disable=not progress or not dist.is_main
        )
        self.t0 = time.perf_counter()

    def advance(self, loss: Tensor, params, parts: dict, extra: dict | None = None) -> None:
        for group in self.opt.param_groups:
            group["lr"] = lr_at(self.step, self.cfg)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        if not math.isfinite(float(loss.detach())):
            raise FloatingPointError(
                f"loss became {float(loss.detach())} at step {self.step}; lower --lr"
            )
        grad = float(torch.nn.utils.clip_grad_norm_(params, self.cfg.grad_clip))
        self.opt.step()
        self.step += 1
        self.bar.update(1)
        self.bar.set_postfix(loss=f"{float(loss.detach()):.4f}")
        if self.step % self.cfg.log_every == 0:
            means = self.dist.mean_all({"loss": float(loss.detach()), **parts})
            if self.log is not None:
                rec = {"step": self.step, **means, "grad_norm": grad, **(extra or {})}
                rec["seconds"] = round(time.perf_counter() - self.t0, 1)
                self.log.write(json.dumps(rec) + "\n")
                self.log.flush()
        if self.step % self.cfg.save_every == 0 or self.step == self.cfg.steps:
            self.save()

    def save(self) -> None:
        """Checkpoint the weights and optimiser at the current step (the main process)."""
        if self.dist.is_main:
            save_checkpoint(
                self.out, self.step, self.weights_fn(), {"optimizer": self.opt.state_dict()}
            )

    def close(self) -> None:
        self.bar.close()
        if self.log is not None:
            self.log.close()
        self.dist.barrier()


def load_curated_sets(spec: str) -> list:
    """The curated sets of ``--data``: one path, or several joined by commas."""
    paths = [p.strip() for p in str(spec).split(",") if p.strip()]
    if not paths:
        raise ValueError("--data needs a curated file (prosplat train curate)")
    return [load_curated(p) for p in paths]


@torch.no_grad()
def validate_improver(model: ImproveModel, data, method: str, device, limit: int = 64) -> dict:
    """Mean PSNR of raw renders and of enhanced ones on the first ``limit`` curated samples."""
    from prosplat.metrics import psnr

    was = model.training
    model.eval()
    idx = torch.arange(min(limit, data["render"].shape[0]))
    raw, ref, fund, gt = curated_batch(data, idx, method, device)
    alpha = curated_alpha(data, idx, device)
    warp = curated_warp(data, idx, method, device) if model.config.warp_input else None
    enh = torch.cat(
        [
            model(
                raw[i : i + 8],
                ref[i : i + 8],
                fund[i : i + 8],
                None if alpha is None else alpha[i : i + 8],
                None if warp is None else warp[i : i + 8],
            )  # fmt: skip
            for i in range(0, len(idx), 8)
        ]
    )
    model.train(was)
    return {
        "val_psnr_raw": float(torch.stack([psnr(raw[i], gt[i]) for i in range(len(idx))]).mean()),
        "val_psnr": float(torch.stack([psnr(enh[i], gt[i]) for i in range(len(idx))]).mean()),
    }


def train_improve(cfg: ImproveTrainConfig, progress: bool = True, model_config=None) -> Path:
    """Train (or resume) an improvement model into ``cfg.out``; returns ``improve.safetensors``."""
    dist = setup_distributed(cfg.device)
    try:
        return _train_improve(cfg, progress, model_config, dist)
    finally:
        dist.close()


def _train_improve(cfg: ImproveTrainConfig, progress: bool, model_config, dist: Dist) -> Path:
    from prosplat.metrics import LPIPS

    device = dist.device
    torch.manual_seed(cfg.seed)
    if cfg.pretrained:
        from prosplat.improve.pretrained import from_diffusers

        if cfg.init or not cfg.denoise:
            raise ValueError(
                "--pretrained builds the model on SD-Turbo: it does not combine with --init "
                "or --no-denoise"
            )
        model = from_diffusers(cfg.pretrained, timestep=cfg.timestep, reference=cfg.reference)
    elif cfg.init:
        # --no-reference from a reference model: the ablation row starts from the same
        # weights, DWEA left out
        model = load_improver(
            cfg.init, alpha_input=cfg.alpha, warp_input=cfg.warp,
            drop_reference=not cfg.reference, fill_input=cfg.fill,
        )  # fmt: skip
        asked = {"timestep": cfg.timestep, "denoise": cfg.denoise, "reference": cfg.reference}
        have = {k: getattr(model.config, k) for k in asked}
        if have != asked:
            raise ValueError(
                f"--init {cfg.init} was trained with {have} but this run asks for {asked}; "
                "pass the same --timestep/--denoise/--reference or start without --init"
            )
        # a switch of behaviour read on every forward: the same weights serve either way
        model.config = model.config.with_(epipolar=cfg.epipolar)
    else:
        base = model_config or preset(cfg.config)
        model = ImproveModel(
            base.with_(
                timestep=cfg.timestep,
                denoise=cfg.denoise,
                reference=cfg.reference,
                epipolar=cfg.epipolar,
                alpha_input=cfg.alpha,
                warp_input=cfg.warp,
                fill_input=cfg.fill,
            )
        )
    model.to(device).train()
    sets = load_curated_sets(cfg.data)
    if cfg.alpha and any("alpha" not in data for data in sets):
        raise ValueError(
            f"--alpha needs curated sets with the renders' alpha; one of {cfg.data} has none "
            "(curate it again with this version of `prosplat train curate`)"
        )
    if model.config.fill_input and not cfg.alpha:
        raise ValueError("--fill fills the renders' holes, which needs their alpha: pass --alpha")
    if model.config.warp_input and not cfg.warp:
        raise ValueError(
            f"--init {cfg.init} was trained with the warped reference (warp_input); pass --warp"
        )
    warp_key = f"warp_{cfg.reference_method}"
    if cfg.warp and any(warp_key not in data for data in sets):
        raise ValueError(
            f"--warp needs curated sets with the warped references; one of {cfg.data} has "
            "none (curate it again with this version of `prosplat train curate`)"
        )
    if cfg.crop and cfg.crop % model.config.size_multiple:
        raise ValueError(
            f"--crop must be a multiple of {model.config.size_multiple}, got {cfg.crop}"
        )
    small = min(min(d["render"].shape[-2:]) for d in sets)
    if cfg.crop and small < cfg.crop:
        raise ValueError(f"--crop {cfg.crop} is larger than the smallest curated views ({small})")
    least = 2 * SHIFT_MARGIN + MAX_SHIFT + 1  # a window and its twin share pixels inside
    if cfg.shift_weight and (cfg.crop < least or cfg.batch % 2 or small < cfg.crop + MAX_SHIFT):
        raise ValueError(
            f"--shift-weight needs --crop of at least {least}, an even --batch and views at "
            f"least --crop + {MAX_SHIFT} px (got crop {cfg.crop}, batch {cfg.batch}, views {small})"
        )
    if cfg.padding:
        model.set_padding(cfg.padding)
    # the views' size, not the crops': the model learns textures at the scale of whole views
    size = max(max(d["render"].shape[-2:]) for d in sets)
    size = size if cfg.working_size < 0 else cfg.working_size
    model.config = model.config.with_(working_size=size)
    augment_rng = torch.Generator().manual_seed(cfg.seed + 1)
    val = load_curated(cfg.val) if cfg.val and dist.is_main else None
    params = [p for p in model.parameters() if p.requires_grad]
    run = _Run(cfg, dist, params, model.state_dict, progress, "train improve")
    if run.resumed is not None:
        model.load_state_dict(run.resumed.weights)
    net = dist.wrap(model)
    lpips_fn = LPIPS().to(device) if cfg.lpips_weight > 0 else None
    interrupted = False
    try:
        while run.step < cfg.steps:
            data = sets[run.step % len(sets)]  # one set per step: a batch has one view size
            n = data["render"].shape[0]
            step = run.step // len(sets)  # each set walks its own shuffled epochs
            _, idx = step_indices(n, cfg.batch, cfg.seed, step, dist.rank, dist.world_size)
            # with the shift term each drawn sample makes two: draw half (per rank)
            index = torch.tensor(idx[: max(1, len(idx) // 2)] if cfg.shift_weight else idx)
            raw, ref, fund, gt = curated_batch(data, index, cfg.reference_method, device)
            alpha = curated_alpha(data, index, device) if cfg.alpha else None
            warp = curated_warp(data, index, cfg.reference_method, device) if cfg.warp else None
            if cfg.crop or cfg.flip:
                # alpha and warp are pixel-aligned with the render: one window, one flip
                aligned = [x for x in (alpha, warp) if x is not None]
                stacked = torch.cat(aligned, 1) if aligned else None
                if cfg.shift_weight:
                    (raw, ref, fund, gt, stacked), shifts, flipped = shifted_pairs(
                        raw, ref, fund, gt, stacked, cfg.crop, cfg.flip, augment_rng
                    )
                else:
                    raw, ref, fund, gt, stacked = augment_samples(
                        raw, ref, fund, gt, stacked, cfg.crop, cfg.flip, augment_rng
                    )
                if cfg.subpixel_shift:  # the twins: the second half of the batch
                    half = raw.shape[0] // 2
                    delta = torch.rand(half, 2, generator=augment_rng) - 0.5  # [B/2,2] px
                    delta = delta.to(device=raw.device, dtype=raw.dtype)
                    raw = torch.cat([raw[:half], subpixel_translate(raw[half:], delta)])
                    gt = torch.cat([gt[:half], subpixel_translate(gt[half:], delta)])
                    if stacked is not None:
                        moved = subpixel_translate(stacked[half:], delta)
                        stacked = torch.cat([stacked[:half], moved])
                alpha = stacked[:, :1] if alpha is not None else None
                warp = stacked[:, -4:] if warp is not None else None
            out = net(raw, ref, fund, alpha, warp)
            loss, parts = enhance_loss(out, gt, lpips_fn, cfg.lpips_weight)
            if cfg.shift_weight:
                compared = out
                if cfg.subpixel_shift:  # first outputs moved as their twins' inputs were
                    compared = torch.cat([subpixel_translate(out[:half], delta), out[half:]])
                shift = shift_disagreement(compared, shifts, flipped)
                loss = loss + cfg.shift_weight * shift
                parts["shift"] = float(shift.detach())
            extra = {}
            if val is not None and (run.step + 1) % cfg.val_every == 0:
                extra = validate_improver(model, val, cfg.reference_method, device)
            run.advance(loss, params, parts, extra)
    except KeyboardInterrupt:  # Ctrl-C, or `timeout --signal=INT` on a time-boxed machine
        interrupted = True
        run.save()  # the same command resumes from here
    finally:
        run.close()
    final = Path(cfg.out) / "improve.safetensors"
    if dist.is_main:
        from prosplat.improve.pretrained import merge_lora

        cmd = f"prosplat train improve {json.dumps(asdict(cfg))}"
        model = merge_lora(model.cpu())  # LoRA runs resume from their checkpoint, not this file
        save_improver(model, final, overwrite=True, command=cmd, steps=str(run.step))
        if interrupted:
            print(
                f"train improve: interrupted at step {run.step} of {cfg.steps}; saved the "
                f"weights so far to {final} and a checkpoint: the same command resumes",
                file=sys.stderr,
            )
    return final


def joint_parameters(pipe, improver: ImproveModel, train_decoder: bool) -> list[Tensor]:
    """Freeze everything but the generator's Gaussian adapter and the improvement model's VAE
    encoder (+ decoder and its skip convolutions with ``train_decoder``); returns what trains."""
    pipe.generator.requires_grad_(False)
    improver.requires_grad_(False)
    parts = [pipe.generator.adapter, improver.vae.encoder]
    if improver.vae.quant_conv is not None:
        parts.append(improver.vae.quant_conv)
    if train_decoder:
        parts += [improver.vae.decoder, improver.skip_convs]
        if improver.vae.post_quant_conv is not None:
            parts.append(improver.vae.post_quant_conv)
    for m in parts:
        m.requires_grad_(True)
    return [p for m in parts for p in m.parameters()]


def train_joint(cfg: JointTrainConfig, progress: bool = True) -> tuple[Path, Path]:
    """Joint fine-tuning; returns (generator checkpoint, improvement checkpoint)."""
    dist = setup_distributed(cfg.device)
    try:
        return _train_joint(cfg, progress, dist)
    finally:
        dist.close()


def _train_joint(cfg: JointTrainConfig, progress: bool, dist: Dist) -> tuple[Path, Path]:
    from prosplat.data import SceneDataset
    from prosplat.improve.epipolar import fundamental_matrix
    from prosplat.improve.mori import select_reference
    from prosplat.metrics import LPIPS
    from prosplat.pipeline.model import ProSplat
    from prosplat.render import render
    from prosplat.train.batches import batch_cameras

    device = dist.device
    torch.manual_seed(cfg.seed)
    pipe = ProSplat.from_pretrained(cfg.generator, improve=cfg.improver, device=device)
    gen, imp = pipe.generator, pipe.improver
    params = joint_parameters(pipe, imp, cfg.train_decoder)

    def weights() -> dict[str, Tensor]:
        return {**{f"generator.{k}": v for k, v in gen.state_dict().items()},
                **{f"improver.{k}": v for k, v in imp.state_dict().items()}}  # fmt: skip

    run = _Run(cfg, dist, params, weights, progress, "train joint")
    if run.resumed is not None:
        w = run.resumed.weights
        gen.load_state_dict({k[10:]: v for k, v in w.items() if k.startswith("generator.")})
        imp.load_state_dict({k[9:]: v for k, v in w.items() if k.startswith("improver.")})
    gen.train()
    imp.train()
    lpips_fn = LPIPS().to(device)
    ds = SceneDataset(cfg.data, n_inputs=cfg.inputs, n_targets=cfg.targets, seed=cfg.seed)
    bg = torch.zeros(3, device=device)
    try:
        while run.step < cfg.steps:
            _, idx = step_indices(len(ds), 1, cfg.seed, run.step, dist.rank, dist.world_size)
            item = {k: v.to(device) if isinstance(v, Tensor) else v for k, v in ds[idx[0]].items()}
            h, w = item["input_images"].shape[-2:]
            out = gen(item["input_images"][None], item["input_K"][None], item["input_w2c"][None],
                      item["near"][None], item["far"][None])  # fmt: skip
            gaussians = out.gaussians(0)
            in_cams = batch_cameras(item["input_K"], item["input_w2c"], w, h)
            tgt_cams = batch_cameras(item["target_K"], item["target_w2c"], w, h)
            raws, refs, funds = [], [], []
            for cam in tgt_cams:
                raws.append(render(gaussians, cam, background=bg).rgb)
                j = select_reference(cam, in_cams, method=cfg.reference_method)
                refs.append(item["input_images"][j])
                funds.append(fundamental_matrix(cam, in_cams[j]).float().to(device))
            enhanced = imp(torch.stack(raws), torch.stack(refs), torch.stack(funds))
            gt = item["target_images"]
            loss, parts = enhance_loss(enhanced, gt, lpips_fn, cfg.lpips_weight)
            run.advance(loss * len(tgt_cams), params, parts)  # summed over the target views
    finally:
        run.close()
    out_dir = Path(cfg.out)
    gen_path, imp_path = out_dir / "generator.safetensors", out_dir / "improve.safetensors"
    if dist.is_main:
        pipe.to("cpu")
        pipe.save(gen_path, overwrite=True)
        cmd = f"prosplat train joint {json.dumps(asdict(cfg))}"
        save_improver(imp, imp_path, overwrite=True, command=cmd, steps=str(run.step))
    return gen_path, imp_path
