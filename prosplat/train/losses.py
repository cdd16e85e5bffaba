"""The generator's loss: every target view rendered from the predicted Gaussians with the
differentiable rasterizer and compared with Blender's image (MSE + LPIPS + SSIM) and depth,
plus the direct depth terms on the generator's own per-input depth maps."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.render import render
from prosplat.render.hole_fill import fill_holes
from prosplat.train.batches import batch_cameras, one_surface
from prosplat.train.generator_config import TrainConfig


def render_views(
    gaussians, cams: list[Camera], bg: Tensor, cpu_backend: str = "cpu-fused"
) -> tuple[Tensor, Tensor, Tensor]:
    """Render the loss's cameras (one size): rgb [C,3,H,W], alpha [C,H,W], depth [C,H,W].

    With gsplat on CUDA all cameras go in one call (:func:`render_gsplat_views`). On CUDA
    without gsplat the Gaussians go to the CPU rasterizer and the outputs come back (autograd
    follows both copies), so a GPU still trains the network. On the CPU the projection is
    the fused C++ kernel (``cpu_backend``): the torch projection computes the same float64
    numbers (the render tests hold them together) through ~100 ops whose autograd cost ~20 %
    of a training step (measured by ``benchmarks/generator_step.py``, in git history).
    """
    from prosplat.render import gsplat_available

    device = gaussians.device
    if device.type == "cuda" and gsplat_available(device):
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
            rgb, alpha, depth = render_views(gaussians, cams, bg, cpu_backend)  # [C,3,H,W]
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
