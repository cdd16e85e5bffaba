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
    projection is most of a render's time at artist sizes: here it runs once and only the
    compositing twice. The same images as two :func:`render` calls: the pixel boxes of the
    lower opacities lie inside those of the higher ones, and samples under 1/255 are skipped
    either way. Opacities above the Gaussians' own (or another backend) take two renders.
    ``max_radius``: as in :func:`render`, the widest Gaussians left out of both."""
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
    plain = _composite_cpu(proj, order, proj.opacities, camera, bg, gaussians.device)
    colour = _composite_cpu(proj, order, lower.cpu(), camera, bg, gaussians.device)
    return plain, colour


def _project_cpu(
    gaussians: Gaussians, camera: Camera, fused: bool, max_radius: float | None = None
):
    """The projection on the CPU and the front-to-back order of the Gaussians it draws: the
    valid ones, less those wider than ``max_radius`` (whose ``valid`` turns False)."""
    from prosplat.render.fused import project_gaussians_fused

    if gaussians.device.type != "cpu":
        gaussians = gaussians.to("cpu")
    proj = (project_gaussians_fused if fused else project_gaussians)(gaussians, camera)
    if max_radius is not None:
        proj = dataclasses.replace(proj, valid=proj.valid & ~wider_than(proj, camera, max_radius))
    idx = torch.nonzero(proj.valid).squeeze(1)
    order = idx[torch.argsort(proj.depths.detach()[idx], stable=True)]
    return proj, order


def _composite_cpu(proj, order, opacities: Tensor, camera: Camera, bg: Tensor, device):
    """A projection composited with ``opacities [N]`` over ``bg``, back on ``device``."""
    from prosplat.render.cpu import composite

    bg = bg.cpu()
    feats = torch.cat([proj.colors, proj.depths[:, None]], dim=1)  # [N,4]
    out, trans = composite(
        proj.means2d, proj.conics, opacities, feats, proj.boxes, order, camera.width,
        camera.height,
    )  # fmt: skip
    alpha = 1.0 - trans
    rgb = out[:3] + trans[None] * bg[:, None, None]
    depth = torch.where(alpha > 0, out[3] / alpha.clamp_min(1e-6), torch.zeros_like(alpha))
    result = RenderOutput(rgb=rgb, alpha=alpha, depth=depth, visible=proj.valid)
    if device.type != "cpu":
        result = RenderOutput(*(x.to(device) for x in (rgb, alpha, depth, proj.valid)))
    return result
