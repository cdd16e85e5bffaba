"""Real spherical harmonics up to degree 3, with the constants and sign convention of 3DGS.

Colour = SH · basis(direction) + 0.5, clamped at 0, so PLY files from other 3DGS tools render
with the same colours here.
"""

from __future__ import annotations

import torch
from torch import Tensor

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Basis values.

    Args:
        degree: 0-3.
        dirs: [..., 3] unit directions (from the camera centre towards the Gaussian).
    Returns:
        [..., (degree+1)^2]
    """
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0-3, got {degree}")
    out = [torch.full_like(dirs[..., 0], C0)]
    if degree >= 1:
        x, y, z = dirs.unbind(-1)
        out += [-C1 * y, C1 * z, -C1 * x]
        if degree >= 2:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            out += [
                C2[0] * xy,
                C2[1] * yz,
                C2[2] * (2 * zz - xx - yy),
                C2[3] * xz,
                C2[4] * (xx - yy),
            ]
            if degree >= 3:
                out += [
                    C3[0] * y * (3 * xx - yy),
                    C3[1] * xy * z,
                    C3[2] * y * (4 * zz - xx - yy),
                    C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
                    C3[4] * x * (4 * zz - xx - yy),
                    C3[5] * z * (xx - yy),
                    C3[6] * x * (xx - 3 * yy),
                ]
    return torch.stack(out, dim=-1)


def sh_to_rgb(sh: Tensor, dirs: Tensor | None) -> Tensor:
    """Colour of each Gaussian seen along ``dirs``.

    Args:
        sh: [N, K, 3] coefficients.
        dirs: [N, 3] unit view directions; ignored (may be None) for degree 0.
    Returns:
        [N, 3] colour, ``max(0, SH·basis + 0.5)``.
    """
    k = sh.shape[1]
    if k == 1:
        rgb = C0 * sh[:, 0]
    else:
        degree = int(round(k**0.5)) - 1
        basis = sh_basis(degree, dirs)  # [N, K]
        rgb = torch.einsum("nk,nkc->nc", basis, sh)
    return (rgb + 0.5).clamp_min(0.0)
