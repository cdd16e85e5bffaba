"""The EWA projection as one C++ kernel, forward and backward (``_cpu_kernels.cpp``).

:func:`prosplat.render.projection.project_gaussians` is its twin: the same float64 arithmetic
written as ~100 torch operations on [N] tensors, whose autograd dominates a refinement step.
Here one pass per Gaussian computes the pixel mean, conic, depth and the dilated covariance
diagonal (for the pixel boxes), and the backward pass recomputes that pass and walks it back
by hand. The tests hold it to the twin, forward and backward, in float64. Colours (SH) stay
in torch. Used by :mod:`prosplat.pipeline.refine` (``RefineOptions.fused_projection``) through
``render(..., backend="cpu-fused")``.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.render import native
from prosplat.render.projection import (
    DILATION,
    FOV_CLAMP,
    NEAR_PLANE,
    ProjectedGaussians,
    pixel_boxes,
    view_directions,
)
from prosplat.render.sh import sh_to_rgb


def _ptr(t: Tensor) -> ctypes.c_void_p:
    return ctypes.c_void_p(t.data_ptr())


def camera_constants(camera: Camera) -> Tensor:
    """[22] float64: R (row-major), t, fx, fy, cx, cy, the x/z and y/z clamp range, near,
    dilation, in the kernel's order."""
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    clamp = [
        -(cx / fx + FOV_CLAMP * tan_x),
        (W - cx) / fx + FOV_CLAMP * tan_x,
        -(cy / fy + FOV_CLAMP * tan_y),
        (H - cy) / fy + FOV_CLAMP * tan_y,
    ]
    rest = torch.tensor([fx, fy, cx, cy, *clamp, NEAR_PLANE, DILATION], dtype=torch.float64)
    R = camera.R.detach().cpu().to(torch.float64).reshape(9)
    t = camera.t.detach().cpu().to(torch.float64).reshape(3)
    return torch.cat([R, t, rest]).contiguous()


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, cam):  # noqa: D102
        n = means.shape[0]
        means2d = means.new_empty(n, 2)
        conics = means.new_empty(n, 3)
        depth = means.new_empty(n)
        ac = means.new_empty(n, 2)
        native.load().prosplat_project_forward_f64(
            n, _ptr(means), _ptr(quats), _ptr(scales), _ptr(cam), _ptr(means2d), _ptr(conics),
            _ptr(depth), _ptr(ac), torch.get_num_threads(),
        )  # fmt: skip
        ctx.save_for_backward(means, quats, scales, cam)
        ctx.mark_non_differentiable(ac)
        return means2d, conics, depth, ac

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_depth, _g_ac):  # noqa: D102
        means, quats, scales, cam = ctx.saved_tensors
        n = means.shape[0]
        g_m2d = torch.zeros_like(means[:, :2]) if g_m2d is None else g_m2d.contiguous()
        g_con = torch.zeros_like(means) if g_con is None else g_con.contiguous()
        g_depth = means.new_zeros(n) if g_depth is None else g_depth.contiguous()
        g_means, g_quats, g_scales = (
            torch.empty_like(means),
            torch.empty_like(quats),
            torch.empty_like(scales),
        )
        native.load().prosplat_project_backward_f64(
            n, _ptr(means), _ptr(quats), _ptr(scales), _ptr(cam), _ptr(g_m2d), _ptr(g_con),
            _ptr(g_depth), _ptr(g_means), _ptr(g_quats), _ptr(g_scales), torch.get_num_threads(),
        )  # fmt: skip
        return g_means, g_quats, g_scales, None


def project_gaussians_fused(gaussians: Gaussians, camera: Camera) -> ProjectedGaussians:
    """:func:`~prosplat.render.projection.project_gaussians` through the fused kernel (CPU)."""
    if camera.K[0, 1] != 0:
        raise ValueError("the rasterizer needs a camera without skew (K[0,1] == 0)")
    if gaussians.device.type != "cpu":
        raise ValueError("the fused projection runs on the CPU; use backend='auto' elsewhere")
    out_dtype, f64 = gaussians.dtype, torch.float64
    args = [t.to(f64).contiguous() for t in (gaussians.means, gaussians.quats, gaussians.scales)]
    means2d, conics, z, ac = _Project.apply(*args, camera_constants(camera))
    in_front = z.detach() >= NEAR_PLANE
    opacities = gaussians.opacities
    boxes, valid = pixel_boxes(
        means2d, ac[:, 0], ac[:, 1], in_front, opacities, camera.width, camera.height
    )
    if gaussians.sh.shape[1] > 1:
        center = camera.center.to(dtype=out_dtype)
        dirs = view_directions(gaussians.means, center)
    else:
        dirs = None
    return ProjectedGaussians(
        means2d=means2d.to(out_dtype),
        conics=conics.to(out_dtype),
        depths=z.to(out_dtype),
        colors=sh_to_rgb(gaussians.sh, dirs),
        opacities=opacities,
        boxes=boxes,
        valid=valid,
    )
