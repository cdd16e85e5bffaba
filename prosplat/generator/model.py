"""The stage-1 generator: posed images -> pixel-aligned 3D Gaussians in one forward pass.

DepthSplat-style (ProSplat paper, Sec. III-B): per-view CNN features refined by cross-view
attention build a plane-sweep cost volume against each view's nearest views; a monocular branch
adds single-view cues; a U-Net turns both into a per-pixel depth distribution, which is
upsampled to full resolution, and an adapter turns every pixel into a Gaussian on its ray.
Optional, grown into trained weights: a second cost volume of the input images' own ZNCC
beside the learned one (``image_matching_window``), and a learned depth sweep in a band around
the refined depth (``band_candidates``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.adapter import GaussianAdapter
from prosplat.generator.band import BandRefiner
from prosplat.generator.config import SIZE_MULTIPLE, TINY, GeneratorConfig
from prosplat.generator.cost_volume import (
    inverse_depth_candidates,
    nearest_views,
    plane_sweep_cost_volume,
    scale_intrinsics,
)
from prosplat.generator.depth_head import DepthHead, DepthRefiner
from prosplat.generator.encoder import FeatureEncoder
from prosplat.generator.image_cost import image_cost_volume
from prosplat.generator.monocular import MonocularBranch
from prosplat.generator.output import GeneratorOutput


def _per_scene(value, b: int, name: str, like: Tensor) -> Tensor:
    """A float, 0-d or [B] tensor -> [B] tensor of ``like``'s dtype/device."""
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        t = t.expand(b)
    if tuple(t.shape) != (b,):
        raise ValueError(
            f"Generator: {name} must be a number or have shape [B={b}], got {list(t.shape)}"
        )
    return t


class Generator(nn.Module):
    """``forward(images [B,V,3,H,W], K [B,V,3,3], w2c [B,V,4,4], near [B], far [B])``.

    Images are in [0, 1]; K in pixels of the given image size; w2c OpenCV world-to-camera;
    near/far bound the depth of everything that should become Gaussians (scene units).
    Any V in [2, config.max_views]; H and W multiples of 32.
    """

    def __init__(self, config: GeneratorConfig = TINY) -> None:
        super().__init__()
        if not isinstance(config, GeneratorConfig):
            raise ValueError(f"Generator needs a GeneratorConfig, got {type(config).__name__}")
        self.config = config
        c = config
        self.encoder = FeatureEncoder(
            c.feature_channels,
            c.attention_layers,
            c.attention_heads,
            c.attention_splits,
            c.attention_mlp_ratio,
            c.fine_matching_channels,
        )
        self.monocular = MonocularBranch(c.mono_channels, c.mono_blocks, c.alexnet_layers)
        self.depth_head = DepthHead(
            c.num_depth_candidates,
            c.mono_channels,
            c.feature_channels,
            c.unet_channels,
            fine_cost=c.fine_matching_channels > 0,
            image_cost=c.image_matching_window > 0,
        )
        self.refiner = DepthRefiner(c.unet_channels[0], c.refine_channels)
        self.band = BandRefiner(c.band_candidates, c.refine_channels) if c.band_candidates else None
        self.adapter = GaussianAdapter(
            c.refine_channels,
            c.sh_degree,
            c.scale_factor_min,
            c.scale_factor_max,
            c.max_offset_px,
        )

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    @property
    def dtype(self) -> torch.dtype:
        return next(self.parameters()).dtype

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    # ---- validation -----------------------------------------------------------------------
    def _validate(self, images, K, w2c, near, far) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        for name, value in (("images", images), ("K", K), ("w2c", w2c)):
            if not isinstance(value, Tensor):
                raise ValueError(
                    f"Generator: {name} must be a torch.Tensor, got {type(value).__name__}"
                )
        if images.ndim != 5 or images.shape[2] != 3:
            raise ValueError(
                f"Generator: images must be [B,V,3,H,W] RGB, got {list(images.shape)}; "
                "add the batch dimension with images[None]"
            )
        b, v, _, h, w = images.shape
        if v < 2:
            raise ValueError(
                f"Generator needs at least 2 input views (the cost volume matches views), got {v}"
            )
        if v > self.config.max_views:
            raise ValueError(
                f"Generator accepts at most {self.config.max_views} views (config.max_views), got {v}; "
                "pick the views nearest the region of interest"
            )
        if h < SIZE_MULTIPLE or w < SIZE_MULTIPLE or h % SIZE_MULTIPLE or w % SIZE_MULTIPLE:
            fix_w = max(SIZE_MULTIPLE, round(w / SIZE_MULTIPLE) * SIZE_MULTIPLE)
            fix_h = max(SIZE_MULTIPLE, round(h / SIZE_MULTIPLE) * SIZE_MULTIPLE)
            raise ValueError(
                f"Generator: image size {w}x{h} must be a multiple of {SIZE_MULTIPLE} in both axes; "
                f"resize (scaling K with Camera.resized) or crop to e.g. {fix_w}x{fix_h}"
            )
        if tuple(K.shape) != (b, v, 3, 3):
            raise ValueError(
                f"Generator: K must be [B={b},V={v},3,3] to match images, got {list(K.shape)}"
            )
        if tuple(w2c.shape) != (b, v, 4, 4):
            raise ValueError(
                f"Generator: w2c must be [B={b},V={v},4,4] to match images, got {list(w2c.shape)}"
            )
        dt, dev = self.dtype, self.device
        images, K, w2c = (x.to(device=dev, dtype=dt) for x in (images, K, w2c))
        near, far = _per_scene(near, b, "near", images), _per_scene(far, b, "far", images)
        for name, value in (
            ("images", images),
            ("K", K),
            ("w2c", w2c),
            ("near", near),
            ("far", far),
        ):
            if not torch.isfinite(value).all():
                raise ValueError(f"Generator: {name} contains NaN or Inf")
        if not ((K[..., 0, 0] > 0) & (K[..., 1, 1] > 0)).all():
            raise ValueError("Generator: K focal lengths must be positive (K is in pixels)")
        bottom = w2c.new_tensor([0.0, 0.0, 0.0, 1.0])
        R = w2c[..., :3, :3]
        eye = torch.eye(3, dtype=dt, device=dev)
        if not torch.allclose(
            w2c[..., 3, :], bottom.expand_as(w2c[..., 3, :])
        ) or not torch.allclose(R @ R.transpose(-1, -2), eye.expand_as(R), atol=1e-3):
            raise ValueError(
                "Generator: w2c must be rigid world-to-camera matrices (orthonormal rotation, last row "
                "[0,0,0,1]); remove scale from the camera poses"
            )
        if not (near > 0).all():
            raise ValueError(
                f"Generator: near must be > 0 (depth along the optical axis), got {near.tolist()}"
            )
        if not (near < far).all():
            raise ValueError(
                f"Generator: near must be < far, got near={near.tolist()}, far={far.tolist()}; "
                "pass the scene's depth range"
            )
        return images, K, w2c, near, far

    def cost_volume(
        self, feats: Tensor, K: Tensor, w2c: Tensor, near: Tensor, far: Tensor, image_size
    ) -> Tensor:
        """Plane-sweep correlation of ``feats [B,V,C,h,w]`` against each view's nearest views.

        ``K [B,V,3,3]`` is for the full ``image_size (H, W)`` and is scaled here to the feature
        resolution; candidates are uniform in inverse depth over [near, far] ([B] each).
        Returns [B,V,D,h,w]."""
        h, w = image_size
        hf, wf = feats.shape[-2:]
        K_feat = scale_intrinsics(K, wf / w, hf / h)  # [B,V,3,3] at feature resolution
        neighbours = nearest_views(w2c, self.config.cost_volume_views)  # [B,V,k]
        candidates = inverse_depth_candidates(near, far, self.config.num_depth_candidates)  # [B,D]
        return plane_sweep_cost_volume(feats, K_feat, w2c, candidates, neighbours)

    def image_cost(
        self, x: Tensor, K: Tensor, w2c: Tensor, near: Tensor, far: Tensor, image_size
    ) -> Tensor:
        """The images' own ZNCC plane sweep (:mod:`prosplat.generator.image_cost`) over the
        cost volume's candidates and neighbours, at half the matching size: ``x
        [B,V,3,Hm,Wm]`` in [-1, 1] (the matching size), ``K`` for the full ``image_size (H,
        W)`` -> [B,V,D,Hm/4,Wm/4]. Half size: on the validation scenes its peaks are nearly
        as often right as at the full size (within 1.5 planes of the truth for 26-29 % of
        pixels, against 31 %) at a fifth of the time."""
        h, w = image_size
        b, v = x.shape[:2]
        hh, wh = x.shape[-2] // 2, x.shape[-1] // 2
        half = F.interpolate(
            x.flatten(0, 1), size=(hh, wh), mode="bilinear", antialias=True, align_corners=False
        )  # [BV,3,Hm/2,Wm/2]
        half = ((half + 1) / 2).clamp(0, 1).view(b, v, 3, hh, wh)
        K_half = scale_intrinsics(K, wh / w, hh / h)  # [B,V,3,3] at half the matching size
        neighbours = nearest_views(w2c, self.config.cost_volume_views)  # [B,V,k]
        candidates = inverse_depth_candidates(near, far, self.config.num_depth_candidates)
        window = self.config.image_matching_window
        return image_cost_volume(half, K_half, w2c, candidates, neighbours, window, pool=2)

    def _band_t(
        self,
        xm: Tensor,
        t: Tensor,
        rfeat: Tensor,
        K: Tensor,
        w2c: Tensor,
        inv_near: Tensor,
        inv_far: Tensor,
        image_size,
    ) -> Tensor:
        """The learned depth sweep (:mod:`prosplat.generator.band`) on the refiner's ``t
        [BV,1,Hm,Wm]``: to depth, moved within the band, back to t. ``xm [B,V,3,Hm,Wm]`` in
        [-1, 1], ``rfeat [BV,R,Hm,Wm]``, ``K`` for the full ``image_size (H, W)``,
        ``inv_near``/``inv_far`` [BV,1,1,1]."""
        h, w = image_size
        b, v, _, hm, wm = xm.shape
        depth = 1.0 / (inv_far + t * (inv_near - inv_far))  # [BV,1,Hm,Wm]
        depth = self.band(
            (xm + 1) / 2,
            depth.view(b, v, hm, wm),
            rfeat,
            scale_intrinsics(K, wm / w, hm / h),
            w2c,
            nearest_views(w2c, self.config.cost_volume_views),
        ).view(b * v, 1, hm, wm)
        return ((1.0 / depth - inv_far) / (inv_near - inv_far)).clamp(0, 1)

    def _match_images(self, x: Tensor, match_size: tuple[int, int]) -> Tensor:
        """x [B,V,3,H,W] -> [B,V,3,Hm,Wm], antialiased bilinear (as :func:`resize_views`)."""
        hm, wm = (int(s) for s in match_size)
        h, w = x.shape[-2:]
        if hm % SIZE_MULTIPLE or wm % SIZE_MULTIPLE or not (0 < hm <= h and 0 < wm <= w):
            raise ValueError(
                f"Generator: match_size {wm}x{hm} must be multiples of {SIZE_MULTIPLE} no larger "
                f"than the images ({w}x{h})"
            )
        if (hm, wm) == (h, w):
            return x
        b, v = x.shape[:2]
        xm = F.interpolate(
            x.flatten(0, 1), size=(hm, wm), mode="bilinear", antialias=True, align_corners=False
        )
        return xm.clamp(-1, 1).view(b, v, 3, hm, wm)

    # ---- forward ----------------------------------------------------------------------------
    def forward(
        self,
        images: Tensor,
        K: Tensor,
        w2c: Tensor,
        near,
        far,
        match_size: tuple[int, int] | None = None,
    ) -> GeneratorOutput:
        """``match_size (Hm, Wm)``, multiples of 32 no larger than the images: the network up
        to the depth refiner sees the images resized to it (antialiased); its per-pixel maps
        (depth, confidence, features) are then upsampled bilinearly to the images' size, where
        the adapter (1x1 convolutions) gives every input pixel its Gaussian with that pixel's
        own colour and footprint. Why: what a model trained at one size does not carry to
        another is its matching (the cost volume's disparities and the U-Net's receptive field
        are in pixels), while the colour and the footprint gain from the full-size pixels
        (BENCHMARKS.md, "Gaussians at the inputs' size": running the refiner at the full size
        instead was worse than both). None: everything at the images' size."""
        images, K, w2c, near, far = self._validate(images, K, w2c, near, far)
        cfg = self.config
        b, v, _, h, w = images.shape

        x = images * 2 - 1  # [B,V,3,H,W] in [-1,1]
        xm = x if match_size is None else self._match_images(x, match_size)  # [B,V,3,Hm,Wm]
        feats, fine = self.encoder(xm)  # [B,V,C,Hm/4,Wm/4] multi-view, [B,V,Cf,Hm/2,Wm/2] / None
        mono = self.monocular(xm.flatten(0, 1))  # [BV,Cm,Hm/4,Wm/4]

        cost = self.cost_volume(feats, K, w2c, near, far, (h, w))  # [B,V,D,Hm/4,Wm/4]
        fine_cost = None
        if fine is not None:
            fine_cost = self.cost_volume(fine, K, w2c, near, far, (h, w)).flatten(0, 1)
        image_cost = None
        if cfg.image_matching_window:
            image_cost = self.image_cost(xm, K, w2c, near, far, (h, w)).flatten(0, 1)

        t, conf, hidden, logits = self.depth_head(
            cost.flatten(0, 1), mono, feats.flatten(0, 1), fine_cost, image_cost
        )  # [BV,1,Hm/4,Wm/4] x2, [BV,U0,Hm/4,Wm/4], [BV,D,Hm/4,Wm/4]
        t, conf, rfeat = self.refiner(
            xm.flatten(0, 1), t, conf, hidden
        )  # [BV,1,Hm,Wm] x2, [BV,R,Hm,Wm]
        inv_near = (1.0 / near).repeat_interleave(v)[:, None, None, None]  # [BV,1,1,1]
        inv_far = (1.0 / far).repeat_interleave(v)[:, None, None, None]
        if self.band is not None:  # the learned depth sweep, at the matching size
            t = self._band_t(xm, t, rfeat, K, w2c, inv_near, inv_far, (h, w))
        if tuple(t.shape[-2:]) != (h, w):  # matched smaller: to the inputs' size
            maps = F.interpolate(
                torch.cat([t, conf, rfeat], 1), size=(h, w), mode="bilinear", align_corners=False
            )  # [BV,2+R,H,W]
            t, conf, rfeat = maps[:, :1], maps[:, 1:2], maps[:, 2:]

        depth = 1.0 / (
            inv_far[:, 0] + t[:, 0] * (inv_near - inv_far)[:, 0]
        )  # [BV,H,W] in (near, far)

        g = self.adapter(
            rfeat, conf, images.flatten(0, 1), depth, K.flatten(0, 1), w2c.flatten(0, 1)
        )  # per-pixel [BV,H,W,...]
        n = v * h * w
        return GeneratorOutput(
            means=g.means.reshape(b, n, 3),
            quats=g.quats.reshape(b, n, 4),
            scales=g.scales.reshape(b, n, 3),
            opacities=g.opacities.reshape(b, n),
            sh=g.sh.reshape(b, n, cfg.sh_coefficients, 3),
            depths=depth.view(b, v, h, w),
            confidence=conf.view(b, v, h, w),
            depth_logits=logits.view(b, v, *logits.shape[1:]),
        )
