"""DepthSplat encoder settings, named as in DepthSplat's encoder config, and the table of the
released checkpoints.

Written from a reading of cvg/depthsplat at commit 2dad25a7b9ba7c5537aba08463ef88d8511a06be
(MIT); no code was copied. The released files and their settings come from that commit's
MODEL_ZOO.md, README.md and scripts/.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

REFERENCE_COMMIT = "2dad25a7b9ba7c5537aba08463ef88d8511a06be"


@dataclass(frozen=True)
class ViTSpec:
    """One DINOv2 ViT/14 (the monocular branch) and the DPT widths that go with it."""

    dim: int
    depth: int
    heads: int
    taps: tuple[int, ...]  # blocks whose outputs feed the DPT heads
    dpt_out: tuple[int, int, int, int]  # DPT per-level channels
    depth_dpt_features: int  # the depth upsampler's fusion width
    feature_dpt_features: int  # the Gaussian feature upsampler's fusion width


VIT_SPECS: dict[str, ViTSpec] = {
    "vits": ViTSpec(384, 12, 6, (2, 5, 8, 11), (48, 96, 192, 384), 32, 64),
    "vitb": ViTSpec(768, 12, 12, (2, 5, 8, 11), (96, 192, 384, 768), 48, 96),
    "vitl": ViTSpec(1024, 24, 16, (4, 11, 17, 23), (128, 256, 512, 1024), 64, 128),
}


@dataclass(frozen=True)
class DepthSplatConfig:
    """The encoder's settings (DepthSplat's ``model.encoder.*`` names where they exist).

    ``depth_only`` is a depth checkpoint (``depthsplat-depth-*``): the depth predictor alone,
    no Gaussian head.
    """

    monodepth_vit_type: str = "vits"
    num_scales: int = 1
    upsample_factor: int = 4
    lowest_feature_resolution: int = 4
    gaussian_scale_min: float = 1e-10
    gaussian_scale_max: float = 3.0
    sh_degree: int = 2
    num_depth_candidates: int = 128
    local_mv_match: int = 2
    depth_unet_channels: int = 128
    feature_channels: int = 128
    num_transformer_layers: int = 6
    multiview_trans_attn_split: int = 2
    gaussian_regressor_channels: int = 64
    init_sh_input_img: bool = True
    depth_only: bool = False

    def __post_init__(self):
        if self.monodepth_vit_type not in VIT_SPECS:
            raise ValueError(
                f"monodepth_vit_type={self.monodepth_vit_type!r}: expected one of {sorted(VIT_SPECS)}"
            )
        if self.num_scales not in (1, 2):
            raise ValueError(f"num_scales={self.num_scales}: DepthSplat uses 1 or 2")
        if self.lowest_feature_resolution not in (4, 8):
            raise ValueError(f"lowest_feature_resolution={self.lowest_feature_resolution}: 4 or 8")
        if self.upsample_factor * 2 ** (self.num_scales - 1) != self.lowest_feature_resolution:
            raise ValueError(
                f"upsample_factor={self.upsample_factor} with num_scales={self.num_scales} needs "
                f"lowest_feature_resolution={self.upsample_factor * 2 ** (self.num_scales - 1)}, "
                f"not {self.lowest_feature_resolution}"
            )
        if self.sh_degree != 2:
            raise ValueError("sh_degree: the released checkpoints use 2, the only supported value")

    @property
    def vit(self) -> ViTSpec:
        return VIT_SPECS[self.monodepth_vit_type]

    @property
    def size_multiple(self) -> int:
        """Image height and width must be multiples of this (the U-Net at the coarsest scale
        halves the feature map twice; the windowed attention splits it in two)."""
        return self.lowest_feature_resolution * 4

    @property
    def num_gaussian_channels(self) -> int:
        """opacity (1) + xy offset (2) + scale (3) + rotation (4) + SH (3·(d+1)²)."""
        return 1 + 2 + 3 + 4 + 3 * (self.sh_degree + 1) ** 2

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> DepthSplatConfig:
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown DepthSplat setting(s) {unknown}; known: {sorted(names)}")
        return cls(**d)

    def with_overrides(self, **overrides) -> DepthSplatConfig:
        names = {f.name for f in fields(self)}
        # accept DepthSplat's nested spelling too: gaussian_adapter.gaussian_scale_max
        flat = {k.rsplit(".", 1)[-1]: v for k, v in overrides.items()}
        unknown = sorted(set(flat) - names)
        if unknown:
            raise ValueError(f"unknown DepthSplat setting(s) {unknown}; known: {sorted(names)}")
        return replace(self, **flat)


SMALL = DepthSplatConfig("vits", 1, 4, 4)
SMALL_448 = DepthSplatConfig("vits", 1, 8, 8, gaussian_scale_max=0.1)
BASE = DepthSplatConfig("vitb", 2, 2, 4)
BASE_DL3DV = DepthSplatConfig("vitb", 2, 4, 8)
BASE_448 = DepthSplatConfig("vitb", 2, 4, 8, gaussian_scale_max=0.1)
LARGE = DepthSplatConfig("vitl", 2, 2, 4)

# Released files (MODEL_ZOO.md at the commit above): name prefix -> settings, licence of the
# monocular weights inside, parameters in millions, training resolution.
RELEASED: dict[str, dict] = {
    "depthsplat-gs-small-re10k-256x256-view2-cfeab6b1": dict(config=SMALL, size=(256, 256)),
    "depthsplat-gs-base-re10k-256x256-view2-ca7b6795": dict(config=BASE, size=(256, 256)),
    "depthsplat-gs-large-re10k-256x256-view2-e0f0f27a": dict(config=LARGE, size=(256, 256)),
    "depthsplat-gs-base-re10k-256x448-view2-fea94f65": dict(config=BASE, size=(256, 448)),
    "depthsplat-gs-base-dl3dv-256x448-randview2-6-02c7b19d": dict(
        config=BASE_DL3DV, size=(256, 448)
    ),
    "depthsplat-gs-small-re10kdl3dv-448x768-randview4-10-c08188db": dict(
        config=SMALL_448, size=(448, 768)
    ),
    "depthsplat-gs-base-re10kdl3dv-448x768-randview2-6-f8ddd845": dict(
        config=BASE_448, size=(448, 768)
    ),
    "depthsplat-depth-small-352x640-randview2-8-e807bd82": dict(
        config=replace(SMALL_448, gaussian_scale_max=3.0, depth_only=True), size=(352, 640)
    ),
    "depthsplat-depth-base-352x640-randview2-8-65a892c5": dict(
        config=replace(BASE_DL3DV, depth_only=True), size=(352, 640)
    ),
}

LICENCES = {
    "vits": "MIT (DepthSplat) + Apache-2.0 (Depth Anything V2 ViT-S): commercial use allowed",
    "vitb": "MIT (DepthSplat) + CC-BY-NC-4.0 (Depth Anything V2 ViT-B): non-commercial use only",
    "vitl": "MIT (DepthSplat) + CC-BY-NC-4.0 (Depth Anything V2 ViT-L): non-commercial use only",
}


def released_entry(name: str) -> tuple[str, dict] | None:
    """The table row whose name the file name contains (the sha256 prefix makes it unique)."""
    for key, row in RELEASED.items():
        if key in name or key.rsplit("-", 1)[-1] in name.split("-")[-1]:
            return key, row
    return None
