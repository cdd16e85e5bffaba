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
1/255 (the bounding box of the ellipse ``dᵀΣ⁻¹d = 2 ln(255·o)``), so tile culling never
changes the image: the rasterizer is exactly "skip samples under 1/255".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
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


def check_max_radius(value, name: str = "max_radius") -> None:
    """Refuse a cap on the splats' radius that is not a finite number > 0, naming ``name``."""
    if isinstance(value, bool) or not (
        isinstance(value, (int, float)) and math.isfinite(value) and value > 0
    ):
        raise ValueError(f"{name} must be a finite number > 0 (or None), got {value!r}")


def wider_than(proj: ProjectedGaussians, camera: Camera, max_radius: float) -> Tensor:
    """[N] bool: the drawn (``valid``) Gaussians of ``proj`` (projected for ``camera``)
    whose screen footprint has a standard deviation wider than ``max_radius`` times the
    view's shorter side along its widest direction. The conic is the inverse 2D covariance,
    so its smallest eigenvalue is 1 / (the widest sd)²; computed in float64 whatever the
    projection's dtype."""
    check_max_radius(max_radius)
    limit = max_radius * min(camera.width, camera.height)  # px
    a, b, c = proj.conics.detach().to(torch.float64).unbind(-1)  # [N] each
    low = (a + c) / 2 - torch.sqrt(((a - c) / 2) ** 2 + b * b)  # [N]
    return proj.valid & (low * limit * limit < 1)


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """[N,4] (w,x,y,z), any non-zero length -> [N,3,3] rotation matrices."""
    rows = _rotation_entries(quats.T)
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def _rotation_entries(q: Tensor) -> list[list[Tensor]]:
    """[4,N] quaternion components -> 3x3 nested list of [N] rotation-matrix entries."""
    w, x, y, z = q / torch.sqrt((q * q).sum(0))
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def view_directions(means: Tensor, center: Tensor) -> Tensor:
    """[N,3] unit directions from the camera centre to each mean; zero (not NaN) at the centre."""
    d = means - center
    sq = (d * d).sum(-1, keepdim=True)
    ok = sq > 1e-24
    return torch.where(
        ok, d / torch.sqrt(torch.where(ok, sq, torch.ones_like(sq))), torch.zeros_like(d)
    )


@torch.no_grad()
def box_radii_sq(opacities: Tensor) -> tuple[Tensor, Tensor]:
    """The opacities [N] in float64 and r² = 2 ln(255 o) [N] float64, the squared Mahalanobis
    radius inside which alpha can reach 1/255. Shared by :func:`pixel_boxes` and the fused
    kernel (:mod:`prosplat.render.fused`), which takes r² from here because torch's log and
    the C library's round differently in about 1 case in 10⁴, and the boxes must agree."""
    o = opacities.detach().to(torch.float64)
    r2 = (255.0 * o).clamp_min_(1.0).log_().mul_(2.0)  # in place: one [N] buffer, not four
    return o, r2


@torch.no_grad()
def pixel_boxes(
    means2d: Tensor, a: Tensor, c: Tensor, in_front: Tensor, opacities: Tensor, W: int, H: int
) -> tuple[Tensor, Tensor]:
    """Inclusive pixel boxes [N,4] int32 (x0, x1, y0, y1) outside which a Gaussian's alpha is
    < 1/255, and whether each is drawn at all; ``a``, ``c``: the dilated 2D covariance diagonal
    (float64)."""
    f64 = torch.float64
    # alpha >= 1/255 needs dᵀ Σ⁻¹ d <= r² = 2 ln(255 o); that ellipse's half-widths are
    # r·sqrt(Σ_xx) and r·sqrt(Σ_yy). A small margin covers float32 rounding in the kernel.
    o, r2 = box_radii_sq(opacities)
    visible_o = o >= MIN_ALPHA
    half_w = torch.sqrt(r2 * a) * (1 + 1e-4) + 1e-3
    half_h = torch.sqrt(r2 * c) * (1 + 1e-4) + 1e-3
    u, v = means2d[:, 0].detach().to(f64), means2d[:, 1].detach().to(f64)
    x0 = torch.ceil(u - half_w - 0.5).clamp(0, W)
    x1 = torch.floor(u + half_w - 0.5).clamp(-1, W - 1)
    y0 = torch.ceil(v - half_h - 0.5).clamp(0, H)
    y1 = torch.floor(v + half_h - 0.5).clamp(-1, H - 1)
    finite = torch.isfinite(half_w) & torch.isfinite(half_h)
    valid = in_front & visible_o & (x0 <= x1) & (y0 <= y1) & finite
    boxes = torch.stack([x0, x1, y0, y1], dim=-1)
    boxes = torch.where(valid[:, None], boxes, boxes.new_tensor([1.0, 0.0, 1.0, 0.0]))
    return boxes.to(torch.int32).contiguous(), valid


def project_gaussians(gaussians: Gaussians, camera: Camera) -> ProjectedGaussians:
    """Project ``gaussians`` into ``camera`` (differentiable w.r.t. every Gaussian parameter).

    Written structure-of-arrays (one [N] tensor per component): torch reduces over a
    trailing dimension of 3 several times slower than it adds rows, and this runs per view.
    """
    if camera.K[0, 1] != 0:
        raise ValueError("the rasterizer needs a camera without skew (K[0,1] == 0)")
    out_dtype = gaussians.dtype
    f64 = torch.float64
    device = gaussians.device
    Rc = camera.R.to(dtype=f64).tolist()
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy

    m = gaussians.means.to(f64).T  # [3,N]
    pc = camera.R.to(device=device, dtype=f64) @ m + camera.t.to(device=device, dtype=f64)[:, None]
    x, y, z = pc  # camera space, [N] each
    in_front = z >= NEAR_PLANE
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    inv_z = 1.0 / z_safe
    xz, yz = x * inv_z, y * inv_z
    means2d = torch.stack([fx * xz + cx, fy * yz + cy], dim=-1)  # [N,2]

    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    xz_c = xz.clamp(-(cx / fx + FOV_CLAMP * tan_x), (W - cx) / fx + FOV_CLAMP * tan_x)
    yz_c = yz.clamp(-(cy / fy + FOV_CLAMP * tan_y), (H - cy) / fy + FOV_CLAMP * tan_y)

    # Rows of M = J · R_cam · R_q · diag(s), the 2x3 map whose M Mᵀ is the undilated 2D
    # covariance: J·R_cam has rows v0 = fx/z (R_cam[0] - x/z R_cam[2]), v1 likewise.
    ux, uy = fx * inv_z, fy * inv_z
    v0 = [ux * (Rc[0][k] - xz_c * Rc[2][k]) for k in range(3)]
    v1 = [uy * (Rc[1][k] - yz_c * Rc[2][k]) for k in range(3)]
    rq = _rotation_entries(gaussians.quats.to(f64).T)
    s = gaussians.scales.to(f64).T  # [3,N]
    row0 = [(v0[0] * rq[0][j] + v0[1] * rq[1][j] + v0[2] * rq[2][j]) * s[j] for j in range(3)]
    row1 = [(v1[0] * rq[0][j] + v1[1] * rq[1][j] + v1[2] * rq[2][j]) * s[j] for j in range(3)]
    a0 = row0[0] * row0[0] + row0[1] * row0[1] + row0[2] * row0[2]
    c0 = row1[0] * row1[0] + row1[1] * row1[1] + row1[2] * row1[2]
    b = row0[0] * row1[0] + row0[1] * row1[1] + row0[2] * row1[2]
    a, c = a0 + DILATION, c0 + DILATION
    # Cauchy-Binet: det(M Mᵀ) = |row0 × row1|², a sum of squares, never negative.
    k0 = row0[1] * row1[2] - row0[2] * row1[1]
    k1 = row0[2] * row1[0] - row0[0] * row1[2]
    k2 = row0[0] * row1[1] - row0[1] * row1[0]
    det = k0 * k0 + k1 * k1 + k2 * k2 + DILATION * (a0 + c0) + DILATION**2
    inv_det = 1.0 / det
    conics = torch.stack([c * inv_det, -b * inv_det, a * inv_det], dim=-1)  # [N,3]

    opacities = gaussians.opacities
    boxes, valid = pixel_boxes(means2d, a, c, in_front, opacities, W, H)

    if gaussians.sh.shape[1] > 1:
        center = camera.center.to(device=device, dtype=out_dtype)
        dirs = view_directions(gaussians.means, center)
    else:
        dirs = None
    colors = sh_to_rgb(gaussians.sh, dirs)
    return ProjectedGaussians(
        means2d=means2d.to(out_dtype),
        conics=conics.to(out_dtype),
        depths=z.to(out_dtype),
        colors=colors,
        opacities=opacities,
        boxes=boxes,
        valid=valid,
    )
