"""Gaussians for the pixels a set of Gaussians leaves uncovered in views whose images are known.

The generator places Gaussians only where its inputs looked, and since v16 it leaves even
parts of its own input views empty (the sky, what lies beyond the scene: BENCHMARKS
"Generator v16a"), because the pipeline's filled and enhanced views paint those parts better
than Gaussians at a guessed depth. Refinement never adds Gaussians, so when the Gaussians are
fitted to views whose whole image is known (:mod:`prosplat.distill`: the input photographs and
the enhanced views), those pixels stay black in every render of the fit and the fit cannot
reproduce them.

:func:`hole_gaussians` gives each such pixel a Gaussian of its own before the fit: on its
view's ray, at the depth the covered pixels around it continue to (the pull-push fill of the
rendered depth, :func:`prosplat.render.hole_fill.fill_colour`), the pixel's colour, one
pixel's footprint wide. Views are visited in order and each is rendered with the Gaussians
added for the views before it, so a part two views both miss is seeded once.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from prosplat.camera import Camera
from prosplat.gaussians import Gaussians
from prosplat.render import render
from prosplat.render.hole_fill import fill_colour

__all__ = ["HOLE_ALPHA", "hole_gaussians"]

#: A pixel whose render alpha is below this is a hole: what covers it is mostly background.
HOLE_ALPHA = 0.5

#: A seeded Gaussian's scale in pixel footprints (depth / focal length), about what the
#: generator's adapter predicts for its own pixels, so neighbours blend without gaps.
FOOTPRINT = 0.7

#: A seeded Gaussian's opacity: opaque enough to cover its pixel, below 1 so that the fit's
#: opacity gradient is not saturated.
OPACITY = 0.9


def _hole_depth(depth: Tensor, alpha: Tensor) -> Tensor:
    """[H,W] the depth a hole pixel's Gaussian is placed at: the covered pixels' depth
    continued into the hole by pull-push (0 where the view covers nothing)."""
    premultiplied = (depth * alpha).expand(3, -1, -1)  # [3,H,W]
    return fill_colour(premultiplied, alpha)[0]


@torch.no_grad()
def hole_gaussians(
    gaussians: Gaussians,
    images: Tensor,
    cameras: Sequence[Camera],
    *,
    hole_alpha: float = HOLE_ALPHA,
) -> Gaussians:
    """``gaussians`` and one new Gaussian per hole pixel of each view.

    Args:
        gaussians: the scene.
        images: [V,3,H,W] what each view shows, in [0, 1] (photographs, enhanced views).
        cameras: one W x H camera per image.
        hole_alpha: pixels rendered with alpha below it are holes (:data:`HOLE_ALPHA`).

    Returns:
        The input Gaussians first, unchanged, then the new ones (SH of the input's degree,
        view-independent colour). Holes with no covered pixel anywhere in their view (a view
        that sees nothing) get none: there is no depth to continue.
    """
    if images.ndim != 4 or images.shape[1] != 3 or images.shape[0] != len(cameras):
        raise ValueError(
            f"hole_gaussians: images must be [V,3,H,W] with one camera each, got "
            f"{list(images.shape)} for {len(cameras)} cameras"
        )
    dtype, device = gaussians.means.dtype, gaussians.means.device
    scene = gaussians
    for image, cam in zip(images, cameras):
        if (cam.height, cam.width) != tuple(image.shape[-2:]):
            raise ValueError(
                f"hole_gaussians: a {cam.width}x{cam.height} camera for an image of "
                f"{image.shape[-1]}x{image.shape[-2]}"
            )
        out = render(scene, cam)
        hole = out.alpha < hole_alpha  # [H,W]
        if not bool(hole.any()):
            continue
        depth = _hole_depth(out.depth, out.alpha)  # [H,W]
        seed = hole & (depth > 0)
        if not bool(seed.any()):
            continue
        uv = cam.pixel_centers(dtype).to(device)[seed]  # [K,2]
        z = depth[seed].to(dtype)  # [K]
        means = cam.to(device).unproject(uv, z)  # [K,3]
        scales = (FOOTPRINT * z / cam.fx)[:, None].expand(-1, 3).contiguous()  # [K,3]
        colors = image.to(device=device, dtype=dtype)[:, seed].T.clamp(0, 1)  # [K,3]
        opacities = torch.full_like(z, OPACITY)
        new = Gaussians.from_colors(means, colors, scales, opacities, sh_degree=scene.sh_degree)
        scene = Gaussians.cat([scene, new])
    return scene
