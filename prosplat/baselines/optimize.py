"""Per-scene 3DGS optimisation on the sparse input views: the slow, classical baseline.

What the feed-forward generator replaces: fit Gaussians to the few input images by gradient
descent through :func:`prosplat.render`, as 3DGS (Kerbl et al. 2023) does, with its learning
rates and loss, ``(1 - λ)·L1 + λ·(1 - SSIM)``, λ = 0.2, one random input view per step.

Deliberate simplifications, because the point is a fair sparse-view baseline, not a full 3DGS:

- no densification or pruning (clone/split/reset): with 2-4 views and few hundred steps the
  initialisation (one Gaussian per input pixel from plane-sweep stereo) is already denser
  than what the views constrain, and densification mostly adds floaters;
- SH degree 0 by default: with so few views, higher bands fit view-dependent noise;
- the position learning rate decays exponentially to 1% over the run, as in 3DGS, scaled by
  the scene extent (below).

The scene extent is ``1.1 x max(camera radius, half the median camera-to-point distance)``:
3DGS uses the camera radius alone, which collapses to zero for coincident cameras, so the
point cloud's distance keeps the position step meaningful there.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.baselines.plane_sweep import _check_inputs, plane_sweep_gaussians
from prosplat.camera import Camera
from prosplat.gaussians import Gaussians
from prosplat.metrics import ssim
from prosplat.render import render

__all__ = ["LearningRates", "optimize_gaussians", "random_init"]

SSIM_LAMBDA = 0.2


@dataclass(frozen=True)
class LearningRates:
    """Adam learning rates per parameter group (3DGS defaults).

    ``means`` is multiplied by the scene extent and decays to ``means * means_final_ratio``;
    ``sh_rest`` applies to SH bands above degree 0 (3DGS: ``sh / 20``).
    """

    means: float = 1.6e-4
    means_final_ratio: float = 0.01
    sh: float = 2.5e-3
    sh_rest: float = 2.5e-3 / 20
    opacity: float = 5e-2
    scale: float = 5e-3
    rotation: float = 1e-3


def random_init(
    images: Tensor,
    cameras: list[Camera],
    near: float,
    far: float,
    n_points: int,
    generator: torch.Generator,
) -> Gaussians:
    """``n_points`` Gaussians at random places in the input frustums between near and far.

    Each point picks a view and a continuous pixel uniformly and a depth uniformly in inverse
    depth (as the plane sweep samples depth); it takes that pixel's colour (a cheap, fair
    start: 3DGS's random init uses random colours, which only costs steps), opacity 0.1 (as
    3DGS), identity rotation, and an isotropic scale equal to the lateral spacing the points
    would have if they all lay on one surface: ``depth / fx * sqrt(V·H·W / n_points)``.
    """
    v, _, h, w = images.shape
    dtype = images.dtype
    view = torch.randint(0, v, (n_points,), generator=generator)
    uv = torch.rand(n_points, 2, generator=generator, dtype=torch.float64)
    uv = uv * torch.tensor([w, h], dtype=torch.float64)
    t = torch.rand(n_points, generator=generator, dtype=torch.float64)
    depth = 1 / (1 / near + (1 / far - 1 / near) * t)
    means = torch.empty(n_points, 3, dtype=torch.float64)
    foot = torch.empty(n_points, dtype=torch.float64)
    for i, cam in enumerate(cameras):
        sel = view == i
        means[sel] = cam.unproject(uv[sel], depth[sel])
        foot[sel] = depth[sel] / cam.fx
    col = uv[:, 0].long().clamp_max(w - 1)
    row = uv[:, 1].long().clamp_max(h - 1)
    colors = images.detach().cpu()[view, :, row, col].to(torch.float64)  # [n,3]
    scale = foot * math.sqrt(v * h * w / max(n_points, 1))
    return Gaussians.from_colors(
        means,
        colors.clamp(0, 1),
        scale[:, None].expand(-1, 3).clone(),
        torch.full((n_points,), 0.1, dtype=torch.float64),
    ).to(device=images.device, dtype=dtype)


def _scene_extent(cameras: list[Camera], means: Tensor) -> float:
    centers = torch.stack([c.center.to(torch.float64).cpu() for c in cameras])
    mid = centers.mean(0)
    cam_radius = float((centers - mid).norm(dim=1).max())
    if len(means):
        point_dist = float((means.detach().cpu().to(torch.float64) - mid).norm(dim=1).median())
    else:
        point_dist = 0.0
    extent = 1.1 * max(cam_radius, 0.5 * point_dist)
    return extent if extent > 0 else 1.0


def _photometric_loss(pred: Tensor, target: Tensor) -> Tensor:
    """3DGS loss: (1 - λ)·L1 + λ·(1 - SSIM), λ = 0.2."""
    l1 = (pred - target).abs().mean()
    return (1 - SSIM_LAMBDA) * l1 + SSIM_LAMBDA * (1 - ssim(pred, target))


class _Params(torch.nn.Module):
    """Raw (unconstrained) 3DGS parameters; :meth:`gaussians` activates them."""

    def __init__(self, g: Gaussians) -> None:
        super().__init__()
        eps = 1e-6
        self.means = torch.nn.Parameter(g.means.detach().clone())
        self.log_scales = torch.nn.Parameter(torch.log(g.scales.detach().clamp_min(1e-8)))
        o = g.opacities.detach().clamp(eps, 1 - eps)
        self.logit_opacities = torch.nn.Parameter(torch.log(o) - torch.log1p(-o))
        self.quats = torch.nn.Parameter(F.normalize(g.quats.detach(), dim=1).clone())
        self.sh_dc = torch.nn.Parameter(g.sh.detach()[:, :1].clone())
        self.sh_rest = torch.nn.Parameter(g.sh.detach()[:, 1:].clone())

    def gaussians(self) -> Gaussians:
        return Gaussians(
            self.means,
            self.quats,
            torch.exp(self.log_scales),
            torch.sigmoid(self.logit_opacities),
            torch.cat([self.sh_dc, self.sh_rest], dim=1),
        )


def _check_images_size(images: Tensor) -> None:
    h, w = images.shape[-2:]
    if min(h, w) < 11:
        raise ValueError(f"images must be at least 11x11 for the SSIM loss, got {w}x{h}")


def optimize_gaussians(
    images: Tensor,
    cameras: list[Camera],
    near: float,
    far: float,
    steps: int,
    init: str = "plane_sweep",
    lr: LearningRates | None = None,
    sh_degree: int = 0,
    n_random: int | None = None,
    n_depths: int = 64,
    background: Tensor | None = None,
    progress: bool = False,
    seed: int = 0,
    deterministic: bool = False,
) -> tuple[Gaussians, dict]:
    """Fit Gaussians to ``images`` from ``cameras`` by per-scene gradient descent.

    Args:
        images: [V,3,H,W] input views in [0, 1]; cameras: V cameras, W x H each.
        near, far: the scene's depth range (plane-sweep range, random-init frustum).
        steps: optimisation steps (one view each).
        init: "plane_sweep" (one Gaussian per input pixel from :func:`plane_sweep_gaussians`)
            or "random" (``n_random`` points in the frustums, default V·H·W).
        lr: learning rates, :class:`LearningRates` (3DGS defaults).
        sh_degree: SH degree of the optimised colours (0-3); bands above 0 start at zero.
        n_depths: plane-sweep depth candidates for the "plane_sweep" init.
        background: [3] colour behind the Gaussians (default black).
        progress: show a tqdm bar.
        seed: seeds the random init and the view order.
        deterministic: run single-threaded so that a seed gives bitwise the same result on
            the CPU backend (gsplat's CUDA backward uses atomics and is never bitwise). The
            multi-threaded CPU backward sums per-thread gradient buffers whose split varies
            from run to run, and Adam (eps 1e-15, as 3DGS) turns the last-bit differences of
            near-zero gradients into steps of a full learning rate.

    Returns:
        The optimised Gaussians (detached) and stats: ``wall_time_s`` (all of it, init and
        evaluation included), ``s_per_step`` (the optimisation loop only),
        ``steps``, ``initial_loss`` and ``final_loss`` (the mean loss over all input views,
        before and after), ``loss_history`` (per step, on that step's view), ``n_gaussians``,
        ``init``, ``scene_extent``.
    """
    _check_inputs(images, cameras, near, far)
    _check_images_size(images)
    if deterministic:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return optimize_gaussians(
                images,
                cameras,
                near,
                far,
                steps,
                init,
                lr,
                sh_degree,
                n_random,
                n_depths,
                background,
                progress,
                seed,
                deterministic=False,
            )
        finally:
            torch.set_num_threads(threads)
    if int(steps) != steps or steps < 0:
        raise ValueError(f"steps must be a non-negative integer, got {steps}")
    if init not in ("plane_sweep", "random"):
        raise ValueError(f"init must be 'plane_sweep' or 'random', got {init!r}")
    if sh_degree not in (0, 1, 2, 3):
        raise ValueError(f"sh_degree must be 0-3, got {sh_degree}")
    lr = lr or LearningRates()
    gen = torch.Generator().manual_seed(seed)
    start = time.perf_counter()

    v, _, h, w = images.shape
    if init == "plane_sweep":
        g0, _, _ = plane_sweep_gaussians(images, cameras, near, far, n_depths)
    else:
        g0 = random_init(images, cameras, near, far, n_random or v * h * w, gen)
    params = _Params(g0.with_sh_degree(sh_degree))
    extent = _scene_extent(cameras, g0.means)
    lr_means = lr.means * extent
    groups = [
        {"params": [params.means], "lr": lr_means},
        {"params": [params.sh_dc], "lr": lr.sh},
        {"params": [params.sh_rest], "lr": lr.sh_rest},
        {"params": [params.logit_opacities], "lr": lr.opacity},
        {"params": [params.log_scales], "lr": lr.scale},
        {"params": [params.quats], "lr": lr.rotation},
    ]
    opt = torch.optim.Adam(groups, eps=1e-15)  # 3DGS's eps: raw gradients here are tiny

    def mean_loss() -> float:
        with torch.no_grad():
            g = params.gaussians()
            return float(
                sum(
                    _photometric_loss(render(g, c, background).rgb, images[i])
                    for i, c in enumerate(cameras)
                )
                / v
            )

    initial = mean_loss()
    history: list[float] = []
    from tqdm import tqdm

    loop_start = time.perf_counter()
    bar = tqdm(range(int(steps)), desc="optimise 3DGS", unit="step", disable=not progress)
    for step in bar:
        frac = step / max(int(steps) - 1, 1)
        opt.param_groups[0]["lr"] = lr_means * lr.means_final_ratio**frac  # log-linear decay
        i = int(torch.randint(0, v, (1,), generator=gen))
        out = render(params.gaussians(), cameras[i], background)
        loss = _photometric_loss(out.rgb, images[i])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        history.append(float(loss.detach()))
        if progress:
            bar.set_postfix(loss=f"{history[-1]:.4f}")
    loop_time = time.perf_counter() - loop_start
    final = mean_loss()
    wall = time.perf_counter() - start
    stats = {
        "wall_time_s": wall,
        "s_per_step": loop_time / max(int(steps), 1),
        "steps": int(steps),
        "initial_loss": initial,
        "final_loss": final,
        "loss_history": history,
        "n_gaussians": len(g0),
        "init": init,
        "scene_extent": extent,
    }
    return params.gaussians().detach(), stats
