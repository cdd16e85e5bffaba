"""The Gaussian adapter: per-pixel raw parameters + depth -> world-space Gaussians
(means, covariances, SH rotated into world space, opacities), DepthSplat's conventions."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.generator.depthsplat.sh_rotation import rotate_sh

SH_C0 = 0.28209479177387814


def quat_xyzw_to_matrix(q: Tensor, eps: float = 1e-8) -> Tensor:
    """[..., 4] quaternions (x, y, z, w), not necessarily unit -> [..., 3, 3]."""
    x, y, z, w = q.unbind(-1)
    s = 2.0 / ((q * q).sum(-1) + eps)
    m = [
        1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
        s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w),
        s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(m, dim=-1).unflatten(-1, (3, 3))


def gaussians_from_raw(
    raw: Tensor,
    depth: Tensor,
    images: Tensor,
    K_norm: Tensor,
    c2w: Tensor,
    scale_min: float,
    scale_max: float,
    sh_degree: int = 2,
) -> dict[str, Tensor]:
    """raw [B,V,C,H,W] head output (opacity, xy offset, scale, rotation xyzw, SH);
    depth [B,V,H,W]; images [B,V,3,H,W] in [0,1]; K_norm [B,V,3,3]; c2w [B,V,4,4].
    Returns means [B,N,3], covariances [B,N,3,3], harmonics [B,N,3,(d+1)^2], opacities [B,N],
    plus camera-space scales [B,N,3] and rotations [B,N,4] (xyzw); N = V*H*W."""
    b, v, c, h, w = raw.shape
    raw = raw.permute(0, 1, 3, 4, 2)  # [B,V,H,W,C]
    opacity = torch.sigmoid(raw[..., 0])
    offset = torch.sigmoid(raw[..., 1:3])  # [B,V,H,W,2]
    n_sh = (sh_degree + 1) ** 2
    s_raw, q_raw, sh = raw[..., 3:].split((3, 4, 3 * n_sh), dim=-1)
    scales = F.softplus(s_raw - 4.0).clamp(min=scale_min, max=scale_max)
    quats = q_raw / (q_raw.norm(dim=-1, keepdim=True) + 1e-8)
    mask = torch.ones(n_sh, device=raw.device, dtype=raw.dtype)
    for deg in range(1, sh_degree + 1):
        mask[deg**2 : (deg + 1) ** 2] = 0.1 * 0.25**deg
    sh = sh.unflatten(-1, (3, n_sh)) * mask  # [B,V,H,W,3,K]
    rgb = images.permute(0, 1, 3, 4, 2)  # [B,V,H,W,3]
    sh = torch.cat([sh[..., :1] + ((rgb - 0.5) / SH_C0)[..., None], sh[..., 1:]], dim=-1)

    # camera-space covariance R S S^T R^T, then into the world with the camera rotation
    Rq = quat_xyzw_to_matrix(quats)
    M = Rq * scales[..., None, :]  # R @ diag(s)
    cov = M @ M.transpose(-1, -2)
    Rc = c2w[:, :, None, None, :3, :3]  # [B,V,1,1,3,3]
    cov = Rc @ cov @ Rc.transpose(-1, -2)

    # pixel centres (normalised) shifted by the predicted offset, unprojected to z = depth
    ys = (torch.arange(h, device=raw.device, dtype=raw.dtype) + 0.5) / h
    xs = (torch.arange(w, device=raw.device, dtype=raw.dtype) + 0.5) / w
    px = xs.view(1, 1, 1, w) + (offset[..., 0] - 0.5) / w
    py = ys.view(1, 1, h, 1) + (offset[..., 1] - 0.5) / h
    uv1 = torch.stack([px, py, torch.ones_like(px)], dim=-1)  # [B,V,H,W,3]
    Kinv = torch.linalg.inv(K_norm)[:, :, None, None]  # [B,V,1,1,3,3]
    dirs = (Kinv @ uv1[..., None])[..., 0]
    dirs = dirs / dirs[..., 2:]
    dirs_w = (Rc @ dirs[..., None])[..., 0]
    means = c2w[:, :, None, None, :3, 3] + dirs_w * depth[..., None]
    harmonics = rotate_sh(sh, Rc[..., None, :, :])  # [B,V,H,W,3,K]

    def flat(t: Tensor, tail: int) -> Tensor:
        return t.reshape(b, v * h * w, *t.shape[t.dim() - tail :])

    return {
        "means": flat(means, 1),
        "covariances": flat(cov, 2),
        "harmonics": flat(harmonics, 2),
        "opacities": opacity.reshape(b, v * h * w),
        "scales": flat(scales, 1),
        "rotations": flat(quats, 1),
    }
