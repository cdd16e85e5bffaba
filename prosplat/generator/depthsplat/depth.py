"""The depth predictor (DepthSplat's ``depth_predictor``): CNN + multi-view transformer
features, a plane-sweep cost volume, DINOv2 monocular features, a U-Net regressor with a
softmax over inverse-depth candidates per scale, and a DPT upsampler to full resolution.

All depths are handled as inverse depth inside; the output is depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.generator.depthsplat.backbone import CNNBackbone
from prosplat.generator.depthsplat.config import DepthSplatConfig
from prosplat.generator.depthsplat.cost_volume import correlation_volume
from prosplat.generator.depthsplat.dpt import DPTHead
from prosplat.generator.depthsplat.ops import cat_channels
from prosplat.generator.depthsplat.pyramid import FeaturePyramid
from prosplat.generator.depthsplat.transformer import (
    MultiViewTransformer,
    add_window_position,
    gather_views,
)
from prosplat.generator.depthsplat.unet import UNet
from prosplat.generator.depthsplat.vit import DinoViT

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass
class DepthFeatures:
    """What the Gaussian head reuses from the depth predictor (N = B*V, b-major)."""

    depth: Tensor  # [B,V,H,W] final depth
    match_prob: Tensor  # [N,D,h,w] the last scale's candidate probabilities
    vit_taps: list[Tensor]  # 4 x [N,vit_dim,H/8,W/8]
    cnn: list[Tensor]  # [64ch, 96ch, 128ch] high to low resolution
    mv: list[Tensor]  # multi-view features per scale, low to high resolution


def bilinear(x: Tensor, size=None, scale=None) -> Tensor:
    if size is not None:
        return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=True)
    return F.interpolate(x, scale_factor=scale, mode="bilinear", align_corners=True)


class DepthPredictor(nn.Module):
    def __init__(self, cfg: DepthSplatConfig):
        super().__init__()
        self.cfg = cfg
        vit = cfg.vit
        fc = cfg.feature_channels
        self.backbone = CNNBackbone(fc, cfg.lowest_feature_resolution)
        self.transformer = MultiViewTransformer(fc, cfg.num_transformer_layers)
        if cfg.num_scales > 1:
            self.mv_pyramid = FeaturePyramid(fc, cfg.num_scales)
        self.pretrained = DinoViT(vit.dim, vit.depth, vit.heads)
        if cfg.num_scales > 1:
            self.mono_pyramid = FeaturePyramid(vit.dim, cfg.num_scales)
        self.regressor = nn.ModuleList()
        self.regressor_residual = nn.ModuleList()
        self.depth_head = nn.ModuleList()
        mult: tuple[int, ...] = (1, 1, 1)
        attn_at: tuple[int, ...] = (4,)
        for i in range(cfg.num_scales):
            d = cfg.num_depth_candidates // 4**i
            cin = d + (128 - 32 * i) + fc // 2**i + vit.dim // 2**i
            ch = cfg.depth_unet_channels // 2**i
            if i > 0:
                mult = mult + (1,)
                attn_at = tuple(2 * a for a in attn_at)
            self.regressor.append(
                nn.Sequential(
                    nn.Conv2d(cin, ch, 3, 1, 1),
                    nn.GroupNorm(8, ch),
                    nn.GELU(),
                    UNet(ch, mult, attn_at),
                    nn.Conv2d(ch, ch, 3, 1, 1),
                )
            )
            self.regressor_residual.append(nn.Conv2d(cin, ch, 1))
            self.depth_head.append(
                nn.Sequential(
                    nn.Conv2d(ch, 2 * ch, 3, 1, 1, padding_mode="replicate"),
                    nn.GELU(),
                    nn.Conv2d(2 * ch, d, 3, 1, 1, padding_mode="replicate"),
                )
            )
        self.upsampler = DPTHead(
            vit.dim,
            vit.depth_dpt_features,
            vit.dpt_out,
            cfg.upsample_factor,
            cfg.num_scales,
            with_depth=True,
        )

    def forward(
        self,
        images: Tensor,
        K_norm: Tensor,
        c2w: Tensor,
        near: Tensor,
        far: Tensor,
        index: Tensor | None,
    ) -> DepthFeatures:
        """images [B,V,3,H,W] in [0,1]; K_norm [B,V,3,3] normalised by W and H; c2w [B,V,4,4];
        near, far [B,V]; index: neighbour table [B,V,M] or None (all other views)."""
        cfg = self.cfg
        b, v, _, h, w = images.shape
        mean = images.new_tensor(IMAGENET_MEAN).view(3, 1, 1)
        std = images.new_tensor(IMAGENET_STD).view(3, 1, 1)
        x = ((images - mean) / std).flatten(0, 1)  # [N,3,H,W]
        x = x.contiguous(memory_format=torch.channels_last)  # convs run faster channels-last
        K = K_norm.clone()
        K[:, :, 0] = K[:, :, 0] * w
        K[:, :, 1] = K[:, :, 1] * h
        inv_lo = (1.0 / far).reshape(-1)  # [N] smallest inverse depth
        inv_hi = (1.0 / near).reshape(-1)

        cnn = self.backbone(x)  # high to low
        coarse = cnn[::-1][: cfg.num_scales]  # low to high, one per scale

        # multi-view transformer at the coarsest scale
        f = add_window_position(coarse[0], cfg.multiview_trans_attn_split)
        f = f.view(b, v, *f.shape[1:])
        mv0 = self.transformer(f, cfg.multiview_trans_attn_split, index).flatten(
            0, 1
        )  # [N,128,h,w]
        mv = self.mv_pyramid(mv0) if cfg.num_scales > 1 else [mv0]

        # monocular features
        h14, w14 = h // 14 * 14, w // 14 * 14
        taps = self.pretrained.intermediate(bilinear(x, size=(h14, w14)), cfg.vit.taps)
        taps = [bilinear(t, size=(h // 8, w // 8)) for t in taps]  # [N,vit,H/8,W/8]
        mono = taps[-1]
        if cfg.lowest_feature_resolution == 4:
            mono = bilinear(mono, scale=2)
        monos = self.mono_pyramid(mono) if cfg.num_scales > 1 else [mono]

        inv_depth = None
        match_prob = None
        c2w_n = c2w  # [B,V,4,4]
        for s in range(cfg.num_scales):
            factor = cfg.upsample_factor * 2 ** (cfg.num_scales - 1 - s)
            feats = mv[s]  # [N,C,hs,ws]
            n, c, hs, ws = feats.shape
            Ks = K.clone()
            Ks[:, :, :2] = Ks[:, :, :2] / factor
            Ks = Ks.reshape(n, 3, 3)
            tgt = gather_views(feats.view(b, v, c, hs, ws), index).flatten(0, 1)  # [N,M,C,hs,ws]
            tgt_c2w = gather_views(c2w_n, index).flatten(0, 1)  # [N,M,4,4]
            ref_to_tgt = torch.linalg.inv(tgt_c2w) @ c2w_n.reshape(n, 1, 4, 4)
            d = cfg.num_depth_candidates // 4**s
            lin = torch.linspace(0, 1, d, device=x.device, dtype=x.dtype).view(1, d, 1, 1)
            if s == 0:
                cand = inv_lo.view(-1, 1, 1, 1) + lin * (inv_hi - inv_lo).view(
                    -1, 1, 1, 1
                )  # [N,D,1,1]
            else:
                inv_depth = bilinear(inv_depth, scale=2)
                step = ((inv_hi - inv_lo) / (cfg.num_depth_candidates - 1) / 2**s).view(-1, 1, 1, 1)
                lo = (inv_depth - step * (d // 2)).clamp(min=inv_lo.view(-1, 1, 1, 1))
                hi = (inv_depth + step * (d // 2 - 1)).clamp(max=inv_hi.view(-1, 1, 1, 1))
                cand = lo + lin * (hi - lo)  # [N,D,hs,ws]
            K_m = Ks[:, None].expand(n, tgt.shape[1], 3, 3)
            cost = correlation_volume(feats, tgt, Ks, K_m, ref_to_tgt, 1.0 / cand)  # [N,D,hs,ws]
            cat = cat_channels([cost, coarse[s], feats, monos[s]])
            self.regressor[s][3].set_num_views(v)
            out = self.regressor[s](cat) + self.regressor_residual[s](cat)
            match_prob = torch.softmax(self.depth_head[s](out), dim=1)  # [N,D,hs,ws]
            inv_depth = (match_prob * cand).sum(dim=1, keepdim=True)  # [N,1,hs,ws]

        mv_for_dpt = mv[0] if cfg.num_scales == 1 else mv[::-1]
        residual = self.upsampler(taps, cnn, mv_for_dpt, inv_depth)
        inv_full = bilinear(inv_depth, scale=cfg.upsample_factor) + residual
        inv_full = inv_full.clamp(min=inv_lo.view(-1, 1, 1, 1), max=inv_hi.view(-1, 1, 1, 1))
        depth = (1.0 / inv_full[:, 0]).view(b, v, h, w)
        return DepthFeatures(depth, match_prob, taps, cnn, mv)
