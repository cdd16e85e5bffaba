"""Refinement: fit a reconstruction's Gaussians to its input views for a few seconds.

The generator gives a scene in one forward pass; a few hundred steps of 3DGS-style gradient
descent starting from its Gaussians fit the input views much more closely. Fitting 2-6 images
can overfit them (floaters, surfaces pulled toward the one view that sees them), so the loop
carries regularisers, each of which :class:`RefineOptions` switches on or off, and its defaults
are the ones the measurements on *target* views support (README, "Refinement"; BENCHMARKS.md):
with the shipped generator, none of them helped novel views, so they are off by default.

The loop is the one per-scene optimisation uses (:func:`prosplat.eval.baselines.optimize_gaussians`
calls :func:`refine` with every regulariser off): 3DGS's Adam learning rates, the position
rate scaled by the scene extent and decayed log-linearly to 1 % over the run (over the time
budget when one is given), loss ``(1 - λ)·L1 + λ·(1 - SSIM)`` with λ = 0.2, one input view
per step, the views visited in a seeded random order, each once per pass.

The Gaussian count never changes (no densification, no pruning): the budget the caller pruned
to is the budget refinement keeps.

    >>> result = refine(gaussians, images, cameras, steps=300, depths=generator_depths)
    >>> result.gaussians, result.stats.steps_per_s
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.geometry.budget import check_view_index
from prosplat.geometry.pixel_gaussians import slide_gaussians
from prosplat.metrics.image import SSIM_WINDOW, ssim_map
from prosplat.render import render
from prosplat.render.projection import DILATION, FOV_CLAMP, MIN_ALPHA, NEAR_PLANE

__all__ = [
    "check_budget",
    "check_refine_args",
    "LearningRates",
    "REFINE_RATES",
    "RefineOptions",
    "RefineResult",
    "RefineStats",
    "photometric_loss",
    "refine",
    "sh_degree_for_views",
]

SSIM_LAMBDA = 0.2

#: The step count a bare ``--refine-steps`` asks for: the knee of the measured curve (README,
#: "Refinement"): at 64 px it buys ~90 % of 1000 steps' PSNR gain and the best LPIPS, in
#: ~5 s on 2 idle cores.
RECOMMENDED_STEPS = 300


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


#: The learning rates refinement runs with: 3DGS's, but the colours stay the generator's. Fitting
#: four views' colours over geometry that is wrong in places pulls each Gaussian's colour
#: towards what its pixels show in the other inputs, which new views then see. Against
#: fitting them too (refine 100, shipped v16 + v22, 4 inputs; BENCHMARKS "Refinement with the
#: colours kept"): the filled raw view +0.24 / +0.18 dB at 64 / 128 px on the 8 validation
#: scenes, enhanced +0.04 / +0.01; on the 24 test scenes (where the hard scenes showed it)
#: enhanced level; on the fox photos (refine 300) enhanced +0.13 / +0.12, LPIPS lower.
#: Per-scene optimisation (:meth:`RefineOptions.unregularised`) fits colours, as 3DGS does.
REFINE_RATES = LearningRates(sh=0.0, sh_rest=0.0)


@dataclass(frozen=True)
class RefineOptions:
    """What the refinement loop fits and how it is regularised (each term has an off switch).

    Attributes:
        lr: Adam learning rates (:class:`LearningRates`).
        ssim_weight: λ of the photometric loss ``(1 - λ)·L1 + λ·(1 - SSIM)``.
        depth_weight: weight of the depth term: the mean relative difference
            ``|z_render - z_gen| / z_gen`` between each input view's rendered depth and the
            generator's depth of that view (the ``depths`` given to :func:`refine`), over
            pixels where both exist (render alpha > 0.5). 0 (or no ``depths``) turns it off.
            It keeps surfaces where the generator's multi-view match put them, so that a
            surface seen well by one view only is not pulled off its place to fit that view.
        opacity_weight: weight of ``mean(opacity)`` (as 3DGS-MCMC): Gaussians that no view
            needs fade out instead of floating in front of novel views. 0 turns it off.
        scale_weight: weight of ``mean(relu(log s - log s_start))``: growth beyond the
            starting scale (blobs that smear novel views) costs; shrinking is free. 0: off.
        freeze_means_steps: the means stay fixed for this many first steps, so colours and
            opacities settle before geometry moves (0: off).
        cross_view_weight: weight of the cross-view term: each step also renders the step's
            input view from the *other* views' Gaussians alone and adds its L1 to the image,
            over the pixels they cover (alpha > 0.5). A view's own pixel-aligned Gaussians
            project onto their pixels at any depth, so fitting a view with them in place
            says nothing about where its surfaces are; seen from another camera they land
            where their depth puts them, so this term is the multi-view photometric match
            that moves geometry. Needs ``view_index`` (which input view predicted each
            Gaussian); 0 or no ``view_index`` turns it off.
        ray_scale_lr: Adam rate of one log-factor for the whole scene's depth, fitted with
            the Gaussians: every Gaussian slides along the ray from the camera of the view
            that predicted it by that factor (its scales with it, so its own view renders as
            before; :func:`prosplat.pipeline.depth_sweep.slide_gaussians`), the rate decaying with the
            position rate. A scene-wide depth error (the generator's depth lies a median 5 %
            too near, BENCHMARKS.md "A scene-wide depth factor") is one coordinated move that
            per-Gaussian position steps, made for 30,000 steps, do not make in a few hundred.
            Needs ``view_index``; 0 or no ``view_index`` turns it off.
        drop_rate: each step renders a random fraction ``1 - drop_rate`` of the Gaussians
            (each dropped independently), their opacities divided by ``1 - drop_rate``
            (capped below 1, :func:`drop_gaussians`) so the image keeps its coverage:
            DropGaussian (Park et al., CVPR 2025). With 2-6 views every Gaussian is fitted to
            few pixels; dropping its neighbours makes each one explain its pixels on its own
            instead of a few front Gaussians absorbing every view's error, the overfitting
            novel views pay for. The final Gaussians are all kept, at their fitted
            opacities. 0 turns it off; the default 0.1 is the measured choice (0.2 and 0.3
            raise the raw views more and cost the enhanced ones up to 0.1 dB).
        sh_degree: SH degree fitted: an int 0-3, or ``"auto"`` (:func:`sh_degree_for_views`:
            raised only when the views allow, and only when ``lr.sh_rest`` fits the higher
            bands; else the Gaussians' own). Bands above the Gaussians' own start at zero.
        background: RGB behind the Gaussians (default black, as the generator renders).
        cull: render each step only the Gaussians that can touch that view (a conservative
            bound, :func:`may_touch`); the image and gradients are bitwise those of rendering
            all of them (the tests hold it to its twin, ``cull=False``). It saved ~15 % of a
            step with the torch projection; with the fused projection the test costs what it
            saves (measured), so it is off by default.
        fused_projection: on the CPU, project with the fused C++ kernel
            (``render(..., backend="cpu-fused")``, :mod:`prosplat.render.fused`): the same
            float64 arithmetic as the torch projection (agreeing to ~1e-13 relative, forward
            and backward, in the tests) without ~100 autograd nodes per step.
        deterministic: on the CPU a seed gives bitwise the same Gaussians for a given thread
            count (the rasterizer's backward pass assigns tiles to threads statically).
            With False nothing changes today; the flag documents the contract.
    """

    lr: LearningRates = REFINE_RATES
    ssim_weight: float = SSIM_LAMBDA
    # The defaults are what the measurements on target views support (README, "Refinement";
    # BENCHMARKS.md): with the shipped generator every loss term tried lost PSNR or was
    # neutral, so all are off; dropping 10 % of the Gaussians per step raises the raw
    # targets +0.17 / +0.22 dB at 128 / 64 px (100 steps) and leaves the enhanced ones level
    # (BENCHMARKS "Refinement: dropping Gaussians"); the SH degree follows the view count.
    depth_weight: float = 0.0
    opacity_weight: float = 0.0
    scale_weight: float = 0.0
    freeze_means_steps: int = 0
    cross_view_weight: float = 0.0
    ray_scale_lr: float = 0.0
    drop_rate: float = 0.1
    sh_degree: int | str = "auto"
    background: tuple[float, float, float] | None = None
    cull: bool = False
    fused_projection: bool = True
    deterministic: bool = True

    @classmethod
    def unregularised(cls, **changes) -> RefineOptions:
        """The plain 3DGS loop: 3DGS's learning rates (colours fitted too), every
        regulariser off, no Gaussians dropped (what per-scene optimisation runs)."""
        base = cls(
            lr=LearningRates(),
            depth_weight=0.0,
            opacity_weight=0.0,
            scale_weight=0.0,
            freeze_means_steps=0,
            cross_view_weight=0.0,
            drop_rate=0.0,
        )
        return replace(base, **{"sh_degree": 0, **changes})

    def check(self) -> None:
        names = ("ssim_weight", "depth_weight", "opacity_weight", "scale_weight")
        for name in (*names, "cross_view_weight", "ray_scale_lr"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"RefineOptions.{name} must be a finite number >= 0, got {value}")
        if not (isinstance(self.drop_rate, (int, float)) and 0 <= self.drop_rate < 1):
            raise ValueError(f"RefineOptions.drop_rate must be in [0, 1), got {self.drop_rate}")
        if self.ssim_weight > 1:
            raise ValueError(f"RefineOptions.ssim_weight must be in [0, 1], got {self.ssim_weight}")
        if int(self.freeze_means_steps) != self.freeze_means_steps or self.freeze_means_steps < 0:
            raise ValueError(
                f"RefineOptions.freeze_means_steps must be an integer >= 0, got "
                f"{self.freeze_means_steps}"
            )
        if self.sh_degree not in (0, 1, 2, 3, "auto"):
            raise ValueError(
                f"RefineOptions.sh_degree must be 0-3 or 'auto', got {self.sh_degree!r}"
            )
        for name, value in vars(self.lr).items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(
                    f"RefineOptions.lr.{name} must be a finite number >= 0, got {value}"
                )


@dataclass
class RefineStats:
    """What one refinement did.

    ``steps``: steps run; ``seconds``: time in the loop; ``steps_per_s``; ``final_loss``: the
    mean photometric loss of the last pass over the input views (one step each, measured
    before each step's update), ``initial_loss`` the same for the first pass;
    ``loss_history``: the photometric loss of every step; ``cancelled``: the cancel hook
    stopped the loop; ``n_gaussians`` (unchanged by refinement), ``sh_degree`` fitted,
    ``scene_extent`` (scales the position learning rate), ``depth_factor`` (the scene-wide
    factor fitted, :attr:`RefineOptions.ray_scale_lr`; 1 when off). A reconstruction's
    generator and budget (seconds, counts) are in :class:`prosplat.Reconstruction`.
    """

    steps: int
    seconds: float
    steps_per_s: float
    initial_loss: float
    final_loss: float
    loss_history: list[float]
    cancelled: bool
    n_gaussians: int
    sh_degree: int
    scene_extent: float
    # the scene-wide depth factor fitted (RefineOptions.ray_scale_lr; 1: none)
    depth_factor: float = 1.0


@dataclass
class RefineResult:
    gaussians: Gaussians  # detached
    stats: RefineStats


def sh_degree_for_views(n_views: int) -> int:
    """The highest SH degree the views can constrain: a surface point seen from V directions
    gives V colour samples per channel, and degree d has (d+1)² coefficients; at least two
    samples per coefficient are asked for, so 2-7 views fit degree 0, 8-17 degree 1, 18-31
    degree 2 and 32 or more degree 3. (Every input view rarely sees every point, so this is
    an upper bound already.)"""
    degree = 0
    while degree < 3 and 2 * (degree + 2) ** 2 <= n_views:
        degree += 1
    return degree


def photometric_loss(pred: Tensor, target: Tensor, ssim_weight: float = SSIM_LAMBDA) -> Tensor:
    """3DGS loss: ``(1 - λ)·L1 + λ·(1 - SSIM)`` of two [3,H,W] images (no input checks; the
    callers check once, and ``prosplat.metrics.ssim`` is the checked twin of the SSIM)."""
    l1 = (pred - target).abs().mean()
    if ssim_weight == 0:
        return l1
    s = ssim_map(pred[None], target[None]).mean()
    return (1 - ssim_weight) * l1 + ssim_weight * (1 - s)


def scene_extent(cameras: Sequence[Camera], means: Tensor) -> float:
    """``1.1 x max(camera radius, half the median camera-to-point distance)``.

    3DGS uses the camera radius alone, which collapses to zero for coincident cameras, so the
    point cloud's distance keeps the position step meaningful there.
    """
    centers = torch.stack([c.center.to(torch.float64).cpu() for c in cameras])
    mid = centers.mean(0)
    cam_radius = float((centers - mid).norm(dim=1).max())
    if len(means):
        point_dist = float((means.detach().cpu().to(torch.float64) - mid).norm(dim=1).median())
    else:
        point_dist = 0.0
    extent = 1.1 * max(cam_radius, 0.5 * point_dist)
    return extent if extent > 0 else 1.0


class GaussianParams(torch.nn.Module):
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
        self.views = g.views  # [N] or None: fitting never changes which view made a Gaussian

    def gaussians(self) -> Gaussians:
        """The activated Gaussians (valid by construction; :meth:`Gaussians.trusted`)."""
        return Gaussians.trusted(
            self.means,
            self.quats,
            torch.exp(self.log_scales),
            torch.sigmoid(self.logit_opacities),
            torch.cat([self.sh_dc, self.sh_rest], dim=1),
            self.views,
        )

    def optimizer(self, lr: LearningRates, lr_means: float) -> torch.optim.Adam:
        """3DGS's Adam (eps 1e-15: raw gradients here are tiny), one group per parameter;
        group 0 holds the means (its rate is scheduled by the loop)."""
        groups = [
            {"params": [self.means], "lr": lr_means},
            {"params": [self.sh_dc], "lr": lr.sh},
            {"params": [self.sh_rest], "lr": lr.sh_rest},
            {"params": [self.logit_opacities], "lr": lr.opacity},
            {"params": [self.log_scales], "lr": lr.scale},
            {"params": [self.quats], "lr": lr.rotation},
        ]
        return torch.optim.Adam(groups, eps=1e-15)


@torch.no_grad()
def may_touch(params: GaussianParams | Gaussians, camera: Camera) -> Tensor:
    """Indices of the Gaussians whose pixel box in ``camera`` may be non-empty: a superset of
    what :func:`prosplat.render.project_gaussians` marks valid, from the means, the largest
    scale and the opacity alone (no rotation, no covariance), so it costs a few ops per
    Gaussian.

    The rasterizer's half-width is ``sqrt(r²·(a0 + 0.3))`` with ``r² = 2 ln(255·o)`` and
    ``a0 = |diag(s)·R_qᵀ·v0|² <= s_max²·|v0|²``, where ``v0 = fx/z·(R_cam[0] - x_c·R_cam[2])``
    has ``|v0|² = (fx/z)²·(1 + x_c²)`` (rows of a rotation are orthonormal; ``x_c`` is x/z
    clamped as the projection clamps it); likewise in y. A Gaussian is kept when it is in
    front of the near plane, at least 1/255 opaque, and its bounded box meets the image.
    """
    f64 = torch.float64
    if isinstance(params, Gaussians):  # already activated (e.g. slid along the rays)
        o = params.opacities.detach().to(f64)
        s_max = params.scales.detach().to(f64).amax(dim=1)
    else:
        o = torch.sigmoid(params.logit_opacities.detach().to(f64))
        s_max = torch.exp(params.log_scales.detach().to(f64).amax(dim=1))
    m = params.means.detach().to(f64).T  # [3,N]
    pc = (
        camera.R.to(device=m.device, dtype=f64) @ m
        + camera.t.to(device=m.device, dtype=f64)[:, None]
    )
    x, y, z = pc
    keep = (z >= NEAR_PLANE) & (o >= MIN_ALPHA)
    z_safe = torch.where(keep, z, torch.ones_like(z))
    r2 = 2.0 * torch.log((255.0 * o).clamp_min(1.0))
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    for coord, f, c, size in ((x, fx, cx, W), (y, fy, cy, H)):
        t = coord / z_safe
        tan = 0.5 * size / f
        t_c = t.clamp(-(c / f + FOV_CLAMP * tan), (size - c) / f + FOV_CLAMP * tan)
        a_bound = (s_max * f / z_safe) ** 2 * (1 + t_c * t_c) + DILATION
        half = torch.sqrt(r2 * a_bound) * 1.001 + 0.01
        u = f * t + c
        keep &= (u + half >= 0) & (u - half <= size) & torch.isfinite(half)
    return torch.nonzero(keep).squeeze(1)


def drop_gaussians(g: Gaussians, rate: float, generator: torch.Generator) -> Gaussians:
    """A random subset of ``g``, each Gaussian dropped with probability ``rate`` and the kept
    ones' opacities divided by ``1 - rate``: the expected coverage is kept
    (:attr:`RefineOptions.drop_rate`). Gradients flow to the kept Gaussians' parameters.

    The scaled opacity is capped just below 1 (the rasterizer takes opacities in [0, 1] and
    caps alpha at 0.99 anyway) with a straight-through gradient: the capped ones are the
    generator's most opaque Gaussians (a third of them above 0.8), and a plain clamp would
    freeze their opacity on every step they are kept."""
    keep = torch.rand(len(g), generator=generator) >= rate  # [N] on the CPU, as the seed is
    sub = g[torch.nonzero(keep).squeeze(1).to(g.device)]  # indices: one nonzero, not six
    scaled = sub.opacities / (1.0 - rate)  # [K]
    capped = scaled.clamp(max=1.0 - 1e-6)
    opacities = scaled + (capped - scaled).detach()  # the value capped, the gradient scaled's
    return Gaussians.trusted(sub.means, sub.quats, sub.scales, opacities, sub.sh, sub.views)


def check_images(images: Tensor, cameras: Sequence[Camera], what: str = "refine") -> None:
    """[V,3,H,W] finite images in [0, 1], one Camera of that size each, H, W >= 11 (SSIM)."""
    if not isinstance(images, Tensor) or images.ndim != 4 or images.shape[1] != 3:
        shape = list(images.shape) if isinstance(images, Tensor) else type(images).__name__
        raise ValueError(f"{what}: images must be a [V,3,H,W] tensor in [0,1], got {shape}")
    if not images.is_floating_point():
        raise ValueError(f"{what}: images must be float in [0,1], got {images.dtype}")
    if not bool(torch.isfinite(images).all()):
        raise ValueError(f"{what}: images hold NaN or Inf values; fix or drop those input views")
    if len(cameras) != images.shape[0]:
        raise ValueError(
            f"{what}: got {images.shape[0]} images but {len(cameras)} cameras; give one camera "
            "per image"
        )
    h, w = images.shape[-2:]
    if min(h, w) < SSIM_WINDOW:
        raise ValueError(
            f"{what}: images must be at least {SSIM_WINDOW}x{SSIM_WINDOW} for the SSIM loss, "
            f"got {w}x{h}"
        )
    for i, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise ValueError(
                f"{what}: cameras[{i}] must be a prosplat.Camera, got {type(cam).__name__}"
            )
        if (cam.width, cam.height) != (w, h):
            raise ValueError(
                f"{what}: cameras[{i}] is {cam.width}x{cam.height} but the images are {w}x{h}; "
                "use camera.resized(W, H) when resizing images"
            )


def check_budget(steps, seconds) -> None:
    """The library's form of a refinement budget: exactly one of ``steps`` (an integer >= 0)
    and ``seconds`` (a finite number > 0), the other None. Callers that run the generator
    first (:meth:`prosplat.ProSplat.reconstruct`, the add-on's worker) check it
    before that work, so a bad budget costs nothing."""
    if (steps is None) == (seconds is None):
        which = "not both" if steps is not None else "got neither"
        raise ValueError(
            f"refine: give steps= (a step count) or seconds= (a time budget), {which}: "
            f"steps={steps!r}, seconds={seconds!r}"
        )
    if steps is not None and (
        isinstance(steps, bool)
        or not isinstance(steps, (int, float))
        or int(steps) != steps
        or steps < 0  # fmt: skip
    ):
        raise ValueError(f"refine: steps must be an integer >= 0, got {steps!r}")
    if seconds is not None and (
        isinstance(seconds, bool)
        or not isinstance(seconds, (int, float))
        or not math.isfinite(seconds)
        or seconds <= 0  # fmt: skip
    ):
        raise ValueError(f"refine: seconds must be a finite number > 0, got {seconds!r}")


def _check_depths(depths: Tensor | None, images: Tensor) -> None:
    if depths is None:
        return
    v, _, h, w = images.shape
    if not isinstance(depths, Tensor) or tuple(depths.shape) != (v, h, w):
        shape = list(depths.shape) if isinstance(depths, Tensor) else type(depths).__name__
        raise ValueError(
            f"refine: depths must be [V,H,W] = [{v},{h},{w}] (the generator's depth per input "
            f"view), got {shape}"
        )
    if not bool(torch.isfinite(depths).all()) or bool((depths < 0).any()):
        raise ValueError("refine: depths must be finite and >= 0 (0 = no depth at that pixel)")


def refine(
    gaussians: Gaussians,
    images: Tensor,
    cameras: Sequence[Camera],
    *,
    steps: int | None = None,
    seconds: float | None = None,
    seed: int = 0,
    progress: Callable[[int, int | None, float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    depths: Tensor | None = None,
    view_index: Tensor | None = None,
    options: RefineOptions | None = None,
) -> RefineResult:
    """Fit ``gaussians`` to the input views ``images`` [V,3,H,W] seen by ``cameras``.

    Args:
        gaussians: the starting Gaussians (e.g. the generator's, pruned to the budget).
        images: [V,3,H,W] input views in [0, 1]; cameras: one W x H Camera each.
        steps / seconds: exactly one: a step count (>= 0) or a time budget (> 0 s; the step
            under way when it runs out is finished).
        seed: the order in which views are visited; the same seed gives the same Gaussians
            on the CPU (for a given thread count).
        progress: called after every step as ``progress(step, total, loss)``: steps done,
            ``steps`` or None under a time budget, that step's photometric loss.
        cancel: called before every step; True stops the loop and returns what was fitted.
        depths: [V,H,W] the generator's depth per input view (for the depth term; 0 = none).
        view_index: [N] the input view that predicted each Gaussian (for the cross-view term;
            :attr:`prosplat.Reconstruction.view_index`).
        options: :class:`RefineOptions` (the measured defaults).

    Returns:
        :class:`RefineResult`: the refined Gaussians (detached, same count, device and dtype
        as ``gaussians``, SH at the fitted degree) and :class:`RefineStats`.

    Raises:
        ValueError: both or neither of steps/seconds, a negative or non-integer step count, a
            bad time budget, NaN/Inf images or depths, mismatched sizes, bad options.
    """
    options = RefineOptions() if options is None else options
    if not isinstance(options, RefineOptions):
        raise ValueError(f"refine: options must be RefineOptions, got {type(options).__name__}")
    if not isinstance(gaussians, Gaussians):
        raise ValueError(
            f"refine: gaussians must be prosplat.Gaussians, got {type(gaussians).__name__}"
        )
    cameras = list(cameras)
    check_budget(steps, seconds)
    check_images(images, cameras)
    _check_depths(depths, images)
    if view_index is not None:
        check_view_index(view_index, len(gaussians), len(cameras), "refine: ")
    options.check()
    for name, fn in (("progress", progress), ("cancel", cancel)):
        if fn is not None and not callable(fn):
            raise ValueError(f"refine: {name} must be a callable or None, got {type(fn).__name__}")
    gaussians.validate()

    v = len(cameras)
    if options.sh_degree != "auto":
        degree = int(options.sh_degree)
    else:  # higher bands only where they are fitted (REFINE_RATES keeps the colours)
        degree = sh_degree_for_views(v) if options.lr.sh_rest > 0 else gaussians.sh_degree
    start = gaussians.detach().with_sh_degree(degree)
    dtype, device = start.means.dtype, start.means.device
    images = images.detach().to(device=device, dtype=dtype)
    bg = None if options.background is None else torch.tensor(options.background, dtype=dtype)
    extent = scene_extent(cameras, start.means)
    if len(start) == 0 or steps == 0:
        stats = RefineStats(0, 0.0, 0.0, math.nan, math.nan, [], False, len(start), degree, extent)
        return RefineResult(start, stats)

    params = GaussianParams(start)
    lr_means = options.lr.means * extent
    opt = params.optimizer(options.lr, lr_means)
    log_s0 = params.log_scales.detach().clone()
    use_depth = depths is not None and options.depth_weight > 0
    if use_depth:
        depths = depths.detach().to(device=device, dtype=dtype)
    others: list[Tensor] = []  # others[i]: the Gaussians the other views predicted
    if view_index is not None and options.cross_view_weight > 0:
        vi = view_index.to(device)
        others = [torch.nonzero(vi != i).squeeze(1) for i in range(v)]
    log_f = None  # the scene's log depth factor [1] (RefineOptions.ray_scale_lr)
    if view_index is not None and options.ray_scale_lr > 0:
        log_f = torch.zeros(1, dtype=dtype, device=device, requires_grad=True)
        opt.add_param_group({"params": [log_f], "lr": options.ray_scale_lr})

    def current() -> Gaussians:
        """The fitted Gaussians, slid along their rays by the scene's factor when fitted."""
        g = params.gaussians()
        return g if log_f is None else slide_gaussians(g, view_index, cameras, log_f.exp())

    opt_params = [p for group in opt.param_groups for p in group["params"]]
    backend = "cpu-fused" if options.fused_projection and device.type == "cpu" else "auto"
    gen = torch.Generator().manual_seed(int(seed))
    drop_gen = torch.Generator().manual_seed(int(seed) + 1)  # apart: order stays as without
    order: list[int] = []
    history: list[float] = []
    cancelled = False
    freeze = int(options.freeze_means_steps)
    params.means.requires_grad_(freeze == 0)

    t0 = time.perf_counter()
    step = 0
    while True:
        if steps is not None and step >= steps:
            break
        elapsed = time.perf_counter() - t0
        if seconds is not None and elapsed >= seconds:
            break
        if cancel is not None and cancel():
            cancelled = True
            break
        frac = step / max(int(steps) - 1, 1) if steps is not None else min(elapsed / seconds, 1.0)
        opt.param_groups[0]["lr"] = lr_means * options.lr.means_final_ratio**frac
        if log_f is not None:
            opt.param_groups[-1]["lr"] = options.ray_scale_lr * options.lr.means_final_ratio**frac
        if step == freeze and freeze:
            params.means.requires_grad_(True)
        if not order:  # every view once per pass, in a seeded order
            order = torch.randperm(v, generator=gen).tolist()
        i = order.pop()
        g = current()
        if options.drop_rate > 0:
            g = drop_gaussians(g, options.drop_rate, drop_gen)
        if options.cull:  # only what can touch view i: the same image, less projection work
            moved = log_f is not None or options.drop_rate > 0  # g is not params' own set
            sub = may_touch(g if moved else params, cameras[i])
            out = render(g[sub], cameras[i], bg, backend, check=False)
        else:
            out = render(g, cameras[i], bg, backend, check=False)
        photo = photometric_loss(out.rgb, images[i], options.ssim_weight)
        loss = photo
        if use_depth:
            ref = depths[i]
            valid = (ref > 0) & (out.alpha.detach() > 0.5)
            if bool(valid.any()):
                rel = (out.depth[valid] - ref[valid]).abs() / ref[valid]
                loss = loss + options.depth_weight * rel.mean()
        if others and len(others[i]):
            cross = render(g[others[i]], cameras[i], bg, backend, check=False)
            covered = cross.alpha.detach() > 0.5  # [H,W]
            if bool(covered.any()):
                a = cross.alpha.clamp_min(0.5)[None]  # [1,H,W]
                rgb = cross.rgb if bg is None else cross.rgb - bg[:, None, None] * (1 - a)
                # [3,H,W] the colour of what the other views put there, un-composited so that
                # partial coverage is not read as a darker surface
                l1 = (rgb / a - images[i]).abs().mean(0)[covered].mean()
                loss = loss + options.cross_view_weight * l1
        if options.opacity_weight > 0:
            loss = loss + options.opacity_weight * g.opacities.mean()
        if options.scale_weight > 0:
            loss = loss + options.scale_weight * torch.relu(params.log_scales - log_s0).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        # the renders skip Gaussians.validate (3.5 ms per 60,000): one sum per parameter
        # (a sum is finite iff every term is, barring overflow) catches a diverged fit
        if not math.isfinite(float(loss.detach())) or not all(
            bool(torch.isfinite(p.detach().sum())) for p in opt_params
        ):
            raise ValueError(
                f"refine: the fit diverged at step {step + 1} (loss {float(loss.detach()):.4g}, "
                "or a parameter is NaN/Inf); lower the learning rates (RefineOptions.lr)"
            )
        history.append(float(photo.detach()))
        step += 1
        if progress is not None:
            progress(step, None if steps is None else int(steps), history[-1])
    seconds_run = time.perf_counter() - t0
    with torch.no_grad():
        result = current().detach()
    k = min(v, len(history))
    stats = RefineStats(
        steps=step,
        seconds=seconds_run,
        steps_per_s=step / seconds_run if seconds_run > 0 else 0.0,
        initial_loss=sum(history[:k]) / k if k else math.nan,
        final_loss=sum(history[-k:]) / k if k else math.nan,
        loss_history=history,
        cancelled=cancelled,
        n_gaussians=len(result),
        sh_degree=degree,
        scene_extent=extent,
        depth_factor=1.0 if log_f is None else float(log_f.detach().exp()),
    )
    return RefineResult(result, stats)


def check_refine_args(
    steps: list[int] | int, seconds: list[float] | float | None, *, one_run: bool = False
) -> None:
    """--refine-steps must be integers >= 0 and --refine-seconds finite numbers > 0.

    ``one_run``: the flags describe one refinement (``demo``, ``reconstruct``, ``eval
    posed``), so a step count > 0 and a time budget are not both allowed; the ladder takes
    lists of both, one row each."""
    steps = steps if isinstance(steps, list) else [steps]
    seconds = seconds if isinstance(seconds, list) else [] if seconds is None else [seconds]
    if bad := [s for s in steps if s < 0]:
        raise ValueError(f"--refine-steps must be >= 0 (0: no refinement), got {bad}")
    if bad := [s for s in seconds if not (math.isfinite(s) and s > 0)]:
        raise ValueError(f"--refine-seconds must be a number of seconds > 0, got {bad}")
    if one_run and any(steps) and seconds:
        raise ValueError(
            "give --refine-steps or --refine-seconds, not both (a step count or a time budget)"
        )
