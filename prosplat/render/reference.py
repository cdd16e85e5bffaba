"""Brute-force twin of ``prosplat.render``: every Gaussian evaluated at every pixel, in torch.

Written from DESIGN.md's rasterizer semantics as directly as possible and independently of
``prosplat/render/projection.py`` (full 3x3 covariances, ``torch.linalg.inv`` for the conic,
no boxes, no tiles), so agreement with the fast path checks the fast path's culling,
binning, compositing and hand-written backward pass. Memory is O(pixels x Gaussians): tiny
scenes only.
"""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.render.sh import sh_to_rgb


def _rotmat(q: Tensor) -> Tensor:
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        [1 - 2 * (y**2 + z**2), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x**2 + z**2), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x**2 + y**2)],
    ]
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def render_reference(g: Gaussians, cam: Camera, background: Tensor | None = None):
    """Returns (rgb [3,H,W], alpha [H,W], depth [H,W]) with the semantics of ``prosplat.render``."""
    dtype = g.means.dtype
    W, H = cam.width, cam.height
    fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
    R, t = cam.R.to(dtype), cam.t.to(dtype)
    bg = (
        torch.zeros(3, dtype=dtype)
        if background is None
        else torch.as_tensor(background, dtype=dtype)
    )

    p = g.means @ R.T + t
    keep = p[:, 2] >= 0.01  # near plane
    p, idx = p[keep], torch.nonzero(keep).squeeze(1)
    order = torch.argsort(p[:, 2].detach(), stable=True)
    p, idx = p[order], idx[order]
    x, y, z = p.unbind(-1)

    # EWA: Jacobian at the mean with x/z, y/z clamped to 1.3x the field of view.
    tanx, tany = W / (2 * fx), H / (2 * fy)
    tx = (x / z).clamp(-(cx / fx + 0.3 * tanx), (W - cx) / fx + 0.3 * tanx) * z
    ty = (y / z).clamp(-(cy / fy + 0.3 * tany), (H - cy) / fy + 0.3 * tany) * z
    zeros = torch.zeros_like(z)
    J = torch.stack(
        [
            torch.stack([fx / z, zeros, -fx * tx / z**2], -1),
            torch.stack([zeros, fy / z, -fy * ty / z**2], -1),
        ],
        -2,
    )  # [M,2,3]
    Rq = _rotmat(g.quats[idx])
    S = torch.diag_embed(g.scales[idx])
    cov3 = Rq @ S @ S @ Rq.transpose(1, 2)
    Wc = R.expand(len(idx), 3, 3)
    cov2 = J @ Wc @ cov3 @ Wc.transpose(1, 2) @ J.transpose(1, 2)
    cov2 = cov2 + 0.3 * torch.eye(2, dtype=dtype)
    conic = torch.linalg.inv(cov2)  # [M,2,2]
    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)  # [M,2]

    if g.sh.shape[1] > 1:
        d = g.means[idx] - cam.center.to(dtype)
        dirs = d / d.norm(dim=-1, keepdim=True)
    else:
        dirs = None
    colors = sh_to_rgb(g.sh[idx], dirs)  # [M,3]

    v, u = torch.meshgrid(
        torch.arange(H, dtype=dtype) + 0.5, torch.arange(W, dtype=dtype) + 0.5, indexing="ij"
    )
    pix = torch.stack([u, v], -1).reshape(-1, 1, 2)  # [P,1,2]
    d = pix - mean2d[None]  # [P,M,2]
    q = torch.einsum("pmi,mij,pmj->pm", d, conic, d)
    alpha = (g.opacities[idx][None] * torch.exp(-0.5 * q)).clamp(max=0.99)
    alpha = torch.where(alpha >= 1 / 255, alpha, torch.zeros_like(alpha))
    # A pixel stops before the sample that would take its transmittance below 1e-4.
    t_after = torch.cumprod(1 - alpha, dim=1)
    alpha = alpha * (t_after >= 1e-4)
    t_before = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1 - alpha[:, :-1]], 1), 1)
    w = alpha * t_before  # [P,M]
    acc = w.sum(1)
    rgb = (w @ colors).T.reshape(3, H, W) + (1 - acc).reshape(1, H, W) * bg[:, None, None]
    a = acc.reshape(H, W)
    dsum = (w @ z).reshape(H, W)
    depth = torch.where(a > 0, dsum / a.clamp_min(1e-6), torch.zeros_like(a))
    return rgb, a, depth
