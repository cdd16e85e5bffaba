"""Classical plane-sweep stereo turned into pixel-aligned Gaussians: the no-learning baseline.

For every reference view, fronto-parallel planes at ``n_depths`` depths (uniform in inverse
depth, so the candidates are evenly spaced in disparity) are swept through the scene; the
other views are warped onto each plane with ``grid_sample`` and compared with the reference
by zero-mean normalised cross-correlation (ZNCC) over a 5x5 window. ZNCC is invariant to
gain and offset between views, so it needs no photometric calibration, and it is zero (not
random) on flat patches, which keeps textureless regions at low confidence. Because it
ignores absolute colour, the cost adds ``COLOR_WEIGHT`` x the mean absolute difference of the
two windows' mean colours (on the demo scene this stops beige wall checks matching blue floor
checks). The winner takes all, a parabola through the best cost and its two neighbours gives a sub-candidate
depth, and the margin to the best non-adjacent candidate gives the confidence.

Each pixel then becomes one Gaussian laid out exactly like the feed-forward generator's
output (view-major, then row-major), so the two can be compared Gaussian for Gaussian and
pruned with :func:`prosplat.geometry.budget.prune_gaussians`:

- mean: the pixel centre unprojected at its depth;
- colour: the pixel's colour as the DC SH coefficient (degree 0);
- scale: ``LATERAL_SCALE`` (0.7) pixel footprints across the ray, so that neighbours overlap
  into a hole-free surface, and ``RAY_SCALE`` (0.1) footprints along it (a surfel facing its
  camera: thin so that depth errors do not smear colour along the ray);
- rotation: the Gaussian's thin axis along the pixel's ray (not just the optical axis);
- opacity: ``min_opacity + (max_opacity - min_opacity) * confidence``, so an unreliable depth
  still paints its colour but is easy to overrule (or prune).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians, rgb_to_sh0
from prosplat.core.rotations import quat_multiply, rotmat_to_qvec
from prosplat.geometry.matching import (
    check_inputs,
    depth_candidates,
    winner_take_all_depth,
    zncc_cost,
)

__all__ = ["gaussians_from_depths", "plane_sweep_depths", "plane_sweep_gaussians"]

LATERAL_SCALE = 0.7  # σ across the ray, in pixel footprints (depth / fx)
RAY_SCALE = 0.1  # σ along the ray, in pixel footprints


@torch.no_grad()
def plane_sweep_depths(
    images: Tensor, cameras: list[Camera], near: float, far: float, n_depths: int = 64
) -> tuple[Tensor, Tensor]:
    """Depth [V,H,W] (z along each optical axis) and confidence [V,H,W] in [0, 1] per view.

    A single view (nothing to match) or coincident cameras give a flat cost curve: every pixel
    gets confidence 0 and the nearest candidate depth, which is finite.
    """
    check_inputs(images, cameras, near, far)
    if int(n_depths) != n_depths or n_depths < 2:
        raise ValueError(f"n_depths must be an integer >= 2, got {n_depths}")
    depths_c = depth_candidates(near, far, int(n_depths), images.dtype, images.device)
    out_d, out_c = [], []
    for ref in range(images.shape[0]):
        cost = zncc_cost(images, cameras, ref, depths_c)
        depth, conf = winner_take_all_depth(cost, near, far)
        out_d.append(depth)
        out_c.append(conf)
    return torch.stack(out_d), torch.stack(out_c)


def _ray_quats(camera: Camera) -> Tensor:
    """[H*W, 4] rotations taking a Gaussian's local z axis onto each pixel's ray (world).

    In camera space the shortest rotation from (0,0,1) to the unit ray r is the quaternion
    (1 + r_z, -r_y, r_x, 0), normalised; it is never zero because r_z > 0 for a pinhole.
    Composing with the camera-to-world rotation gives the world rotation.
    """
    uv = camera.pixel_centers(torch.float64).reshape(-1, 2)
    K = camera.K.to(torch.float64)
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    r = F.normalize(torch.stack([x, y, torch.ones_like(x)], -1), dim=-1)
    q_local = F.normalize(
        torch.stack([1 + r[:, 2], -r[:, 1], r[:, 0], torch.zeros_like(x)], -1), dim=-1
    )
    q_c2w = rotmat_to_qvec(camera.R.to(torch.float64).T.cpu()).to(q_local.device)
    return quat_multiply(q_c2w.expand_as(q_local), q_local)


def gaussians_from_depths(
    images: Tensor,
    cameras: list[Camera],
    depths: Tensor,
    confidence: Tensor,
    min_opacity: float = 0.2,
    max_opacity: float = 0.95,
) -> Gaussians:
    """One surfel-like Gaussian per pixel (view-major, row-major) from depth and confidence.

    Args:
        images: [V,3,H,W] colours in [0, 1]; cameras: V cameras of size W x H.
        depths: [V,H,W] z-depth per pixel (> 0); confidence: [V,H,W] in [0, 1].
        min_opacity, max_opacity: opacity at confidence 0 and 1.
    """
    v, _, h, w = images.shape
    means, scales, quats = [], [], []
    for i, cam in enumerate(cameras):
        z = depths[i].to(torch.float64)
        uv = cam.pixel_centers(torch.float64).to(z.device)
        means.append(cam.unproject(uv, z).reshape(-1, 3))
        foot = (z / cam.fx).reshape(-1, 1)
        scales.append(foot * foot.new_tensor([[LATERAL_SCALE, LATERAL_SCALE, RAY_SCALE]]))
        quats.append(_ray_quats(cam).to(z.device))
    dtype = images.dtype
    colors = images.permute(0, 2, 3, 1).reshape(-1, 3).clamp(0, 1)
    opac = min_opacity + (max_opacity - min_opacity) * confidence.reshape(-1).clamp(0, 1)
    sh = rgb_to_sh0(colors)[:, None, :]  # [N,1,3]
    return Gaussians(
        torch.cat(means).to(dtype),
        torch.cat(quats).to(dtype),
        torch.cat(scales).to(dtype),
        opac.to(dtype),
        sh.to(dtype),
    )


@torch.no_grad()
def plane_sweep_gaussians(
    images: Tensor,
    cameras: list[Camera],
    near: float,
    far: float,
    n_depths: int = 64,
) -> tuple[Gaussians, Tensor, Tensor]:
    """Plane-sweep stereo on ``images`` and one Gaussian per input pixel.

    Args:
        images: [V,3,H,W] float images in [0, 1] (V >= 2 for any depth information).
        cameras: V cameras, each W x H.
        near, far: the depth range to sweep (scene units, 0 < near < far).
        n_depths: number of depth candidates D (cost memory and time grow linearly with it).

    Returns:
        gaussians: N = V*H*W Gaussians, view-major then row-major (the generator's layout);
        depths: [V,H,W] z-depth each pixel was unprojected at;
        confidence: [V,H,W] in [0, 1].
    """
    depths, conf = plane_sweep_depths(images, cameras, near, far, n_depths)
    return gaussians_from_depths(images, cameras, depths, conf), depths, conf
