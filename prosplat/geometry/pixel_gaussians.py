"""One Gaussian per pixel of an image, at a given depth along its ray.

Two places build a scene this way and must agree on what "a pixel's Gaussian" is:

* :func:`prosplat.eval.ladder.geometry.true_depth_gaussians`, the ladder's upper bound: every input
  pixel at Blender's true depth;
* :func:`prosplat.geometry.hole_gaussians.hole_gaussians`: the pixels a scene leaves uncovered, on a
  backdrop behind what the view sees.

Each Gaussian sits on its pixel centre's ray at the pixel's depth, takes the pixel's colour
(view-independent), is isotropic with a standard deviation of ``footprint`` pixel widths at
that depth (``footprint * depth / min(fx, fy)``), identity rotation. The plane-sweep baseline
builds ray-aligned surfels with a confidence opacity instead
(:func:`prosplat.eval.baselines.plane_sweep.gaussians_from_depths`), a different model.
"""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians

__all__ = ["pixel_gaussians"]


def pixel_gaussians(
    image: Tensor,
    depth: Tensor,
    camera: Camera,
    footprint: float,
    opacity: float,
    sh_degree: int = 0,
) -> Gaussians:
    """One Gaussian per pixel of ``image`` whose ``depth`` is > 0, in row-major order.

    Args:
        image: [3,H,W] colours in [0, 1] (clamped).
        depth: [H,W] z-depth along the optical axis per pixel; 0 (or below): no Gaussian.
            The Gaussians take its dtype and device, so a float64 depth gives float64 means.
        camera: the W x H camera the image was seen from.
        footprint: the standard deviation in pixel widths at the pixel's depth.
        opacity: every Gaussian's opacity.
        sh_degree: SH degree of the result (higher bands zero).

    Returns:
        Gaussians, N = the number of pixels with depth > 0.
    """
    if image.ndim != 3 or image.shape[0] != 3 or image.shape[1:] != depth.shape:
        raise ValueError(
            f"pixel_gaussians: image [3,H,W] and depth [H,W] must match, got "
            f"{list(image.shape)} and {list(depth.shape)}"
        )
    if (camera.height, camera.width) != tuple(depth.shape):
        raise ValueError(
            f"pixel_gaussians: a {camera.width}x{camera.height} camera for a "
            f"{depth.shape[-1]}x{depth.shape[-2]} depth map"
        )
    dtype, device = depth.dtype, depth.device
    cam = camera.to(device=device, dtype=dtype)
    ok = depth > 0  # [H,W]
    z = depth[ok]  # [N]
    means = cam.unproject(cam.pixel_centers(dtype)[ok], z)  # [N,3]
    scales = (footprint * z / min(cam.fx, cam.fy))[:, None].expand(-1, 3).contiguous()  # [N,3]
    colors = image.to(device=device, dtype=dtype).permute(1, 2, 0)[ok].clamp(0, 1)  # [N,3]
    opacities = torch.full_like(z, opacity)  # [N]
    return Gaussians.from_colors(means, colors, scales, opacities, sh_degree=sh_degree)


def slide_gaussians(
    gaussians: Gaussians, view_index: Tensor, cameras: list[Camera], factor: float | Tensor
) -> Gaussians:
    """``gaussians`` (``view_index [N]``: the input view that predicted each) slid along their
    rays to ``factor`` x their depth: means scaled about their own camera's centre, scales
    by the same factor, so each still covers its footprint in its own view. ``factor`` may be
    a one-element tensor that needs a gradient (refinement fits it: ``RefineOptions
    .ray_scale_lr``); a float 1 returns ``gaussians`` as they are."""
    if not isinstance(factor, Tensor) and factor == 1.0:
        return gaussians
    centres = torch.stack([c.center for c in cameras]).to(gaussians.means)  # [V,3]
    c = centres[view_index.to(centres.device)]  # [N,3]
    means = c + factor * (gaussians.means - c)
    g = gaussians
    return Gaussians(means, g.quats, g.scales * factor, g.opacities, g.sh, g.views)
