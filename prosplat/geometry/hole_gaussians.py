"""Gaussians for the pixels a set of Gaussians leaves uncovered in views whose images are known.

The generator places Gaussians only where its inputs looked, and since v16 it leaves even
parts of its own input views empty (the sky, what lies beyond the scene: BENCHMARKS
"Generator v16a"), because the pipeline's filled and enhanced views paint those parts better
than Gaussians at a guessed depth. Refinement never adds Gaussians, so when the Gaussians are
fitted to views whose whole image is known (:mod:`prosplat.pipeline.distill`: the input photographs and
the enhanced views), those pixels stay black in every render of the fit and the fit cannot
reproduce them.

:func:`hole_gaussians` gives each such pixel a Gaussian of its own before the fit: on its
view's ray, with the pixel's colour, one pixel's footprint wide, at the farthest depth the
view's covered pixels reach: a backdrop behind everything that view sees. A hole is mostly
what lies beyond the scene or outside every input's view, and a seed placed there cannot
land in front of a surface another view sees. Placed at the depth the covered pixels around
it continue to (a pull-push fill of the rendered depth), the seeds gained +0.04 dB over the
enhanced views on 12 test scenes where the backdrop gains +0.16: on one tabletop the ground
one view missed lay across another view's sky (BENCHMARKS "Distilled views with generator
v16"). Views are visited in order and each is rendered with the Gaussians added for the
views before it, so a part two views both miss is seeded once.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.geometry.pixel_gaussians import pixel_gaussians
from prosplat.render import render

__all__ = ["BACKGROUND_TOLERANCE", "HOLE_ALPHA", "backdrop_depth", "hole_gaussians"]

#: A pixel whose render alpha is below this is a hole: what covers it is mostly background.
HOLE_ALPHA = 0.5

#: A seeded Gaussian's scale in pixel footprints (depth / focal length), about what the
#: generator's adapter predicts for its own pixels, so neighbours blend without gaps.
FOOTPRINT = 0.7

#: With a background colour, a hole pixel whose image is within this of it in every channel
#: shows the background already and gets no Gaussian (about 5/255).
BACKGROUND_TOLERANCE = 0.02

#: A seeded Gaussian's opacity: opaque enough to cover its pixel, below 1 so that the fit's
#: opacity gradient is not saturated.
OPACITY = 0.9


def backdrop_depth(depth: Tensor, alpha: Tensor, hole_alpha: float = HOLE_ALPHA) -> float | None:
    """The depth a view's hole Gaussians are placed at: the farthest rendered depth among its
    covered pixels (alpha >= ``hole_alpha``), or None when it covers none (no depth to go on).
    ``depth``, ``alpha``: [H,W] from :func:`prosplat.render.render`."""
    covered = alpha >= hole_alpha
    return float(depth[covered].max()) if bool(covered.any()) else None


@torch.no_grad()
def hole_gaussians(
    gaussians: Gaussians,
    images: Tensor,
    cameras: Sequence[Camera],
    *,
    hole_alpha: float = HOLE_ALPHA,
    background: Sequence[float] | Tensor | None = None,
) -> Gaussians:
    """``gaussians`` and one new Gaussian per hole pixel of each view.

    Args:
        gaussians: the scene.
        images: [V,3,H,W] what each view shows, in [0, 1] (photographs, enhanced views).
        cameras: one W x H camera per image.
        hole_alpha: pixels rendered with alpha below it are holes (:data:`HOLE_ALPHA`).
        background: the RGB the images were composited over, if not black (a NeRF-synthetic
            set's white): a hole pixel showing it gets no Gaussian, since the background
            already shows there and a wall of Gaussians in its colour would stand in the
            scene (:data:`BACKGROUND_TOLERANCE`). None: every hole pixel gets one.

    Returns:
        The input Gaussians first, unchanged, then the new ones (SH of the input's degree,
        view-independent colour). A view with no covered pixel at all (one that sees nothing)
        gets none: there is no depth to go on.
    """
    if images.ndim != 4 or images.shape[1] != 3 or images.shape[0] != len(cameras):
        raise ValueError(
            f"hole_gaussians: images must be [V,3,H,W] with one camera each, got "
            f"{list(images.shape)} for {len(cameras)} cameras"
        )
    dtype, device = gaussians.means.dtype, gaussians.means.device
    bg = None if background is None else torch.as_tensor(background, dtype=torch.float32)  # [3]
    scene = gaussians
    for image, cam in zip(images, cameras):
        if (cam.height, cam.width) != tuple(image.shape[-2:]):
            raise ValueError(
                f"hole_gaussians: a {cam.width}x{cam.height} camera for an image of "
                f"{image.shape[-1]}x{image.shape[-2]}"
            )
        out = render(scene, cam)
        hole = out.alpha < hole_alpha  # [H,W]
        if bg is not None:
            shows_bg = ((image.to(bg) - bg[:, None, None]).abs() <= BACKGROUND_TOLERANCE).all(0)
            hole &= ~shows_bg.to(hole.device)
        if not bool(hole.any()):
            continue
        far = backdrop_depth(out.depth, out.alpha, hole_alpha)
        if far is None:
            continue
        depth = torch.zeros(hole.shape, dtype=dtype, device=device).masked_fill_(hole, far)
        new = pixel_gaussians(image, depth, cam, FOOTPRINT, OPACITY, sh_degree=scene.sh_degree)
        scene = Gaussians.cat([scene, new])
    return scene
