"""Per-scene 3DGS optimisation on the sparse input views: the slow, classical baseline.

What the feed-forward generator replaces: fit Gaussians to the few input images by gradient
descent through :func:`prosplat.render`, as 3DGS (Kerbl et al. 2023) does, with its learning
rates and loss, ``(1 - λ)·L1 + λ·(1 - SSIM)``, λ = 0.2, one input view per step. The loop
is :func:`prosplat.pipeline.refine.refine` with its regularisers off, started from plane-sweep stereo
or random points instead of the generator's Gaussians.

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

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.eval.baselines.plane_sweep import plane_sweep_gaussians
from prosplat.geometry.matching import check_inputs
from prosplat.pipeline.refine import LearningRates, RefineOptions, photometric_loss, refine
from prosplat.render import render

__all__ = ["LearningRates", "optimize_gaussians", "random_init"]


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
    check_inputs(images, cameras, near, far)
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
    g0 = g0.with_sh_degree(sh_degree)
    bg = None if background is None else tuple(float(x) for x in background)

    def mean_loss(g) -> float:
        with torch.no_grad():
            return float(
                sum(
                    photometric_loss(render(g, c, background).rgb, images[i])
                    for i, c in enumerate(cameras)
                )
                / v
            )

    initial = mean_loss(g0)
    from tqdm import tqdm

    bar = tqdm(total=int(steps), desc="optimise 3DGS", unit="step", disable=not progress)

    def report(step: int, total, loss: float) -> None:
        bar.update(1)
        bar.set_postfix(loss=f"{loss:.4f}")

    options = RefineOptions.unregularised(lr=lr, sh_degree=sh_degree, background=bg)
    result = refine(
        g0,
        images,
        cameras,
        steps=int(steps),
        seed=seed,
        progress=report if progress else None,
        options=options,
    )
    bar.close()
    final = mean_loss(result.gaussians)
    wall = time.perf_counter() - start
    stats = {
        "wall_time_s": wall,
        "s_per_step": result.stats.seconds / max(int(steps), 1),
        "steps": int(steps),
        "initial_loss": initial,
        "final_loss": final,
        "loss_history": result.stats.loss_history,
        "n_gaussians": len(g0),
        "init": init,
        "scene_extent": result.stats.scene_extent,
    }
    return result.gaussians, stats
