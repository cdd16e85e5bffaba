"""EWA projection of 3D Gaussians to screen-space conics, in differentiable torch.

Classic 3DGS semantics (see DESIGN.md): the Jacobian of the perspective map is evaluated at
the mean with x/z, y/z clamped to 1.3x the field of view, the 2D covariance is dilated by
0.3 px², and Gaussians nearer than the 0.01 near plane are culled. Two departures in *how*
(not what) it is computed, both for numerical stability:

- the 2D covariance is formed as ``M Mᵀ`` with ``M = J·W·R·S`` (2x3), and its determinant
  by Cauchy-Binet as ``|M₀ × M₁|² + 0.3·tr(M Mᵀ) + 0.09``, which is positive for needles
  seen edge-on where ``a·c − b²`` cancels catastrophically;
- the math runs in float64 and only the results are cast back, so 1e-12 scales, focal
  lengths of 1e5 px and Gaussians 1e7 away stay finite.

Each Gaussian also gets an inclusive pixel box outside which its alpha is provably below
1/255 (an opacity-aware radius, ``sqrt(2 ln(255·o) λ_max)``), so tile culling never changes
the image: the rasterizer is exactly "skip samples under 1/255".
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from prosplat.camera import Camera
from prosplat.gaussians import Gaussians
from prosplat.render.sh import sh_to_rgb

NEAR_PLANE = 0.01
DILATION = 0.3  # px², added to the 2D covariance diagonal
FOV_CLAMP = 0.3  # the Jacobian is clamped to (1 + FOV_CLAMP) x the field of view
MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
MIN_TRANSMITTANCE = 1e-4


@dataclass
class ProjectedGaussians:
    """Screen-space Gaussians (all in the input dtype).

    means2d [N,2] pixel coords; conics [N,3] (a, b, c) of the inverse 2D covariance
    [[a, b], [b, c]]; depths [N] camera z; colors [N,3]; opacities [N];
    boxes [N,4] int32 inclusive (x0, x1, y0, y1), empty (x0 > x1) when culled; valid [N] bool.
    """

    means2d: Tensor
    conics: Tensor
    depths: Tensor
    colors: Tensor
    opacities: Tensor
    boxes: Tensor
    valid: Tensor


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """[N,4] (w,x,y,z), any non-zero length -> [N,3,3] rotation matrices."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)


def view_directions(means: Tensor, center: Tensor) -> Tensor:
    """[N,3] unit directions from the camera centre to each mean; zero (not NaN) at the centre."""
    d = means - center
    sq = (d * d).sum(-1, keepdim=True)
    ok = sq > 1e-24
    return torch.where(
        ok, d / torch.sqrt(torch.where(ok, sq, torch.ones_like(sq))), torch.zeros_like(d)
    )


def project_gaussians(gaussians: Gaussians, camera: Camera) -> ProjectedGaussians:
    """Project ``gaussians`` into ``camera`` (differentiable w.r.t. every Gaussian parameter)."""
    if camera.K[0, 1] != 0:
        raise ValueError("the rasterizer needs a camera without skew (K[0,1] == 0)")
    out_dtype = gaussians.dtype
    f64 = torch.float64
    means = gaussians.means.to(f64)
    R = camera.R.to(device=means.device, dtype=f64)
    t = camera.t.to(device=means.device, dtype=f64)
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy

    pc = means @ R.T + t  # [N,3] camera space
    z = pc[:, 2]
    in_front = z >= NEAR_PLANE
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    xz, yz = pc[:, 0] / z_safe, pc[:, 1] / z_safe
    means2d = torch.stack([fx * xz + cx, fy * yz + cy], dim=-1)  # [N,2]

    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    xz_c = xz.clamp(-(cx / fx + FOV_CLAMP * tan_x), (W - cx) / fx + FOV_CLAMP * tan_x)
    yz_c = yz.clamp(-(cy / fy + FOV_CLAMP * tan_y), (H - cy) / fy + FOV_CLAMP * tan_y)

    # M = J · R_cam · R_q · diag(s): the 2x3 map whose M Mᵀ is the undilated 2D covariance.
    axes = (
        R @ quat_to_rotmat(gaussians.quats.to(f64)) * gaussians.scales.to(f64)[:, None, :]
    )  # [N,3,3]
    inv_z = 1.0 / z_safe
    row0 = fx * inv_z[:, None] * (axes[:, 0] - xz_c[:, None] * axes[:, 2])  # [N,3]
    row1 = fy * inv_z[:, None] * (axes[:, 1] - yz_c[:, None] * axes[:, 2])  # [N,3]
    a0, c0 = (row0 * row0).sum(-1), (row1 * row1).sum(-1)
    b = (row0 * row1).sum(-1)
    a, c = a0 + DILATION, c0 + DILATION
    cross = torch.linalg.cross(row0, row1)
    det = (cross * cross).sum(-1) + DILATION * (a0 + c0) + DILATION**2
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)  # [N,3]

    opacities = gaussians.opacities
    with torch.no_grad():
        half_diff = 0.5 * (a - c)
        lam_max = 0.5 * (a + c) + torch.sqrt(half_diff * half_diff + b * b)
        o = opacities.detach().to(f64)
        visible_o = o >= MIN_ALPHA
        log_term = torch.log((255.0 * o).clamp_min(1.0))
        radius = torch.sqrt(2.0 * log_term * lam_max) * (1 + 1e-4) + 1e-3
        u, v = means2d[:, 0], means2d[:, 1]
        x0 = torch.ceil(u - radius - 0.5).clamp(0, W)
        x1 = torch.floor(u + radius - 0.5).clamp(-1, W - 1)
        y0 = torch.ceil(v - radius - 0.5).clamp(0, H)
        y1 = torch.floor(v + radius - 0.5).clamp(-1, H - 1)
        valid = in_front & visible_o & (x0 <= x1) & (y0 <= y1) & torch.isfinite(radius)
        boxes = torch.stack([x0, x1, y0, y1], dim=-1)
        boxes = torch.where(valid[:, None], boxes, boxes.new_tensor([1.0, 0.0, 1.0, 0.0]))
        boxes = boxes.to(torch.int32)

    if gaussians.sh.shape[1] > 1:
        center = camera.center.to(device=means.device, dtype=f64)
        dirs = view_directions(means, center).to(out_dtype)
    else:
        dirs = None
    colors = sh_to_rgb(gaussians.sh, dirs)
    return ProjectedGaussians(
        means2d=means2d.to(out_dtype),
        conics=conics.to(out_dtype),
        depths=z.to(out_dtype),
        colors=colors,
        opacities=opacities,
        boxes=boxes.contiguous(),
        valid=valid,
    )
