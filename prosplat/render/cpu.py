"""The CPU fast path: torch autograd around the C++ compositing kernels."""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from prosplat.render import native


def _ptr(t: Tensor) -> ctypes.c_void_p:
    return ctypes.c_void_p(t.data_ptr())


def _kernel(name: str, dtype: torch.dtype):
    suffix = {torch.float32: "f32", torch.float64: "f64"}.get(dtype)
    if suffix is None:
        raise ValueError(f"the CPU rasterizer supports float32 and float64, got {dtype}")
    return getattr(native.load(), f"prosplat_{name}_{suffix}")


class _Composite(torch.autograd.Function):
    """Front-to-back compositing of depth-sorted screen-space Gaussians.

    Returns ``features [F,H,W] = Σ wᵢ fᵢ`` and the final transmittance ``T [H,W]``.
    """

    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, boxes, order, width, height):  # noqa: D102
        n_feat = feats.shape[1]
        out = means2d.new_empty(n_feat, height, width)
        trans = means2d.new_empty(height, width)
        last = torch.empty(height, width, dtype=torch.int32)
        n_threads = torch.get_num_threads()
        _kernel("forward", means2d.dtype)(
            order.numel(),
            n_feat,
            width,
            height,
            _ptr(means2d),
            _ptr(conics),
            _ptr(opacities),
            _ptr(feats),
            _ptr(boxes),
            _ptr(order),
            _ptr(out),
            _ptr(trans),
            _ptr(last),
            n_threads,
        )
        ctx.save_for_backward(means2d, conics, opacities, feats, boxes, order, trans, last)
        ctx.size = (width, height)
        return out, trans

    @staticmethod
    def backward(ctx, grad_out, grad_trans):  # noqa: D102
        means2d, conics, opacities, feats, boxes, order, trans, last = ctx.saved_tensors
        width, height = ctx.size
        n, n_feat = feats.shape
        grad_out = torch.zeros_like(trans).expand(n_feat, -1, -1) if grad_out is None else grad_out
        grad_trans = torch.zeros_like(trans) if grad_trans is None else grad_trans
        grad_out, grad_trans = grad_out.contiguous(), grad_trans.contiguous()
        n_threads = torch.get_num_threads()
        grads = means2d.new_zeros(n_threads, n, 6 + n_feat)
        _kernel("backward", means2d.dtype)(
            order.numel(),
            n_feat,
            width,
            height,
            _ptr(means2d),
            _ptr(conics),
            _ptr(opacities),
            _ptr(feats),
            _ptr(boxes),
            _ptr(order),
            _ptr(trans),
            _ptr(last),
            _ptr(grad_out),
            _ptr(grad_trans),
            _ptr(grads),
            n,
            n_threads,
        )
        g = grads.sum(0)
        return g[:, 0:2], g[:, 2:5], g[:, 5], g[:, 6:], None, None, None, None


def composite(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    feats: Tensor,
    boxes: Tensor,
    order: Tensor,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """Composite screen-space Gaussians.

    Args:
        means2d: [N,2], conics: [N,3], opacities: [N], feats: [N,F] (same float dtype).
        boxes: [N,4] int32 inclusive pixel boxes; order: [M] int64 indices, front to back.
    Returns:
        features [F,H,W] (Σ wᵢ fᵢ, no background) and transmittance [H,W].
    """
    dtype = means2d.dtype
    args = [x.to(dtype).contiguous() for x in (means2d, conics, opacities, feats)]
    return _Composite.apply(*args, boxes.contiguous(), order.contiguous(), width, height)
