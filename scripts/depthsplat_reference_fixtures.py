"""Writes tests/fixtures/depthsplat/: runs the reference DepthSplat encoder (cvg/depthsplat at
commit 2dad25a, MIT) with deterministic random weights. Run it OUTSIDE this repository
against your own checkouts (nothing of the reference is kept here):

    git clone <cvg/depthsplat> /tmp/ref/depthsplat && git -C /tmp/ref/depthsplat checkout 2dad25a
    git clone <facebookresearch/dinov2> /tmp/ref/dinov2
    pip install --target /tmp/ref/pydeps --no-deps einops jaxtyping e3nn==0.5.1 opt_einsum opt_einsum_fx
    XFORMERS_DISABLED=1 python scripts/depthsplat_reference_fixtures.py OUT_DIR [layouts|cases]

The reference's dataset/visualisation packages are bypassed (namespace stubs), torchvision
and scipy (imported but unused by the encoder) are stubbed, and torch.hub.load answers from
the local dinov2 copy with pretrained=False."""

# ruff: noqa: E402
import json
import math
import os
import sys
import types

REF = os.environ.get("DEPTHSPLAT_REF", "/tmp/ref")
sys.path[:0] = [REF + "/pydeps", REF + "/depthsplat"]
import torch

ROOT = REF + "/depthsplat/src"
for name, path in (
    ("src", ROOT),
    ("src.model", ROOT + "/model"),
    ("src.model.encoder", ROOT + "/model/encoder"),
    ("src.dataset", ROOT + "/dataset"),
    ("src.misc", ROOT + "/misc"),
):
    m = types.ModuleType(name)
    m.__path__ = [path]
    sys.modules[name] = m
for stub in ("torchvision", "torchvision.transforms", "scipy", "scipy.signal"):
    sys.modules[stub] = types.ModuleType(stub)
sys.modules["torchvision"].transforms = sys.modules["torchvision.transforms"]
sys.modules["scipy"].signal = sys.modules["scipy.signal"]

_hub_load = torch.hub.load


def local_hub(repo, name, *a, **k):
    return _hub_load(REF + "/dinov2", name, source="local", pretrained=False)


torch.hub.load = local_hub

from src.model.encoder.common.gaussian_adapter import GaussianAdapterCfg
from src.model.encoder.encoder_depthsplat import EncoderDepthSplat, EncoderDepthSplatCfg
from src.model.encoder.visualization.encoder_visualizer_depthsplat_cfg import (
    EncoderVisualizerDepthSplatCfg,
)


def make_cfg(vit, ns, up, low, scale_max=3.0, depth_only=False):
    return EncoderDepthSplatCfg(
        name="depthsplat",
        d_feature=128,
        num_depth_candidates=128,
        num_surfaces=1,
        visualizer=EncoderVisualizerDepthSplatCfg(8, 256, False),
        gaussian_adapter=GaussianAdapterCfg(1e-10, scale_max, 2),
        gaussians_per_pixel=1,
        unimatch_weights_path=None,
        downscale_factor=4,
        shim_patch_size=4,
        multiview_trans_attn_split=2,
        costvolume_unet_feat_dim=128,
        costvolume_unet_channel_mult=[1, 1, 1],
        costvolume_unet_attn_res=[],
        depth_unet_feat_dim=64,
        depth_unet_attn_res=[],
        depth_unet_channel_mult=[1, 1, 1],
        num_scales=ns,
        upsample_factor=up,
        lowest_feature_resolution=low,
        depth_unet_channels=128,
        grid_sample_disable_cudnn=False,
        large_gaussian_head=False,
        color_large_unet=False,
        init_sh_input_img=True,
        feature_upsampler_channels=64,
        gaussian_regressor_channels=64,
        supervise_intermediate_depth=True,
        return_depth=True,
        train_depth_only=depth_only,
        monodepth_vit_type=vit,
        local_mv_match=2,
    )


def fill(module, seed):
    """The recipe: one torch.Generator seeded with `seed`; state-dict keys in sorted order;
    each floating tensor = randn(shape) / sqrt(fan_in), fan_in = prod(shape[1:]) for ndim > 1,
    shape[0] for ndim == 1 (and 1 for 0-d)."""
    g = torch.Generator().manual_seed(seed)
    sd = module.state_dict()
    new = {}
    for k in sorted(sd):
        t = sd[k]
        if not t.is_floating_point():
            new[k] = t
            continue
        fan = math.prod(t.shape[1:]) if t.dim() > 1 else (t.shape[0] if t.dim() == 1 else 1)
        new[k] = torch.randn(t.shape, generator=g, dtype=torch.float32) / math.sqrt(fan)
    module.load_state_dict(new, strict=True)


def make_inputs(seed, b, v, h, w):
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(b, v, 3, h, w, generator=g)
    K = torch.zeros(b, v, 3, 3)
    f = 0.8 + 0.4 * torch.rand(b, v, 2, generator=g)
    K[..., 0, 0] = f[..., 0] * (h / w) ** 0  # normalised fx (by width)
    K[..., 1, 1] = f[..., 1]
    K[..., 0, 2] = 0.5 + 0.05 * (torch.rand(b, v, generator=g) - 0.5)
    K[..., 1, 2] = 0.5 + 0.05 * (torch.rand(b, v, generator=g) - 0.5)
    K[..., 2, 2] = 1
    # cameras on an arc around the origin looking at it, distinct distances between centres
    E = torch.zeros(b, v, 4, 4)
    E[..., 3, 3] = 1
    for bi in range(b):
        for vi in range(v):
            ang = (vi - (v - 1) / 2) * 0.35 + 0.1 * float(torch.rand((), generator=g))
            rad = 3.0 + 0.3 * float(torch.rand((), generator=g))
            eye = torch.tensor(
                [
                    rad * math.sin(ang),
                    0.3 * float(torch.randn((), generator=g)),
                    -rad * math.cos(ang),
                ]
            )
            z = -eye / eye.norm()
            x = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0]), z)
            x = x / x.norm()
            y = torch.linalg.cross(z, x)
            E[bi, vi, :3, :3] = torch.stack([x, y, z], dim=1)
            E[bi, vi, :3, 3] = eye
    near = 1.0 + 0.2 * torch.rand(b, v, generator=g)
    far = 8.0 + 2.0 * torch.rand(b, v, generator=g)
    return images, K, E, near, far


CONFIGS = {
    "small": make_cfg("vits", 1, 4, 4),
    "small_448": make_cfg("vits", 1, 8, 8, 0.1),
    "base": make_cfg("vitb", 2, 2, 4),
    "base_448": make_cfg("vitb", 2, 4, 8, 0.1),
    "large": make_cfg("vitl", 2, 2, 4),
    "depth_small": make_cfg("vits", 1, 8, 8, 3.0, True),
    "depth_base": make_cfg("vitb", 2, 4, 8, 3.0, True),
}

CASES = [  # name, config, views, h, w, weight seed, input seed
    ("small_v2_64x64", "small", 2, 64, 64, 1, 11),
    ("small_v4_64x64", "small", 4, 64, 64, 2, 12),
    ("small_v3_64x96", "small", 3, 64, 96, 3, 13),
    ("small448_v2_64x96", "small_448", 2, 64, 96, 4, 14),
    ("base_v2_64x64", "base", 2, 64, 64, 5, 15),
    ("base448_v4_64x96", "base_448", 4, 64, 96, 6, 16),
]

if __name__ == "__main__":
    from safetensors.torch import save_file

    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    what = sys.argv[2] if len(sys.argv) > 2 else "all"
    if what in ("all", "layouts"):
        layouts = {}
        for name, cfg in CONFIGS.items():
            enc = EncoderDepthSplat(cfg)
            sd = enc.state_dict()
            layouts[name] = {k: list(t.shape) for k, t in sorted(sd.items())}
            print(name, len(sd), sum(t.numel() for t in sd.values()) / 1e6)
            del enc
        with open(os.path.join(out, "layouts.json"), "w") as fh:
            json.dump(layouts, fh, indent=0, sort_keys=True)
    if what in ("all", "cases"):
        torch.set_grad_enabled(False)
        for name, cfg_name, v, h, w, wseed, iseed in CASES:
            if len(sys.argv) > 3 and name not in sys.argv[3:]:
                continue
            enc = EncoderDepthSplat(CONFIGS[cfg_name]).eval()
            fill(enc, wseed)
            images, K, E, near, far = make_inputs(iseed, 1, v, h, w)
            res = enc(
                {"image": images, "intrinsics": K, "extrinsics": E, "near": near, "far": far},
                global_step=0,
            )
            gs = res["gaussians"]
            n = gs.means.shape[1]
            idx = torch.arange(0, n, 7)  # every 7th Gaussian keeps the file small
            tensors = {
                "images": images,
                "intrinsics": K,
                "extrinsics": E,
                "near": near,
                "far": far,
                "depths": res["depths"].contiguous(),
                "index": idx,
                "means": gs.means[:, idx].contiguous(),
                "covariances": gs.covariances[:, idx].contiguous(),
                "harmonics": gs.harmonics[:, idx].contiguous(),
                "opacities": gs.opacities[:, idx].contiguous(),
            }
            meta = {
                "config": cfg_name,
                "weight_seed": str(wseed),
                "reference_commit": "2dad25a7b9ba7c5537aba08463ef88d8511a06be",
            }
            save_file(tensors, os.path.join(out, f"{name}.safetensors"), metadata=meta)
            print(
                name,
                {k: tuple(t.shape) for k, t in tensors.items()},
                float(res["depths"].min()),
                float(res["depths"].max()),
            )
