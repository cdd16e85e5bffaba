"""DepthSplat's encoder: the depth predictor, the DPT feature upsampler, the Gaussian
regressor and head, and the adapter. :meth:`DepthSplatEncoder.forward_reference` speaks
DepthSplat's own conventions; prosplat's cameras go through
:mod:`prosplat.generator.depthsplat.wrapper`."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.depthsplat.adapter import gaussians_from_raw
from prosplat.generator.depthsplat.config import DepthSplatConfig
from prosplat.generator.depthsplat.depth import DepthPredictor
from prosplat.generator.depthsplat.dpt import DPTHead
from prosplat.generator.depthsplat.ops import cat_channels
from prosplat.generator.depthsplat.transformer import neighbour_index


class DepthSplatEncoder(nn.Module):
    """Parameter names equal DepthSplat's ``encoder.*`` keys (without the prefix)."""

    def __init__(self, cfg: DepthSplatConfig):
        super().__init__()
        self.cfg = cfg
        self.depth_predictor = DepthPredictor(cfg)
        if cfg.depth_only:
            return
        vit = cfg.vit
        f = vit.feature_dpt_features
        self.feature_upsampler = DPTHead(
            vit.dim, f, vit.dpt_out, cfg.upsample_factor, cfg.num_scales, with_depth=False
        )
        ch = cfg.gaussian_regressor_channels
        self.gaussian_regressor = nn.Sequential(
            nn.Conv2d(3 + 1 + 1 + f, ch, 3, 1, 1), nn.GELU(), nn.Conv2d(ch, ch, 3, 1, 1)
        )
        g = cfg.num_gaussian_channels
        self.gaussian_head = nn.Sequential(
            nn.Conv2d(ch + 3 + f + 1, g, 3, 1, 1, padding_mode="replicate"),
            nn.GELU(),
            nn.Conv2d(g, g, 3, 1, 1, padding_mode="replicate"),
        )

    def check_inputs(
        self, images: Tensor, intrinsics: Tensor, extrinsics: Tensor, near: Tensor, far: Tensor
    ):
        if images.dim() != 5 or images.shape[2] != 3:
            raise ValueError(f"images must be [B,V,3,H,W], got {tuple(images.shape)}")
        b, v, _, h, w = images.shape
        m = self.cfg.size_multiple
        if h % m or w % m:
            raise ValueError(
                f"image size {h}x{w}: this DepthSplat configuration needs height and width that "
                f"are multiples of {m} (resize or crop; the prosplat wrapper does it for you)"
            )
        if v < 2:
            raise ValueError(f"DepthSplat needs at least 2 views, got {v}")
        for name, t, shape in (
            ("intrinsics", intrinsics, (b, v, 3, 3)),
            ("extrinsics", extrinsics, (b, v, 4, 4)),
            ("near", near, (b, v)),
            ("far", far, (b, v)),
        ):
            if tuple(t.shape) != shape:
                raise ValueError(f"{name} must be {list(shape)}, got {list(t.shape)}")
        if not bool((near > 0).all()) or not bool((far > near).all()):
            raise ValueError("near must be > 0 and far > near for every view")

    def forward_reference(
        self, images: Tensor, intrinsics: Tensor, extrinsics: Tensor, near: Tensor, far: Tensor
    ) -> dict[str, Tensor]:
        """DepthSplat's conventions.

        Args:
            images: [B,V,3,H,W] in [0,1].
            intrinsics: [B,V,3,3], first row divided by W, second by H.
            extrinsics: [B,V,4,4] camera-to-world, OpenCV axes.
            near, far: [B,V].
        Returns:
            depths [B,V,H,W]; and unless depth-only: means [B,N,3], covariances [B,N,3,3],
            harmonics [B,N,3,9], opacities [B,N] (N = V*H*W, view-major then row-major),
            scales [B,N,3] and rotations [B,N,4] (camera space, xyzw), confidence [B,V,H,W].
        """
        self.check_inputs(images, intrinsics, extrinsics, near, far)
        b, v, _, h, w = images.shape
        index = neighbour_index(extrinsics, self.cfg.local_mv_match)
        dp = self.depth_predictor(images, intrinsics, extrinsics, near, far, index)
        if self.cfg.depth_only:
            return {"depths": dp.depth}
        mv = dp.mv[0] if self.cfg.num_scales == 1 else dp.mv[::-1]
        feats = self.feature_upsampler(dp.vit_taps, dp.cnn, mv)  # [N,F,H,W]
        conf = dp.match_prob.max(dim=1, keepdim=True).values
        conf = F.interpolate(conf, size=(h, w), mode="nearest")  # [N,1,H,W]
        img = images.flatten(0, 1).contiguous(memory_format=torch.channels_last)
        depth = dp.depth.reshape(b * v, 1, h, w)
        x = self.gaussian_regressor(cat_channels([img, depth, conf, feats]))
        raw = self.gaussian_head(cat_channels([x, img, feats, conf]))  # [N,37,H,W]
        out = gaussians_from_raw(
            raw.view(b, v, *raw.shape[1:]),
            dp.depth,
            images,
            intrinsics,
            extrinsics,
            self.cfg.gaussian_scale_min,
            self.cfg.gaussian_scale_max,
            self.cfg.sh_degree,
        )
        out["depths"] = dp.depth
        out["confidence"] = conf.view(b, v, h, w)
        return out

    def forward(self, *args, **kwargs):
        return self.forward_reference(*args, **kwargs)
