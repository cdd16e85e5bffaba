"""Rendering a camera and enhancing it with stage 2: the glue between rasterizer, MORI and the
improvement model, shared by :meth:`prosplat.ProSplat.render`, curation and evaluation.

The improvement model needs image sizes that are multiples of its stride (16 for ``tiny``);
any camera works here because the render and the reference are padded on the right and
bottom (edge replicate) and the result cropped back. Padding there leaves pixel coordinates,
and so the fundamental matrix, unchanged.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.camera import Camera
from prosplat.gaussians import Gaussians
from prosplat.improve.epipolar import fundamental_matrix
from prosplat.improve.mori import select_reference
from prosplat.render import render


@dataclass
class EnhancedView:
    """One rendered (and possibly enhanced) view.

    ``image`` [3,H,W] is the enhanced image (the raw render when not enhanced); ``raw``
    [3,H,W] the rasterizer's image; ``alpha``/``depth`` [H,W]; ``reference`` the index of the
    input camera MORI chose (None when not enhanced); ``timings`` in milliseconds.
    """

    image: Tensor
    raw: Tensor
    alpha: Tensor
    depth: Tensor
    reference: int | None
    timings: dict[str, float] = field(default_factory=dict)


def pad_to_multiple(images: Tensor, multiple: int) -> Tensor:
    """[B,3,H,W] -> [B,3,H',W'] with H', W' the next multiples, edge-replicated right/bottom."""
    h, w = images.shape[-2:]
    ph, pw = -h % multiple, -w % multiple
    if ph == 0 and pw == 0:
        return images
    return F.pad(images, (0, pw, 0, ph), mode="replicate")


def reference_at(image: Tensor, camera: Camera, width: int, height: int) -> tuple[Tensor, Camera]:
    """An input view resampled to the target's size (bilinear, antialiased) with its camera."""
    if (camera.width, camera.height) == (width, height):
        return image, camera
    resized = F.interpolate(
        image[None], size=(height, width), mode="bilinear", align_corners=False, antialias=True
    )[0]
    return resized, camera.resized(width, height)


def enhance(
    improver,
    raw: Tensor,
    camera: Camera,
    reference_image: Tensor | None,
    reference_camera: Camera | None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Run ``improver`` on one render ``raw [3,H,W]`` with its reference; returns [3,H,W].

    ``dtype=torch.bfloat16`` runs under CPU/GPU autocast (the output is float32 again).
    """
    h, w = raw.shape[-2:]
    m = improver.config.size_multiple
    device = next(improver.parameters()).device
    x = pad_to_multiple(raw[None].to(device), m)
    ref = fund = None
    if improver.config.reference:
        if reference_image is None or reference_camera is None:
            raise ValueError("this improvement model needs a reference view and its camera")
        ref_img, ref_cam = reference_at(reference_image.to(device), reference_camera, w, h)
        ref = pad_to_multiple(ref_img[None], m)
        fund = fundamental_matrix(camera, ref_cam)[None].to(device)  # float64: DWEA's precision
    with torch.autocast(device.type, dtype=dtype, enabled=dtype != torch.float32):
        out = improver(x, ref, fund)
    return out.float()[0, :, :h, :w]


def render_view(
    gaussians: Gaussians,
    camera: Camera,
    images: Tensor | None = None,
    cameras: Sequence[Camera] | None = None,
    improver=None,
    *,
    reference_method: str = "paper",
    background: Tensor | None = None,
    dtype: torch.dtype = torch.float32,
) -> EnhancedView:
    """Render ``camera`` and, when ``improver`` is given, enhance it with the MORI reference
    chosen among ``cameras`` (whose images are ``images [N,3,H,W]``)."""
    t0 = time.perf_counter()
    with torch.no_grad():
        out = render(gaussians, camera, background=background)
    t1 = time.perf_counter()
    timings = {"render_ms": 1e3 * (t1 - t0)}
    if improver is None:
        return EnhancedView(out.rgb, out.rgb, out.alpha, out.depth, None, timings)
    if images is None or cameras is None or len(cameras) == 0:
        raise ValueError("enhancing needs the input images and cameras (MORI picks a reference)")
    cameras = list(cameras)
    if images.ndim != 4 or images.shape[0] != len(cameras):
        raise ValueError(
            f"images must be [N,3,H,W] with one image per camera; got {list(images.shape)} for "
            f"{len(cameras)} cameras"
        )
    depth = out.depth if reference_method == "overlap" else None
    ref = select_reference(camera, cameras, method=reference_method, target_depth=depth)
    t2 = time.perf_counter()
    with torch.no_grad():
        image = enhance(improver, out.rgb, camera, images[ref], cameras[ref], dtype)
    t3 = time.perf_counter()
    timings.update(mori_ms=1e3 * (t2 - t1), enhance_ms=1e3 * (t3 - t2))
    return EnhancedView(image.to(out.rgb.device), out.rgb, out.alpha, out.depth, ref, timings)
