"""The optional CUDA backend: gsplat's ``rasterization`` with our semantics.

gsplat follows the same classic 3DGS rules (0.3 px² dilation, 1.3x FOV Jacobian clamp,
1/255 skip, 1e-4 transmittance stop, near plane 0.01, pixel centres at +0.5). One known
difference: gsplat culls with a 3σ radius, where our CPU path uses an opacity-aware radius
that never drops a sample above 1/255, so very opaque Gaussians may differ in a thin rim.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.render.output import RenderOutput
from prosplat.render.projection import NEAR_PLANE


def _rasterize(gaussians: Gaussians, cameras: Sequence[Camera], bg: Tensor):
    """gsplat's ``rasterization`` for cameras of one size with our settings: rgb [C,3,H,W]
    over ``bg``, alpha [C,H,W], depth [C,H,W] (0 where nothing was drawn) and gsplat's meta."""
    from gsplat import rasterization

    if gaussians.dtype != torch.float32:
        raise ValueError(
            "the gsplat backend renders float32 Gaussians only; call .to(dtype=torch.float32)"
        )
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1:
        raise ValueError(f"the gsplat backend renders cameras of one size, got {sorted(sizes)}")
    (width, height), device = sizes.pop(), gaussians.device
    viewmats = torch.stack([c.world_to_cam for c in cameras]).to(device, torch.float32)
    Ks = torch.stack([c.K for c in cameras]).to(device, torch.float32)  # [C,3,3]
    colors, alphas, meta = rasterization(
        gaussians.means,
        gaussians.quats,
        gaussians.scales,
        gaussians.opacities,
        gaussians.sh,
        viewmats,
        Ks,
        width,
        height,
        near_plane=NEAR_PLANE,
        eps2d=0.3,
        sh_degree=gaussians.sh_degree,
        packed=False,
        render_mode="RGB+ED",
        rasterize_mode="classic",
    )  # colors [C,H,W,4], alphas [C,H,W,1]
    alpha = alphas[..., 0]
    rgb = colors[..., :3].permute(0, 3, 1, 2) + (1 - alpha)[:, None] * bg[None, :, None, None]
    depth = torch.where(alpha > 0, colors[..., 3], torch.zeros_like(alpha))
    return rgb, alpha, depth, meta


def render_gsplat(gaussians: Gaussians, camera: Camera, bg: Tensor):

    rgb, alpha, depth, meta = _rasterize(gaussians, [camera], bg)
    visible = (meta["radii"][0] > 0).reshape(len(gaussians), -1).any(dim=1)
    return RenderOutput(rgb=rgb[0], alpha=alpha[0], depth=depth[0], visible=visible)


def render_gsplat_views(
    gaussians: Gaussians, cameras: Sequence[Camera], bg: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Several cameras of one size in one ``rasterization`` call.

    gsplat takes a batch of view matrices and intrinsics, so a training step that renders
    every target and input camera of a scene launches one kernel sequence instead of one
    per camera: per-camera launches and Python, not the GPU, bounded the first GPU run's
    step (BENCHMARKS "Generator v2: the first GPU run").

    Returns rgb [C,3,H,W] over ``bg``, alpha [C,H,W], depth [C,H,W] (0 where nothing was
    drawn), the same numbers :func:`render_gsplat` gives camera by camera.
    """
    return _rasterize(gaussians, cameras, bg)[:3]
