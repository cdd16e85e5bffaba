"""Ground-truth geometry for the ladder: the true-depth upper bound and the valid regions.

Blender gives the exact depth of every pixel, so two things a real capture can only estimate
are exact here:

* :func:`true_depth_gaussians`: what a pixel-aligned generator would emit if its depth were
  perfect. Every input pixel with depth becomes one Gaussian at its surface point, coloured
  with the pixel, sized to the pixel's footprint, opaque. Rendering it is the ceiling of
  "predict depth, splat the input pixels", the recipe stage 1 follows.
* :func:`valid_mask`: the target pixels whose surface at least one input sees (the paper's
  "valid regions"). Pixels outside it can only be guessed, by any method; scoring inside it
  separates "wrong geometry" from "nothing to copy from".
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.geometry.pixel_gaussians import pixel_gaussians

#: a true-depth Gaussian's standard deviation in units of its pixel's footprint
#: (depth / min(fx, fy), :func:`prosplat.geometry.pixel_gaussians.pixel_gaussians`).
#: Small enough not to smear the input's own view (the rasterizer adds 0.3 px² anyway), large
#: enough to close gaps where a target sees a surface closer than an input did. Measured on
#: two test scenes at 64 px (valid-region PSNR over the targets, open / room): 0.2 → 20.3 /
#: 19.0 dB, 0.35 → 21.9 / 19.2, 0.5 → 21.4 / 19.1, 0.7 → 19.8 / 18.7, 1.0 → 17.8 / 18.0.
FOOTPRINT_SIGMA = 0.35
#: opacity of a true-depth Gaussian ("~1": alpha saturates at 0.99 anyway)
TRUE_DEPTH_OPACITY = 1.0
#: relative depth slack of the visibility test: a point counts as seen by an input when its
#: depth there is at most (1 + tol) x the input's depth at that pixel (not hidden behind it)
VISIBILITY_TOL = 0.05
#: sky pixels (depth 0) are tested as points this many times farther than the scene's far
SKY_DISTANCE = 1e4
#: true-depth sky Gaussians sit at this many times the farthest input depth (far enough that
#: the parallax between inputs is a fraction of a pixel, near enough for float32)
SKY_DEPTH_FACTOR = 20.0


def resize_depths(depths: Tensor, width: int, height: int) -> Tensor:
    """[V,H,W] depth maps -> [V,height,width] by nearest sampling at the new pixel centres.

    Nearest, not an average: averaging across an object's silhouette invents a depth between
    the object and the wall that no surface has (and mixes sky's 0 into real depths).
    """
    if tuple(depths.shape[-2:]) == (height, width):
        return depths
    out = F.interpolate(depths[:, None].float(), size=(height, width), mode="nearest-exact")
    return out[:, 0]


def true_depth_gaussians(
    images: Tensor, depths: Tensor, cameras: Sequence[Camera], part: str = "all"
) -> Gaussians:
    """One Gaussian per input pixel, at the pixel's true surface point.

    Args:
        images: [V,3,H,W] input images in [0, 1].
        depths: [V,H,W] their z-depths along the optical axis (0 = no surface: sky).
        cameras: V cameras of size W x H.
        part: "all" (every pixel; sky pixels at ``SKY_DEPTH_FACTOR`` x the farthest input
            depth), "surface" (pixels with depth only) or "sky" (the sky pixels only).
    Returns:
        Gaussians (float32, SH degree 0): means [N,3] on the surfaces, colour = the pixel's,
        isotropic scale ``FOOTPRINT_SIGMA * depth / min(fx, fy)``, opacity ``TRUE_DEPTH_OPACITY``;
        N = the number of pixels in ``part``.
    """
    if images.ndim != 4 or depths.shape != (images.shape[0], *images.shape[-2:]):
        raise ValueError(
            f"true_depth_gaussians: images [V,3,H,W] and depths [V,H,W] must match, got "
            f"{list(images.shape)} and {list(depths.shape)}"
        )
    if len(cameras) != images.shape[0]:
        raise ValueError(f"true_depth_gaussians: {len(cameras)} cameras for {len(images)} images")
    if part not in ("all", "surface", "sky"):
        raise ValueError(f"true_depth_gaussians: part must be all, surface or sky, got {part!r}")
    surface = depths[depths > 0]
    sky_depth = SKY_DEPTH_FACTOR * float(surface.max()) if surface.numel() else 1.0
    parts = []
    for image, depth, cam in zip(images, depths, cameras):
        d = depth.to(torch.float64)  # [H,W] float64: sky depths are far for float32 means
        if part == "sky":
            d = torch.where(d > 0, torch.zeros_like(d), torch.full_like(d, sky_depth))
        elif part == "all":
            d = torch.where(d > 0, d, torch.full_like(d, sky_depth))
        parts.append(pixel_gaussians(image, d, cam, FOOTPRINT_SIGMA, TRUE_DEPTH_OPACITY))
    return Gaussians.cat(parts).to(dtype=torch.float32)


def valid_mask(
    target: Camera,
    target_depth: Tensor,
    inputs: Sequence[Camera],
    input_depths: Tensor,
    tol: float = VISIBILITY_TOL,
) -> Tensor:
    """[H,W] bool: target pixels whose surface point at least one input sees.

    A target pixel with depth is lifted to its surface point and projected into every input
    (nearest pixel); input j sees it when it lands inside j's frame, in front of j, on a pixel
    where j has a surface, and not behind that surface: ``z_j <= (1 + tol) * depth_j``.
    A sky pixel (depth 0) is seen when its direction, taken as a point far beyond the scene,
    lands on a sky pixel of some input. All maps must match their cameras' sizes.

    Args:
        target: the target camera, W x H.
        target_depth: [H,W] its z-depth (0 = sky).
        inputs: V input cameras.
        input_depths: [V,H',W'] their z-depths (0 = sky), each at its camera's size.
        tol: relative depth slack of the occlusion test (nearest-pixel lookups on slanted
            surfaces need some).
    """
    if tuple(target_depth.shape) != (target.height, target.width):
        raise ValueError(
            f"valid_mask: target_depth is {list(target_depth.shape)}, the camera "
            f"{target.width}x{target.height}"
        )
    if input_depths.ndim != 3 or input_depths.shape[0] != len(inputs):
        raise ValueError(
            f"valid_mask: input_depths must be [V={len(inputs)},H,W], got {list(input_depths.shape)}"
        )
    cam_t = target.to(dtype=torch.float64)
    d = target_depth.to(torch.float64)
    surface = d > 0  # [H,W]
    uv = cam_t.pixel_centers(torch.float64).reshape(-1, 2)  # [HW,2]
    finite = input_depths[input_depths > 0]
    far = float(finite.max()) if finite.numel() else 1.0
    z = torch.where(surface, d, torch.full_like(d, SKY_DISTANCE * far)).reshape(-1)  # [HW]
    points = cam_t.unproject(uv, z)  # [HW,3]
    seen = torch.zeros(len(points), dtype=torch.bool)
    flat_surface = surface.reshape(-1)
    for cam, dep in zip(inputs, input_depths):
        col, row, zj, inside = cam.to(dtype=torch.float64).nearest_pixels(points)  # [HW] each
        dj = dep.to(torch.float64)[row, col]  # [HW]
        hit_surface = flat_surface & (dj > 0) & (zj <= (1.0 + tol) * dj)
        hit_sky = ~flat_surface & (dj <= 0)
        seen |= inside & (hit_surface | hit_sky)
    return seen.reshape(d.shape)
