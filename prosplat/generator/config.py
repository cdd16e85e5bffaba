"""Hyper-parameters of the stage-1 generator (DepthSplat-style), with a CPU and a GPU preset.

The config travels with the weights: :meth:`GeneratorConfig.to_dict` is stored as a JSON string
in the safetensors metadata, so a checkpoint always rebuilds the network it was trained as.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any

#: Images must be a multiple of this: 1/4-resolution features, then three U-Net halvings.
SIZE_MULTIPLE = 32

#: The most AlexNet layers ``alexnet_layers`` can take: relu3 is at 1/16 of the image, the
#: coarsest level the 1/4-resolution depth head can still place (3x3 maps at 64 px).
MAX_ALEXNET_LAYERS = 3


@dataclass(frozen=True)
class GeneratorConfig:
    """Every size and bound of the generator.

    Attributes:
        feature_channels: channels of the matching features (1/4 resolution) that feed the
            cross-view transformer and the cost volume.
        num_depth_candidates: D, plane-sweep candidates uniformly spaced in inverse depth.
        attention_layers: cross-view transformer layers (each: window self-attention,
            cross-attention to the same window in the other views, MLP).
        attention_heads: heads per attention; must divide ``feature_channels``.
        attention_splits: the 1/4-resolution map is cut into ``splits x splits`` windows
            (Swin-style, shifted by half a window on odd layers); attention stays inside a
            window, which is what keeps it cheap. Must divide 8 (sizes are multiples of 32).
        attention_mlp_ratio: hidden width of the transformer MLP relative to the channels.
        cost_volume_views: k, the nearest views (by camera-centre distance) that each view
            matches against; with fewer other views, all of them are used.
        fine_matching_channels: channels of the 1/2-resolution matching features; > 0 adds a
            second plane-sweep cost volume at 1/2 resolution (over the same candidates) to the
            depth head, so that a wide baseline, whose disparities span many 1/4-resolution
            cells, still finds a sharp peak. 0 (v1 weights) leaves it out.
        image_matching_window: > 0 adds a plane sweep of the input images themselves to the
            depth head: the ZNCC of this many pixels square (odd, at half the matching size)
            against the neighbours at every candidate, averaged to 1/4 resolution
            (:mod:`prosplat.generator.image_cost`),
            because the learned features cannot rank depths a few planes apart and the pixels
            can. 0 (v1-v12 weights) leaves it out.
        band_candidates: > 0 adds a learned depth sweep after the depth refiner: this many
            depths in a ±30 % band around each pixel's depth, scored by the images' ZNCC
            against the neighbours, read by a small conv net that moves the depth within the
            band (:mod:`prosplat.generator.band`). 0 (v1-v12 weights) leaves it out.
        mono_channels: channels of the monocular branch (stands in for DepthSplat's ViT).
        mono_blocks: residual blocks in the monocular branch (dilations cycle 1, 2, 4).
        alexnet_layers: 1-3 adds AlexNet's relu1..relu<n> maps (the LPIPS backbone, frozen,
            stored in the weights file) to the monocular branch
            (:mod:`prosplat.generator.alexnet`); 0 (v1-v5 weights) leaves them out.
        unet_channels: U-Net channels per level (level 0 at 1/4 resolution, each next level
            halves the resolution); three or more levels.
        refine_channels: channels of the full-resolution refinement network whose features
            also feed the Gaussian adapter.
        sh_degree: spherical-harmonic degree of the Gaussians (0-3).
        scale_factor_min, scale_factor_max: bounds of the learned factor that multiplies the
            pixel footprint ``depth / f`` to give a Gaussian's scale (geometric-mean init, 1.0
            for the default bounds).
        max_offset_px: bound on the learned sub-pixel offset of each Gaussian's centre.
        max_views: the most input views the generator accepts (attention and cost-volume memory
            grow with it).
    """

    feature_channels: int = 48
    num_depth_candidates: int = 32
    attention_layers: int = 2
    attention_heads: int = 2
    attention_splits: int = 2
    attention_mlp_ratio: int = 2
    cost_volume_views: int = 3
    fine_matching_channels: int = 0
    image_matching_window: int = 0
    band_candidates: int = 0
    mono_channels: int = 32
    mono_blocks: int = 3
    alexnet_layers: int = 0
    unet_channels: tuple[int, ...] = (32, 40, 48, 64)
    refine_channels: int = 16
    sh_degree: int = 0
    scale_factor_min: float = 0.25
    scale_factor_max: float = 4.0
    max_offset_px: float = 0.5
    max_views: int = 6

    def __post_init__(self) -> None:
        object.__setattr__(self, "unet_channels", tuple(int(c) for c in self.unet_channels))
        positive = (
            "feature_channels",
            "attention_heads",
            "attention_splits",
            "attention_mlp_ratio",
            "cost_volume_views",
            "mono_channels",
            "refine_channels",
        )
        for name in positive:
            if int(getattr(self, name)) < 1:
                raise ValueError(f"GeneratorConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.num_depth_candidates < 2:
            raise ValueError(
                f"GeneratorConfig.num_depth_candidates must be >= 2, got {self.num_depth_candidates}"
            )
        if self.attention_layers < 0 or self.mono_blocks < 0 or self.fine_matching_channels < 0:
            raise ValueError(
                "GeneratorConfig.attention_layers, mono_blocks and fine_matching_channels must be >= 0"
            )
        if self.image_matching_window < 0 or (
            self.image_matching_window and self.image_matching_window % 2 == 0
        ):
            raise ValueError(
                "GeneratorConfig.image_matching_window must be 0 (off) or odd, got "
                f"{self.image_matching_window}"
            )
        if self.band_candidates < 0 or self.band_candidates == 1:
            raise ValueError(
                "GeneratorConfig.band_candidates must be 0 (off) or >= 2, got "
                f"{self.band_candidates}"
            )
        if not 0 <= self.alexnet_layers <= MAX_ALEXNET_LAYERS:
            raise ValueError(
                f"GeneratorConfig.alexnet_layers must be 0-{MAX_ALEXNET_LAYERS}, "
                f"got {self.alexnet_layers}"
            )
        if self.feature_channels % self.attention_heads:
            raise ValueError(
                f"GeneratorConfig.attention_heads ({self.attention_heads}) must divide "
                f"feature_channels ({self.feature_channels})"
            )
        if 8 % self.attention_splits:
            raise ValueError(
                f"GeneratorConfig.attention_splits must divide 8 (1, 2, 4 or 8), got {self.attention_splits}"
            )
        if len(self.unet_channels) < 3 or min(self.unet_channels) < 1:
            raise ValueError(
                f"GeneratorConfig.unet_channels needs >= 3 positive levels, got {self.unet_channels}"
            )
        if SIZE_MULTIPLE % (4 * 2 ** (len(self.unet_channels) - 1)):
            raise ValueError(
                f"GeneratorConfig.unet_channels has {len(self.unet_channels)} levels; at most 4 fit "
                f"images that are multiples of {SIZE_MULTIPLE}"
            )
        if self.sh_degree not in (0, 1, 2, 3):
            raise ValueError(f"GeneratorConfig.sh_degree must be 0-3, got {self.sh_degree}")
        if not 0 < self.scale_factor_min < self.scale_factor_max:
            raise ValueError(
                "GeneratorConfig needs 0 < scale_factor_min < scale_factor_max, got "
                f"{self.scale_factor_min}, {self.scale_factor_max}"
            )
        if not self.max_offset_px > 0:
            raise ValueError(f"GeneratorConfig.max_offset_px must be > 0, got {self.max_offset_px}")
        if self.max_views < 2:
            raise ValueError(f"GeneratorConfig.max_views must be >= 2, got {self.max_views}")

    @property
    def sh_coefficients(self) -> int:
        """K = (degree + 1)^2 coefficients per colour channel."""
        return (self.sh_degree + 1) ** 2

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (tuples become lists)."""
        d = asdict(self)
        d["unet_channels"] = list(self.unet_channels)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GeneratorConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error (they would be silently lost)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"GeneratorConfig has no keys {unknown}; the checkpoint comes from another version"
            )
        return cls(**data)

    @classmethod
    def from_json(cls, text: str) -> GeneratorConfig:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"GeneratorConfig JSON is not valid: {e}") from e
        if not isinstance(data, dict):
            raise ValueError("GeneratorConfig JSON must be an object")
        return cls.from_dict(data)


#: Trainable on a 2-core CPU at 64-128 px in hours (see the parameter count in the tests' report).
TINY = GeneratorConfig()

#: v2: trained on a GPU at 64 and 128 px, still light enough for the CPU at 256 px. Twice the
#: 1.5x the depth candidates of ``tiny`` and a 1/2-resolution cost volume: geometry from
#: matching.
SMALL = GeneratorConfig(
    feature_channels=48,
    num_depth_candidates=48,
    attention_layers=2,
    attention_heads=2,
    attention_splits=2,
    attention_mlp_ratio=2,
    cost_volume_views=3,
    fine_matching_channels=16,
    mono_channels=48,
    mono_blocks=3,
    unet_channels=(48, 64, 96, 128),
    refine_channels=24,
    sh_degree=0,
)

#: For a GPU at 256 px and up.
BASE = GeneratorConfig(
    feature_channels=128,
    num_depth_candidates=64,
    attention_layers=6,
    attention_heads=4,
    attention_splits=2,
    attention_mlp_ratio=4,
    cost_volume_views=3,
    mono_channels=128,
    mono_blocks=6,
    unet_channels=(128, 192, 256, 384),
    refine_channels=32,
    sh_degree=2,
)

PRESETS: dict[str, GeneratorConfig] = {"tiny": TINY, "small": SMALL, "base": BASE}


def preset(name: str) -> GeneratorConfig:
    """A preset by name ("tiny", "small" or "base")."""
    try:
        return PRESETS[name.lower()]
    except KeyError:
        raise ValueError(
            f"unknown generator preset {name!r}; use one of {sorted(PRESETS)}"
        ) from None
