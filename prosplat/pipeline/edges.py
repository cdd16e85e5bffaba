"""The generator's output with the ramps between its surfaces resolved
(:mod:`prosplat.geometry.depth_edges`).

Why here and not in the network: it needs no learning, so it carries to any generator that
emits pixel-aligned Gaussians, and training keeps seeing the network's own depth."""

from __future__ import annotations

from dataclasses import replace

import torch

from prosplat.core.camera import Camera
from prosplat.generator import GeneratorOutput
from prosplat.geometry.depth_edges import EdgeOptions, resolve_depth_edges
from prosplat.pipeline.depth_sweep import slide_along_rays

__all__ = ["resolve_output"]


def resolve_output(
    out: GeneratorOutput,
    cameras: list[Camera],
    options: EdgeOptions | None = None,
    scale: float = 1.0,
) -> GeneratorOutput:
    """``out`` (one scene, pixel-aligned) with the Gaussians of the pixels inside ramps
    between surfaces made transparent (``"drop"``: the budget then removes them) or slid
    along their rays onto the nearer surface, their footprint in their own view kept
    (``"snap"``). ``scale``: input pixels per pixel of the size the generator matched at."""
    if out.batch_size != 1:
        raise ValueError(f"resolve_output takes one scene (B = 1), got B = {out.batch_size}")
    depths = out.depths[0].detach()  # [V,H,W]
    new, dropped = resolve_depth_edges(depths, options, scale)
    if bool(dropped.any()):
        keep = (~dropped).reshape(1, -1).to(out.opacities.dtype)  # [1,N]
        out = replace(out, opacities=out.opacities * keep)
    if not torch.equal(new, depths):
        out = slide_along_rays(out, cameras, new)
    return out
