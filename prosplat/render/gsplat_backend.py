"""The optional CUDA backend: gsplat's ``rasterization`` with our semantics.

gsplat follows the same classic 3DGS rules (0.3 px² dilation, 1.3x FOV Jacobian clamp,
1/255 skip, 1e-4 transmittance stop, near plane 0.01, pixel centres at +0.5). One known
difference: gsplat culls with a 3σ radius, where our CPU path uses an opacity-aware radius
that never drops a sample above 1/255, so very opaque Gaussians may differ in a thin rim.
"""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.camera import Camera
from prosplat.gaussians import Gaussians
from prosplat.render.projection import NEAR_PLANE


def render_gsplat(gaussians: Gaussians, camera: Camera, bg: Tensor):
    from gsplat import rasterization

    from prosplat.render import RenderOutput

    if gaussians.dtype != torch.float32:
        raise ValueError(
            "the gsplat backend renders float32 Gaussians only; call .to(dtype=torch.float32)"
        )
    device = gaussians.device
    viewmat = camera.world_to_cam.to(device=device, dtype=torch.float32)[None]
    K = camera.K.to(device=device, dtype=torch.float32)[None]
    colors, alphas, meta = rasterization(
        gaussians.means,
        gaussians.quats,
        gaussians.scales,
        gaussians.opacities,
        gaussians.sh,
        viewmat,
        K,
        camera.width,
        camera.height,
        near_plane=NEAR_PLANE,
        eps2d=0.3,
        sh_degree=gaussians.sh_degree,
        packed=False,
        render_mode="RGB+ED",
        rasterize_mode="classic",
    )
    alpha = alphas[0, ..., 0]  # [H,W]
    rgb = colors[0, ..., :3].permute(2, 0, 1) + (1 - alpha)[None] * bg[:, None, None]
    depth = torch.where(alpha > 0, colors[0, ..., 3], torch.zeros_like(alpha))
    visible = (meta["radii"][0] > 0).reshape(len(gaussians), -1).any(dim=1)
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth, visible=visible)
