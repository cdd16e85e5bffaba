"""``prosplat.render``: differentiable rasterization of 3D Gaussians for one camera.

Backends: ``"cpu"`` (tile-based C++ compositing, projection in torch; the default on CPU),
``"gsplat"`` (CUDA, when gsplat is installed; the default for CUDA tensors). Both follow the
rasterizer semantics of DESIGN.md; the pure-torch brute-force twin that defines them lives in
``prosplat/render/reference.py``.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.render.output import RenderOutput
from prosplat.render.projection import (
    ProjectedGaussians,
    project_gaussians,
    wider_than,
)

__all__ = ["RenderOutput", "render", "render_pair", "project_gaussians", "ProjectedGaussians"]


def _background(background: Tensor | None, like: Tensor) -> Tensor:
    if background is None:
        return like.new_zeros(3)
    bg = torch.as_tensor(background, dtype=like.dtype, device=like.device)
    if bg.shape != (3,) or not torch.isfinite(bg).all():
        raise ValueError(f"background must be 3 finite values (RGB), got {bg.tolist()}")
    return bg


def gsplat_available(device: torch.device) -> bool:
    if device.type != "cuda":
        return False
    try:
        import gsplat  # noqa: F401
    except ImportError:
        return False
    return True


def _chosen_backend(backend: str, device: torch.device) -> str:
    """``backend`` with "auto" resolved: gsplat where it runs (CUDA), else the fused CPU
    projection (the same image as "cpu", ~1.3x faster at 128 px)."""
    if backend != "auto":
        return backend
    return "gsplat" if gsplat_available(device) else "cpu-fused"


def render(
    gaussians: Gaussians,
    camera: Camera,
    background: Tensor | None = None,
    backend: str = "auto",
    *,
    check: bool = True,
    max_radius: float | None = None,
) -> RenderOutput:
    """Render ``gaussians`` from ``camera``; differentiable w.r.t. every Gaussian parameter.

    Args:
        gaussians: N Gaussians (float32 or float64).
        camera: a pinhole :class:`~prosplat.Camera` without skew.
        background: [3] RGB behind the Gaussians (default black).
        backend: "auto", "cpu", "cpu-fused" (the CPU path with the projection as one C++
            kernel, :mod:`prosplat.render.fused`, checked against "cpu") or "gsplat". "auto"
            is gsplat where it runs (CUDA), else "cpu-fused".
        check: validate the Gaussians first (:meth:`Gaussians.validate`). False only in
            loops whose Gaussians are valid by construction and that watch their own loss
            for NaN (refinement): the check reads every value, every render.
        max_radius: Gaussians this camera would draw with a standard deviation wider than
            this fraction of the view's shorter side are left out, as if not given
            (``visible`` False; :func:`prosplat.render.projection.wider_than`). On the CPU
            the projection that draws them judges them, so leaving them out costs nothing;
            None draws them all.
    """
    if not isinstance(gaussians, Gaussians):
        raise ValueError(f"render expects prosplat.Gaussians, got {type(gaussians).__name__}")
    if not isinstance(camera, Camera):
        raise ValueError(f"render expects a prosplat.Camera, got {type(camera).__name__}")
    if check:
        gaussians.validate()
    bg = _background(background, gaussians.means)
    backend = _chosen_backend(backend, gaussians.device)
    if backend not in ("cpu", "cpu-fused", "gsplat"):
        raise ValueError(f"unknown backend {backend!r}; use 'auto', 'cpu', 'cpu-fused' or 'gsplat'")
    if backend == "gsplat":
        from prosplat.render.gsplat_backend import render_gsplat

        if max_radius is None:
            return render_gsplat(gaussians, camera, bg)
        # judged by the torch projection: gsplat's own is not shared with this code
        keep = ~wider_than(project_gaussians(gaussians, camera), camera, max_radius)  # [N]
        return _scattered(render_gsplat(gaussians[keep], camera, bg), keep)
    proj, order = _project_cpu(gaussians, camera, backend == "cpu-fused", max_radius)
    return _composite_cpu(proj, order, proj.opacities, camera, bg, gaussians.device)


def _scattered(out: RenderOutput, keep: Tensor) -> RenderOutput:
    """A render of ``gaussians[keep]`` with ``visible`` back over all N Gaussians."""
    visible = torch.zeros_like(keep)
    visible[keep] = out.visible
    return RenderOutput(rgb=out.rgb, alpha=out.alpha, depth=out.depth, visible=visible)


def render_pair(
    gaussians: Gaussians,
    camera: Camera,
    colour_opacities: Tensor,
    background: Tensor | None = None,
    backend: str = "auto",
    *,
    max_radius: float | None = None,
) -> tuple[RenderOutput, RenderOutput]:
    """``render(gaussians, camera)`` and the render of the same Gaussians with opacities
    ``colour_opacities [N]`` (each at most its Gaussian's opacity), as two
    :class:`RenderOutput`. Why: a view that favours one input's colour
    (:func:`prosplat.pipeline.enhance.render_favouring`) needs both, and on the CPU the
    projection is most of a render's time at artist sizes: here it runs once, and both
    composites run as one pass that shares the binning and the exp of each sample
    (:func:`prosplat.render.cpu.composite_pair`). The same images as two :func:`render` calls,
    bitwise: the pixel boxes of the lower opacities lie inside those of the higher ones, and
    samples under 1/255 are skipped either way. Opacities above the Gaussians' own (or
    another backend) take two renders. ``max_radius``: as in :func:`render`, the widest
    Gaussians left out of both."""
    if not isinstance(gaussians, Gaussians):
        raise ValueError(f"render expects prosplat.Gaussians, got {type(gaussians).__name__}")
    lower = colour_opacities.to(gaussians.opacities)
    if lower.shape != gaussians.opacities.shape:
        raise ValueError(
            f"colour_opacities must be [N] = {list(gaussians.opacities.shape)}, got "
            f"{list(lower.shape)}"
        )
    weighted = Gaussians.trusted(
        gaussians.means, gaussians.quats, gaussians.scales, lower, gaussians.sh, gaussians.views
    )
    backend = _chosen_backend(backend, gaussians.device)
    if backend not in ("cpu", "cpu-fused") or bool((lower > gaussians.opacities).any()):
        return (
            render(gaussians, camera, background, backend, max_radius=max_radius),
            render(weighted, camera, background, backend, check=False, max_radius=max_radius),
        )
    if not isinstance(camera, Camera):
        raise ValueError(f"render expects a prosplat.Camera, got {type(camera).__name__}")
    gaussians.validate()
    bg = _background(background, gaussians.means)
    proj, order = _project_cpu(gaussians, camera, backend == "cpu-fused", max_radius)
    return _composite_pair_cpu(proj, order, lower.cpu(), camera, bg, gaussians.device)


def _project_cpu(
    gaussians: Gaussians, camera: Camera, fused: bool, max_radius: float | None = None
) -> tuple[ProjectedGaussians, Tensor]:
    """The projection on the CPU and the front-to-back order [M] int64 of the Gaussians it
    draws: the valid ones, less those wider than ``max_radius`` (whose ``valid`` turns False;
    the fused kernel judges them itself)."""
    from prosplat.render.fused import depth_order, project_gaussians_fused

    if gaussians.device.type != "cpu":
        gaussians = gaussians.to("cpu")
    if fused:
        proj = project_gaussians_fused(gaussians, camera, max_radius)
    else:
        proj = project_gaussians(gaussians, camera)
        if max_radius is not None:
            wide = wider_than(proj, camera, max_radius)  # [N]
            proj = dataclasses.replace(proj, valid=proj.valid & ~wide)
    return proj, depth_order(proj.depths, proj.valid)


def _features(proj: ProjectedGaussians) -> Tensor:
    """[N,4]: each Gaussian's colour and depth, the features the composite sums."""
    return torch.cat([proj.colors, proj.depths[:, None]], dim=1)


def _composite_cpu(proj, order, opacities: Tensor, camera: Camera, bg: Tensor, device):
    """A projection composited with ``opacities [N]`` over ``bg``, back on ``device``."""
    from prosplat.render.cpu import composite

    out, trans = composite(
        proj.means2d, proj.conics, opacities, _features(proj), proj.boxes, order, camera.width,
        camera.height,
    )  # fmt: skip
    return _finished(out, trans, proj.valid, bg, device)


def _composite_pair_cpu(proj, order, lower: Tensor, camera: Camera, bg: Tensor, device):
    """The projection composited with its own opacities and with ``lower [N]`` (at most
    those) in one pass (:func:`prosplat.render.cpu.composite_pair`): two renders."""
    from prosplat.render.cpu import composite_pair

    out, trans, out_lo, trans_lo = composite_pair(
        proj.means2d, proj.conics, proj.opacities, lower, _features(proj), proj.boxes, order,
        camera.width, camera.height,
    )  # fmt: skip
    return (
        _finished(out, trans, proj.valid, bg, device),
        _finished(out_lo, trans_lo, proj.valid, bg, device),
    )


def _finished(out: Tensor, trans: Tensor, valid: Tensor, bg: Tensor, device) -> RenderOutput:
    """A render from a composite's features [4,H,W] (colour, depth) and transmittance [H,W]:
    the colour over ``bg`` [3], the alpha, the depth (0 where nothing is drawn), on ``device``.
    One C++ pass where no gradient is needed, the torch twin otherwise (the same values)."""
    from prosplat.render.cpu import finish, finish_reference

    bg = bg.cpu()
    grad = torch.is_grad_enabled() and any(x.requires_grad for x in (out, trans, bg))
    fast = not grad and bg.dtype == out.dtype
    rgb, alpha, depth = (finish if fast else finish_reference)(out, trans, bg)
    result = RenderOutput(rgb=rgb, alpha=alpha, depth=depth, visible=valid)
    if device.type != "cpu":
        result = RenderOutput(*(x.to(device) for x in (rgb, alpha, depth, valid)))
    return result
