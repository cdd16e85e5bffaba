"""The reference view warped into the target camera through the rendered depth.

Stage 2 sees the MORI reference only at its 4x4 bottleneck (DWEA), where a texture cannot
land on the pixel it belongs to. Warping puts it there: every target pixel the Gaussians
cover is lifted to 3D with the rendered depth, projected into the reference camera and
sampled from the reference image. Where the depth is right this is the input photograph's
own texture, sharp; where the target pixel is hidden from the reference (its depth there,
rendered from the same Gaussians, is nearer), outside the reference's frame, or not covered,
the warp is marked invalid. The generator issue's "paste" baseline is this warp with an
infinitely distant plane; the ladder's ``warp paste`` rung measures it with real depth.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.render import render

#: A target pixel's point is visible to the reference when its depth there is within this
#: fraction of the reference's own rendered depth (soft surfaces of Gaussians blur depth).
OCCLUSION_TOLERANCE = 0.05


def warp_reference(
    reference: Tensor,
    reference_camera: Camera,
    target_camera: Camera,
    target_depth: Tensor,
    target_alpha: Tensor | None = None,
    reference_depth: Tensor | None = None,
    tolerance: float = OCCLUSION_TOLERANCE,
) -> tuple[Tensor, Tensor]:
    """Warp ``reference`` [3,h,w] into ``target_camera`` through ``target_depth`` [H,W].

    Args:
        reference: [3,h,w] the reference image (at ``reference_camera``'s size).
        reference_camera, target_camera: pinhole cameras; sizes may differ.
        target_depth: [H,W] z along the target's optical axis (rendered; <= 0 where empty).
        target_alpha: [H,W] coverage of the render; pixels under 0.5 are invalid.
        reference_depth: [h,w] z-depth rendered at the reference camera, for the occlusion
            test (None: no test, every projected pixel counts as visible).
        tolerance: relative depth difference still counted as the same surface.
    Returns:
        warped [3,H,W] (bilinear; border colour where invalid) and valid [H,W] bool.
    """
    h, w = reference.shape[-2:]
    H, W = target_depth.shape
    if (target_camera.height, target_camera.width) != (H, W):
        raise ValueError(
            f"warp_reference: target_depth is {W}x{H} but the target camera is "
            f"{target_camera.width}x{target_camera.height}"
        )
    if (reference_camera.height, reference_camera.width) != (h, w):
        raise ValueError(
            f"warp_reference: the reference image is {w}x{h} but its camera is "
            f"{reference_camera.width}x{reference_camera.height}"
        )
    f64 = torch.float64  # camera maths in float64: poses far from the origin lose pixels in f32
    uv = target_camera.pixel_centers(f64)  # [H,W,2]
    depth = target_depth.to(f64)
    points = target_camera.unproject(uv, depth)  # [H,W,3] world
    uv_ref, z_ref = reference_camera.project(points)  # [H,W,2], [H,W]
    valid = (depth > 0) & (z_ref > 0)
    valid &= (uv_ref[..., 0] >= 0) & (uv_ref[..., 0] <= w) & (uv_ref[..., 1] >= 0)
    valid &= uv_ref[..., 1] <= h
    if target_alpha is not None:
        valid &= target_alpha > 0.5
    # grid_sample, align_corners=False: -1 and 1 are the outer edges of the border pixels
    grid = torch.stack([uv_ref[..., 0] / w * 2 - 1, uv_ref[..., 1] / h * 2 - 1], dim=-1)
    grid = grid.clamp(-2, 2).to(reference.dtype)[None]  # [1,H,W,2]; clamp keeps f32 finite
    warped = F.grid_sample(
        reference[None], grid, mode="bilinear", padding_mode="border", align_corners=False
    )[0]  # [3,H,W]
    if reference_depth is not None:
        seen = F.grid_sample(
            reference_depth[None, None].to(reference.dtype),
            grid,
            mode="nearest",
            padding_mode="border",
            align_corners=False,
        )[0, 0].to(f64)  # [H,W] the reference's own depth where the point lands
        valid &= (seen > 0) & ((z_ref - seen).abs() <= tolerance * seen)
    return warped, valid


def reference_warp(
    gaussians,
    target_camera: Camera,
    target_depth: Tensor,
    target_alpha: Tensor,
    reference: Tensor,
    reference_camera: Camera,
    reference_depth: Tensor | None = None,
) -> Tensor:
    """Stage 2's warp input [4,H,W]: the reference warped into the target through the depth
    the Gaussians render there (RGB, border colour where invalid) and its validity (0/1).

    The occlusion test uses the same Gaussians' depth rendered at ``reference_camera`` (at the
    reference image's size): one more render per view, unless the caller passes that depth
    ``[h,w]`` (``reference_depth``), as curation does for the targets that share a reference.
    """

    with torch.no_grad():
        if reference_depth is None:
            reference_depth = render(gaussians, reference_camera).depth  # [h,w]
        warped, valid = warp_reference(
            reference, reference_camera, target_camera, target_depth, target_alpha,
            reference_depth,
        )  # fmt: skip
    return torch.cat([warped, valid[None].to(warped.dtype)])  # [4,H,W]


def warp_for(
    improver,
    gaussians,
    target_camera: Camera,
    target_depth: Tensor,
    target_alpha: Tensor,
    reference: Tensor,
    reference_camera: Camera,
) -> Tensor | None:
    """:func:`reference_warp` when ``improver`` takes it (``config.warp_input``), else None:
    what every caller of :func:`prosplat.pipeline.enhance.enhance` that holds the Gaussians passes as
    its ``warp``."""
    if not improver.config.warp_input:
        return None
    return reference_warp(
        gaussians, target_camera, target_depth, target_alpha, reference, reference_camera
    )
