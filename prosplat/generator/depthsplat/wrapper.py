"""DepthSplat behind prosplat's generator interface.

``DepthSplatGenerator.forward(images [B,V,3,H,W], K [B,V,3,3] pixels, w2c [B,V,4,4], near,
far) -> GeneratorOutput``, like :class:`prosplat.generator.Generator`, so
``ProSplat.from_pretrained(generator=PATH)`` can use either.

Conversions:
- sizes: DepthSplat needs H and W to be multiples of ``cfg.size_multiple`` (16 or 32). The
  images are resized (bilinear, antialiased) to the nearest such size, or to ``size`` when
  given (e.g. the checkpoint's training resolution), or centre-cropped down to multiples
  with ``mode="crop"``; K is scaled / shifted to match (pixel centres at +0.5, so a resize
  by s maps x to s*x). The Gaussians and depths are those of the resized images.
- cameras: K in pixels -> normalised by W and H; w2c -> camera-to-world; near/far per view.
- Gaussians: DepthSplat gives world covariances R_c R_q S^2 R_q^T R_c^T. Its adapter also
  gives the factors (camera-space scales S and quaternion q, xyzw), so the world rotation is
  the product R_c R_q, turned into a (w, x, y, z) quaternion -- no eigendecomposition of the
  covariance is needed (and none of its sign and ordering ambiguity); the tests check
  R S^2 R^T against the covariance.
- SH: DepthSplat's harmonics [N,3,9] are what its 3DGS rasterizer reads (the 3DGS basis;
  rotated into the world with e3nn's Wigner matrices by the reference, reproduced here), so
  prosplat's ``sh [N,9,3]`` is their transpose: the same colours in prosplat's renderer.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.core.rotations import quat_multiply, rotmat_to_quat
from prosplat.generator.depthsplat.config import LICENCES, DepthSplatConfig
from prosplat.generator.depthsplat.model import DepthSplatEncoder
from prosplat.generator.output import GeneratorOutput


def _per_view(value, b: int, v: int, name: str, like: Tensor) -> Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        t = t.expand(b)
    if t.ndim == 1:
        if t.shape[0] != b:
            raise ValueError(f"{name} must be a number, [B={b}] or [B,V], got {list(t.shape)}")
        t = t[:, None].expand(b, v)
    if tuple(t.shape) != (b, v):
        raise ValueError(f"{name} must be a number, [B={b}] or [B,V], got {list(t.shape)}")
    return t


def fit_size(h: int, w: int, multiple: int, mode: str) -> tuple[int, int]:
    """The model size for an h x w input: nearest multiples ("resize") or the largest
    multiples inside it ("crop"), at least one multiple each."""
    if mode == "resize":
        return max(multiple, round(h / multiple) * multiple), max(
            multiple, round(w / multiple) * multiple
        )
    if mode == "crop":
        if h < multiple or w < multiple:
            raise ValueError(f"images {h}x{w} are smaller than {multiple} px; use mode='resize'")
        return h // multiple * multiple, w // multiple * multiple
    raise ValueError(f"mode must be 'resize' or 'crop', got {mode!r}")


def prepare_views(
    images: Tensor, K: Tensor, size: tuple[int, int], mode: str
) -> tuple[Tensor, Tensor]:
    """images [B,V,3,H,W], K [B,V,3,3] pixels -> at ``size`` (resized or centre-cropped)."""
    b, v, _, h, w = images.shape
    th, tw = size
    if (th, tw) == (h, w):
        return images, K
    K = K.clone()
    if mode == "crop" and th <= h and tw <= w:
        top, left = (h - th) // 2, (w - tw) // 2
        images = images[..., top : top + th, left : left + tw]
        K[..., 0, 2] -= left
        K[..., 1, 2] -= top
        return images, K
    flat = F.interpolate(
        images.flatten(0, 1), size=(th, tw), mode="bilinear", align_corners=False, antialias=True
    )
    K[..., 0, :] *= tw / w
    K[..., 1, :] *= th / h
    return flat.view(b, v, 3, th, tw).clamp(0, 1), K


class DepthSplatGenerator(nn.Module):
    """A loaded :class:`DepthSplatEncoder` with prosplat's generator interface.

    Args:
        encoder: from :func:`~prosplat.generator.depthsplat.load_depthsplat`.
        size: (H, W) to run at (multiples of the configuration's size multiple); None: the
            input size rounded to multiples.
        mode: "resize" (default) or "crop" for inputs that are not multiples.
    """

    kind = "depthsplat"

    def __init__(
        self, encoder: DepthSplatEncoder, size: tuple[int, int] | None = None, mode: str = "resize"
    ):
        super().__init__()
        if encoder.cfg.depth_only:
            raise ValueError(
                "this is a DepthSplat depth checkpoint (depthsplat-depth-*): it predicts depth "
                "only; use a depthsplat-gs-* checkpoint for Gaussians"
            )
        self.encoder = encoder
        m = encoder.cfg.size_multiple
        if size is not None and (size[0] % m or size[1] % m):
            raise ValueError(
                f"size {size} must be multiples of {m} for this DepthSplat configuration"
            )
        self.size = size
        self.mode = mode
        fit_size(m, m, m, mode)  # validates mode

    @property
    def config(self) -> DepthSplatConfig:
        return self.encoder.cfg

    @property
    def licence(self) -> str:
        return LICENCES[self.config.monodepth_vit_type]

    @property
    def device(self) -> torch.device:
        return next(self.encoder.parameters()).device

    @property
    def dtype(self) -> torch.dtype:
        return next(self.encoder.parameters()).dtype

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.encoder.parameters())

    def forward(self, images: Tensor, K: Tensor, w2c: Tensor, near, far) -> GeneratorOutput:
        if images.ndim != 5 or images.shape[2] != 3:
            raise ValueError(f"images must be [B,V,3,H,W], got {list(images.shape)}")
        b, v, _, h, w = images.shape
        dev, dt = self.device, self.dtype
        images, K, w2c = images.to(dev, dt), K.to(dev, dt), w2c.to(dev, dt)
        size = self.size or fit_size(h, w, self.config.size_multiple, self.mode)
        images, K = prepare_views(images, K, size, self.mode)
        th, tw = size
        K_norm = K.clone()
        K_norm[..., 0, :] /= tw
        K_norm[..., 1, :] /= th
        c2w = torch.linalg.inv(w2c)
        near_v = _per_view(near, b, v, "near", images)
        far_v = _per_view(far, b, v, "far", images)
        out = self.encoder.forward_reference(images, K_norm, c2w, near_v, far_v)
        # world rotation = camera rotation * camera-space Gaussian rotation
        q_cam = out["rotations"]  # [B,N,4] xyzw
        q_cam = torch.cat([q_cam[..., 3:], q_cam[..., :3]], dim=-1)  # wxyz
        q_c2w = rotmat_to_quat(c2w[:, :, :3, :3])  # [B,V,4]
        q_c2w = q_c2w[:, :, None].expand(b, v, th * tw, 4).reshape(b, -1, 4)
        quats = F.normalize(quat_multiply(q_c2w, q_cam), dim=-1)
        return GeneratorOutput(
            means=out["means"],
            quats=quats,
            scales=out["scales"],
            opacities=out["opacities"],
            sh=out["harmonics"].transpose(-1, -2),  # [B,N,9,3]
            depths=out["depths"],
            confidence=out["confidence"],
        )
