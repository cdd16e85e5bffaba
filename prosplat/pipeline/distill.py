"""Enhanced views distilled back into the Gaussians: one consistent scene for a set of cameras.

Stage 2 enhances every view on its own, from the reference MORI picks for it and the texture
warped through depth that is often wrong. Along a camera path the same surface therefore
changes from frame to frame: the shipped v6 flickers 1.8x as much as the raw renders (the
stage-2 issue's bar is 1.2x), and a multi-reference blend of the warp does not help (the
texture slides because the depth is wrong, not because the reference switches).

Distilling removes the disagreement at its root, as Difix3D+ does with its fixer: render and
enhance every camera that will be shown, then refine the Gaussians against the input
photographs and those enhanced views together (:func:`prosplat.pipeline.refine.refine`), and render
the cameras from the distilled Gaussians. One set of Gaussians cannot disagree with itself,
so the frames are as consistent as raw renders, and fitting many enhanced views at once keeps
what they agree on. Refinement never adds Gaussians, and the generator leaves holes where
no input saw (since v16 even in its own input views), so every pixel of the inputs and views
that the Gaussians leave uncovered first gets a Gaussian of its own
(:mod:`prosplat.geometry.hole_gaussians`); without that the distilled views keep those holes black.
With generator v16 and stage 2 v22 on the test ladder, 800 steps give +0.22 dB over the
enhanced views at 64 px and 400 steps +0.10 dB at 128 px, at the same LPIPS, with no scene
type below them (BENCHMARKS "Distilled views with generator v16").

What it costs: one enhancement per view plus the refinement steps, all before the first
frame comes out; so it is a choice for a set of views or a path (``--distill-steps``), not
for a single view.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.geometry.hole_gaussians import hole_gaussians
from prosplat.pipeline.enhance import EnhanceOptions, render_view
from prosplat.pipeline.refine import RefineOptions, RefineResult, RefineStats, refine

#: Refinement steps a distillation runs when the caller names neither steps nor seconds,
#: measured on the test ladder (generator v16, stage 2 v22, holes seeded): at 64 px 400
#: beat the enhanced views by +0.13 dB and 800 by +0.22, with no scene type below them
#: (with v3 + v6: 400 +0.2-0.3 dB, some types below). Each step fits one view, so a long
#: path (hundreds of frames) visits each view only a few times.
DEFAULT_DISTILL_STEPS = 800


@dataclass
class DistillResult:
    """The distilled Gaussians (detached), the enhanced views they were fitted to
    ``[T,3,H,W]`` at the inputs' size, the refinement's statistics and the seconds spent
    enhancing."""

    gaussians: Gaussians
    enhanced: Tensor
    stats: RefineStats
    enhance_s: float


def fits_inputs(camera: Camera, height: int, width: int) -> bool:
    """Whether a view of ``camera`` can be distilled with inputs of ``height`` x ``width``:
    the same aspect ratio within 1 % (refinement fits views of one size, so a view of
    another resolution is resized to the inputs')."""
    return abs(camera.width * height - camera.height * width) <= 0.01 * camera.height * width


def _at_input_size(image: Tensor, camera: Camera, height: int, width: int, k: int):
    """A view [3,h,w] and its camera at the inputs' size (antialiased), when only the
    resolution differs; refinement fits views of one size."""
    if (camera.height, camera.width) == (height, width):
        return image, camera
    if not fits_inputs(camera, height, width):
        raise ValueError(
            f"distill: view {k} is {camera.width}x{camera.height} but the inputs are "
            f"{width}x{height}; views must have the inputs' aspect ratio (render other "
            "shapes one by one with ProSplat.render)"
        )
    out = F.interpolate(
        image[None], size=(height, width), mode="bilinear", antialias=True, align_corners=False
    )[0].clamp(0, 1)
    return out, camera.resized(width, height)


def _check_views(view_cameras: Sequence[Camera]) -> None:
    if len(view_cameras) == 0:
        raise ValueError("distill: no view cameras given; pass the cameras to be rendered")


def enhance_views(
    gaussians: Gaussians,
    images: Tensor,
    cameras: Sequence[Camera],
    view_cameras: Sequence[Camera],
    improver,
    *,
    enhance_options: EnhanceOptions | None = None,
    dtype: torch.dtype = torch.float32,
    progress: Callable[[int, int], None] | None = None,
) -> Tensor:
    """Every view of ``view_cameras`` rendered and enhanced on its own (what distilling fits),
    at the inputs' size: [T,3,H,W] (a guarded view is its raw render). ``progress(k, T)`` is
    called before view k."""
    if improver is None:
        raise ValueError("distill: needs an improvement model (stage 2) to enhance the views")
    _check_views(view_cameras)
    height, width = images.shape[-2:]
    out = []
    for k, cam in enumerate(view_cameras):
        if progress is not None:
            progress(k, len(view_cameras))
        view = render_view(
            gaussians, cam, images, cameras, improver, dtype=dtype, options=enhance_options
        )
        out.append(_at_input_size(view.image.clamp(0, 1), cam, height, width, k)[0])
    return torch.stack(out).to(images.dtype)


def distill(
    gaussians: Gaussians,
    images: Tensor,
    cameras: Sequence[Camera],
    views: Tensor,
    view_cameras: Sequence[Camera],
    *,
    steps: int | None = None,
    seconds: float | None = None,
    seed: int = 0,
    progress: Callable[[int, int | None, float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    options: RefineOptions | None = None,
    seed_holes: bool = True,
) -> RefineResult:
    """Refine ``gaussians`` against the inputs and ``views`` together.

    Args:
        gaussians: the scene (the generator's, pruned, or refined).
        images: [N,3,H,W] the input photographs in [0, 1]; ``cameras`` their N cameras.
        views: [T,3,h,w] what the Gaussians should show at ``view_cameras`` (the enhanced
            views, :func:`enhance_views`); views of another resolution than the inputs are
            fitted at the inputs' size (same aspect ratio).
        steps / seconds: the refinement's length, at most one (neither:
            :data:`DEFAULT_DISTILL_STEPS`); ``seed``, ``progress``, ``cancel``, ``options``:
            as :func:`prosplat.pipeline.refine.refine`.
        seed_holes: first give every pixel of the inputs and views that ``gaussians`` leave
            uncovered a Gaussian of its own (:func:`prosplat.geometry.hole_gaussians.hole_gaussians`),
            so the fit can show what the views show there; refinement never adds Gaussians,
            and the generator leaves holes even in its own input views. The result then
            holds more Gaussians than ``gaussians``.
    Raises:
        ValueError: no views, views and cameras that do not pair up, a view of another
            aspect ratio, or what :func:`prosplat.pipeline.refine.refine` refuses.
    """
    view_cameras = list(view_cameras)
    _check_views(view_cameras)
    if views.ndim != 4 or views.shape[0] != len(view_cameras):
        raise ValueError(
            f"distill: views must be [T,3,H,W] with one image per view camera; got "
            f"{list(views.shape)} for {len(view_cameras)} cameras"
        )
    if steps is None and seconds is None:
        steps = DEFAULT_DISTILL_STEPS
    height, width = images.shape[-2:]
    fitted = [
        _at_input_size(v, c, height, width, k) for k, (v, c) in enumerate(zip(views, view_cameras))
    ]
    targets = torch.cat([images, torch.stack([v for v, _ in fitted]).to(images)])  # [N+T,3,H,W]
    target_cameras = list(cameras) + [c for _, c in fitted]
    if seed_holes:  # not where the views show the background the fit composites over
        background = None if options is None else options.background
        gaussians = hole_gaussians(gaussians, targets, target_cameras, background=background)
    return refine(
        gaussians,
        targets,
        target_cameras,
        steps=steps,
        seconds=seconds,
        seed=seed,
        progress=progress,
        cancel=cancel,
        options=options,
    )


def distill_enhanced(
    gaussians: Gaussians,
    images: Tensor,
    cameras: Sequence[Camera],
    view_cameras: Sequence[Camera],
    improver,
    *,
    steps: int | None = None,
    seconds: float | None = None,
    seed: int = 0,
    progress: Callable[[int, int | None, float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    refine_options: RefineOptions | None = None,
    enhance_options: EnhanceOptions | None = None,
    dtype: torch.dtype = torch.float32,
) -> DistillResult:
    """:func:`enhance_views` then :func:`distill`: the Gaussians that show ``view_cameras``
    as stage 2 enhances them, consistently. Render the result's ``gaussians`` at the view
    cameras raw (their consistency is the point); arguments as those two functions'."""
    t0 = time.perf_counter()
    enhanced = enhance_views(
        gaussians, images, cameras, view_cameras, improver,
        enhance_options=enhance_options, dtype=dtype,
    )  # fmt: skip
    enhance_s = time.perf_counter() - t0
    result = distill(
        gaussians, images, cameras, enhanced, view_cameras, steps=steps, seconds=seconds,
        seed=seed, progress=progress, cancel=cancel, options=refine_options,
    )  # fmt: skip
    return DistillResult(result.gaussians, enhanced, result.stats, enhance_s)
