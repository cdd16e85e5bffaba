"""The EWA projection as one C++ kernel, forward and backward (``_cpu_project.cpp``).

:func:`prosplat.render.projection.project_gaussians` is its twin: the same float64 arithmetic
written as ~100 torch operations on [N] tensors, whose autograd dominates a refinement step.
Here one pass per Gaussian (``_cpu_project.cpp``) computes the pixel mean, conic, depth, the
pixel box and whether it is drawn, and the backward pass recomputes that pass and walks it
back by hand. The tests hold it to the twin, forward and backward, in float64, and its boxes
to :func:`~prosplat.render.projection.pixel_boxes` exactly. Colours (SH) stay in torch.
:func:`depth_order` sorts the drawn Gaussians front to back as one radix sort. Used by
:mod:`prosplat.pipeline.refine` (``RefineOptions.fused_projection``) through
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
    box_radii_sq,
    check_max_radius,
    view_directions,
    wider_than,
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


def _forward(means, quats, scales, cam, opac, r2, frame):
    """The forward kernel in the inputs' dtype (float32 or float64): means2d [N,2], conics [N,3],
    depth [N] in that dtype, boxes [N,4] int32, valid [N] bool."""
    n, dtype = means.shape[0], means.dtype
    suffix = {torch.float32: "f32", torch.float64: "f64"}[dtype]
    means2d = means.new_empty(n, 2)
    conics = means.new_empty(n, 3)
    depth = means.new_empty(n)
    boxes = torch.empty(n, 4, dtype=torch.int32)
    valid = torch.empty(n, dtype=torch.bool)
    getattr(native.load(), f"prosplat_project_forward_{suffix}")(
        n, _ptr(means), _ptr(quats), _ptr(scales), _ptr(cam), _ptr(opac), _ptr(r2), _ptr(frame),
        _ptr(means2d), _ptr(conics), _ptr(depth), _ptr(boxes), _ptr(valid),
        torch.get_num_threads(),
    )  # fmt: skip
    return means2d, conics, depth, boxes, valid


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, cam, opac, r2, frame):  # noqa: D102
        means2d, conics, depth, boxes, valid = _forward(means, quats, scales, cam, opac, r2, frame)
        ctx.save_for_backward(means, quats, scales, cam)
        ctx.mark_non_differentiable(boxes, valid)
        return means2d, conics, depth, boxes, valid

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_depth, _g_boxes, _g_valid):  # noqa: D102
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
        return g_means, g_quats, g_scales, None, None, None, None


def project_gaussians_fused(
    gaussians: Gaussians, camera: Camera, max_radius: float | None = None
) -> ProjectedGaussians:
    """:func:`~prosplat.render.projection.project_gaussians` through the fused kernel (CPU),
    pixel boxes included; with ``max_radius``, the Gaussians
    :func:`~prosplat.render.projection.wider_than` flags are not ``valid`` (their boxes kept).

    Where no gradient is asked for, the kernel reads and writes the Gaussians' own dtype (the
    same values: it works in float64 and rounds once, as ``.to`` does), so the Gaussians are
    not copied to float64 first; a differentiable call keeps the float64 autograd path."""
    if camera.K[0, 1] != 0:
        raise ValueError("the rasterizer needs a camera without skew (K[0,1] == 0)")
    if gaussians.device.type != "cpu":
        raise ValueError("the fused projection runs on the CPU; use backend='auto' elsewhere")
    if max_radius is not None:
        check_max_radius(max_radius)
    out_dtype, f64 = gaussians.dtype, torch.float64
    inputs = (gaussians.means, gaussians.quats, gaussians.scales)
    opacities = gaussians.opacities
    opac, r2 = box_radii_sq(opacities)  # [N] float64 each
    grad = torch.is_grad_enabled() and any(t.requires_grad for t in inputs)
    limit = -1.0 if max_radius is None or grad else max_radius * min(camera.width, camera.height)
    frame = torch.tensor([camera.width, camera.height, limit], dtype=f64)
    cam = camera_constants(camera)
    if grad:
        args = [t.to(f64).contiguous() for t in inputs]
        means2d, conics, z, boxes, valid = _Project.apply(*args, cam, opac, r2, frame)
        means2d, conics, z = means2d.to(out_dtype), conics.to(out_dtype), z.to(out_dtype)
    else:
        args = [t.detach().contiguous() for t in inputs]
        means2d, conics, z, boxes, valid = _forward(*args, cam, opac, r2, frame)
    if gaussians.sh.shape[1] > 1:
        center = camera.center.to(dtype=out_dtype)
        dirs = view_directions(gaussians.means, center)
    else:
        dirs = None
    proj = ProjectedGaussians(
        means2d=means2d,
        conics=conics,
        depths=z,
        colors=sh_to_rgb(gaussians.sh, dirs),
        opacities=opacities,
        boxes=boxes,
        valid=valid,
    )
    if grad and max_radius is not None:  # judged in torch on the rounded conics, as the kernel
        proj.valid = valid & ~wider_than(proj, camera, max_radius)
    return proj


def depth_order(depths: Tensor, valid: Tensor) -> Tensor:
    """[M] int64: the indices of the ``valid`` Gaussians front to back, ties in index order;
    ``idx[torch.argsort(depths[idx], stable=True)]`` for ``idx = nonzero(valid)``, as one C++
    radix sort. ``depths`` [N] float32 or float64 on the CPU, positive where ``valid`` (drawn
    Gaussians lie beyond the near plane)."""
    depths = depths.detach().contiguous()
    valid = valid.contiguous()
    suffix = {torch.float32: "f32", torch.float64: "f64"}.get(depths.dtype)
    if suffix is None or depths.device.type != "cpu" or valid.dtype != torch.bool:
        raise ValueError("depth_order takes [N] float32/float64 depths and [N] bool on the CPU")
    order = torch.empty(depths.shape[0], dtype=torch.int64)
    m = getattr(native.load(), f"prosplat_depth_order_{suffix}")(
        depths.shape[0], _ptr(depths), _ptr(valid), _ptr(order)
    )
    return order[:m]
