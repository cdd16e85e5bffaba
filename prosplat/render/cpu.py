"""The CPU fast path: torch autograd around the C++ compositing kernels, for one opacity
stream (:func:`composite`) or two of the same Gaussians in one pass (:func:`composite_pair`)."""

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


def _backward(saved, size, grad_out, grad_trans):
    """Gradients of one stream's composite: d means2d [N,2], d conics [N,3], d opacities [N],
    d feats [N,F]; ``saved`` = (means2d, conics, opacities, feats, boxes, order, trans, last)."""
    means2d, conics, opacities, feats, boxes, order, trans, last = saved
    width, height = size
    n, n_feat = feats.shape
    grad_out = torch.zeros_like(trans).expand(n_feat, -1, -1) if grad_out is None else grad_out
    grad_trans = torch.zeros_like(trans) if grad_trans is None else grad_trans
    grad_out, grad_trans = grad_out.contiguous(), grad_trans.contiguous()
    n_threads = torch.get_num_threads()
    grads = means2d.new_zeros(n_threads, n, 6 + n_feat)
    _kernel("backward", means2d.dtype)(
        order.numel(), n_feat, width, height, _ptr(means2d), _ptr(conics), _ptr(opacities),
        _ptr(feats), _ptr(boxes), _ptr(order), _ptr(trans), _ptr(last), _ptr(grad_out),
        _ptr(grad_trans), _ptr(grads), n, n_threads,
    )  # fmt: skip
    g = grads.sum(0)
    return g[:, 0:2], g[:, 2:5], g[:, 5], g[:, 6:]


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
        grads = _backward(ctx.saved_tensors, ctx.size, grad_out, grad_trans)
        return *grads, None, None, None, None


class _CompositePair(torch.autograd.Function):
    """:class:`_Composite` with two opacity vectors in one pass (``prosplat_forward_pair``):
    returns ``(features_a, T_a, features_b, T_b)``. The backward pass is each stream's
    backward, summed where they share an input."""

    @staticmethod
    def forward(ctx, means2d, conics, op_a, op_b, feats, boxes, order, width, height):  # noqa: D102
        n_feat = feats.shape[1]
        outs = [means2d.new_empty(n_feat, height, width) for _ in range(2)]
        trans = [means2d.new_empty(height, width) for _ in range(2)]
        last = [torch.empty(height, width, dtype=torch.int32) for _ in range(2)]
        _kernel("forward_pair", means2d.dtype)(
            order.numel(), n_feat, width, height, _ptr(means2d), _ptr(conics), _ptr(op_a),
            _ptr(op_b), _ptr(feats), _ptr(boxes), _ptr(order), _ptr(outs[0]), _ptr(trans[0]),
            _ptr(last[0]), _ptr(outs[1]), _ptr(trans[1]), _ptr(last[1]),
            torch.get_num_threads(),
        )  # fmt: skip
        ctx.save_for_backward(
            means2d, conics, op_a, op_b, feats, boxes, order, trans[0], trans[1], last[0], last[1]
        )
        ctx.size = (width, height)
        return outs[0], trans[0], outs[1], trans[1]

    @staticmethod
    def backward(ctx, g_out_a, g_trans_a, g_out_b, g_trans_b):  # noqa: D102
        means2d, conics, op_a, op_b, feats, boxes, order, t_a, t_b, l_a, l_b = ctx.saved_tensors
        shared = (means2d, conics)
        ga = _backward((*shared, op_a, feats, boxes, order, t_a, l_a), ctx.size, g_out_a, g_trans_a)
        gb = _backward((*shared, op_b, feats, boxes, order, t_b, l_b), ctx.size, g_out_b, g_trans_b)
        return ga[0] + gb[0], ga[1] + gb[1], ga[2], gb[2], ga[3] + gb[3], None, None, None, None


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


def composite_pair(
    means2d: Tensor,
    conics: Tensor,
    opacities_a: Tensor,
    opacities_b: Tensor,
    feats: Tensor,
    boxes: Tensor,
    order: Tensor,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`composite` of the same Gaussians with ``opacities_a`` [N] and ``opacities_b`` [N]
    in one pass: ``(features_a [F,H,W], T_a [H,W], features_b, T_b)``, bitwise what two
    :func:`composite` calls return (:func:`composite_pair_reference`). Why: the binning and
    the exp of each sample, most of a composite's time, are shared; each stream keeps its own
    transmittance and stops on its own. The boxes must hold both streams' samples above 1/255:
    those of the higher opacity of each Gaussian do."""
    dtype = means2d.dtype
    args = [x.to(dtype).contiguous() for x in (means2d, conics, opacities_a, opacities_b, feats)]
    return _CompositePair.apply(*args, boxes.contiguous(), order.contiguous(), width, height)


def composite_pair_reference(
    means2d: Tensor,
    conics: Tensor,
    opacities_a: Tensor,
    opacities_b: Tensor,
    feats: Tensor,
    boxes: Tensor,
    order: Tensor,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`composite_pair` as two :func:`composite` calls: its twin, for the tests."""
    shared = (feats, boxes, order, width, height)
    return (
        *composite(means2d, conics, opacities_a, *shared),
        *composite(means2d, conics, opacities_b, *shared),
    )


def finish(out: Tensor, trans: Tensor, bg: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """A render from a composite of colour and depth: ``out`` [4,H,W] (Σ w·colour, Σ w·depth),
    ``trans`` [H,W], ``bg`` [3] (all one dtype) -> (rgb [3,H,W] over ``bg``, alpha [H,W],
    depth [H,W], 0 where nothing is drawn). :func:`finish_reference`'s values in one C++ pass
    (ten torch operations over the image otherwise); no gradient: renders that need one take
    the reference."""
    out, trans = out.detach().contiguous(), trans.detach().contiguous()
    bg = bg.detach().to(out.dtype).contiguous()
    rgb, alpha, depth = (
        out.new_empty(3, *trans.shape),
        torch.empty_like(trans),
        torch.empty_like(trans),
    )
    _kernel("finish", out.dtype)(
        trans.numel(), _ptr(out), _ptr(trans), _ptr(bg), _ptr(rgb), _ptr(alpha), _ptr(depth),
        torch.get_num_threads(),
    )  # fmt: skip
    return rgb, alpha, depth


def finish_reference(out: Tensor, trans: Tensor, bg: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`finish` in torch, differentiable: its twin and the path of renders with grad."""
    alpha = 1.0 - trans
    rgb = out[:3] + trans[None] * bg[:, None, None]
    depth = torch.where(alpha > 0, out[3] / alpha.clamp_min(1e-6), torch.zeros_like(alpha))
    return rgb, alpha, depth
