"""Hyper-parameters of the stage-2 improvement model, with the ablation switches of the paper.

The config travels with the weights (JSON in the safetensors metadata), like the generator's,
so a checkpoint always rebuilds the network it was trained as. The switches ``denoise`` and
``reference`` are the rows of the paper's Table IV: VAE + U-Net alone, + the one-step
diffusion update, + MORI/DWEA.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

#: How convolutions may pad (``ImproveConfig.padding``).
PADDINGS = ("zeros", "replicate")

#: The empty-prompt embedding SD-Turbo's U-Net cross-attends to has 77 CLIP tokens.
SD_PROMPT_TOKENS = 77


@dataclass(frozen=True)
class ImproveConfig:
    """Every size and switch of the improvement model.

    Attributes:
        vae_channels: ``AutoencoderKL`` block widths; the latent is ``2^(len-1)`` times smaller
            than the image.
        vae_layers: resnet layers per VAE block.
        latent_channels: channels of the latent z.
        vae_groups: GroupNorm groups in the VAE (must divide every VAE width).
        unet_channels: ``UNet2DConditionModel`` block widths; the bottleneck where DWEA acts
            is ``2^(len-1)`` times smaller than the latent.
        unet_layers: resnet layers per U-Net block.
        unet_cross_attention: per level, whether the block cross-attends to the (fixed,
            empty) prompt embedding; SD-Turbo does at all but the last level. ``tiny`` does
            not: attending to one fixed token is a constant, so those layers would only cost
            time (its mid block still self-attends).
        cross_attention_dim, attention_head_dim: the U-Net's attention sizes.
        unet_groups: GroupNorm groups in the U-Net.
        prompt_tokens: length of the empty-prompt embedding buffer.
        scaling_factor: latent scale (SD's 0.18215; 1 for a VAE trained from scratch here).
        timestep: the fixed diffusion timestep t of the one-step update (pix2pix-turbo uses
            999, Difix 199).
        denoise: take ``x0 = (z - sqrt(1 - abar_t) eps) / sqrt(abar_t)`` from the U-Net's
            noise prediction (one-step diffusion); off = the U-Net output is the new latent
            (the paper's "VAE + U-Net" baseline).
        reference: fuse the MORI reference view through DWEA at the U-Net bottleneck.
        epipolar: DWEA weights its attention by the distance to each target position's
            epipolar line (the paper's design); off, the fundamental matrix is ignored and
            DWEA is plain cross-attention to the reference (issue 13's "plain" ablation row).
            A switch of behaviour, not of weights: the same weights load either way.
        dwea_heads: attention heads of DWEA.
        vae_skip: pix2pix-turbo's encoder -> decoder skip connections (1x1 convolutions).
        skip_init: the constant those 1x1 convolutions start at ("near zero").
        residual: add the decoder's output to the input render, with the decoder's last
            convolution zero-initialised, so an untrained model is exactly the identity and
            training can only start from "no change". For training from scratch on a CPU
            this is what makes a few thousand steps enough; a pretrained SD-Turbo decoder
            already reproduces images, so that path turns it off.
        working_size: the largest view (longest side) the model runs on directly. A larger
            view is enhanced at this size and only the change is carried up to the full
            resolution (:mod:`prosplat.pipeline.enhance`): memory stays bounded whatever the camera, and
            a model trained on small views sees textures near the scale it learned. ``prosplat
            train improve`` sets it to the training views' size; a model that measures better
            run natively above that size (the v2 candidate, up to 256 px: BENCHMARKS) can be
            saved with a larger one. 0 runs every view at its own size. Not an architecture
            parameter: it travels in the config so the weights say how to use them.
        alpha_input: the render's alpha (where the Gaussians cover the view; holes are 0)
            enters the VAE encoder of the render through a zero-initialised convolution added
            to its first features, so the model knows where it must fill rather than guess
            it from black pixels. Zero-initialised: weights without it load and behave the
            same (:func:`prosplat.improve.io.load_improver` with ``alpha_input=True``).
        warp_input: the MORI reference warped into the view through the rendered depth, with
            its validity mask (:func:`prosplat.improve.warp.reference_warp`, 4 channels),
            enters the render's VAE encoder like the alpha: through a zero-initialised
            convolution added to its first features. DWEA sees the reference only at the
            bottleneck; the warp puts its texture on the pixel it belongs to. Zero-initialised:
            weights without it load and behave the same (``load_improver(warp_input=True)``).
        fill_input: the render's holes (where alpha < 1) are filled by pull-push from its own
            colours (:mod:`prosplat.render.hole_fill`) before the model sees it, and the
            residual is added to that filled render: the model corrects a continuation of
            the scene instead of painting on black. No weights of its own: a model trained
            without it loads with it (``load_improver(fill_input=True)``) to be fine-tuned.
            Needs the alpha at run time (without it the render is taken as fully covered).
        padding: how every padded convolution extends the image: "zeros" (diffusers' default)
            or "replicate". Zero padding tells a network where the border is, and through
            many layers where every pixel is, which is how a model can stamp the same picture
            on every view (v1's fixed pattern: a flat grey render comes back with it).
            Replicate padding keeps the network translation-equivariant away from the
            border, so a flat input gives a flat change.
    """

    vae_channels: tuple[int, ...] = (32, 64, 64)
    vae_layers: int = 1
    latent_channels: int = 4
    vae_groups: int = 16
    unet_channels: tuple[int, ...] = (32, 64, 64)
    unet_layers: int = 1
    unet_cross_attention: tuple[bool, ...] = (False, False, False)
    cross_attention_dim: int = 32
    attention_head_dim: int = 8
    unet_groups: int = 16
    prompt_tokens: int = 1
    scaling_factor: float = 1.0
    timestep: int = 199
    denoise: bool = True
    reference: bool = True
    epipolar: bool = True
    dwea_heads: int = 1
    vae_skip: bool = True
    skip_init: float = 1e-5
    residual: bool = True
    working_size: int = 64
    alpha_input: bool = False
    warp_input: bool = False
    fill_input: bool = False
    padding: str = "zeros"

    def __post_init__(self) -> None:
        for name in ("vae_channels", "unet_channels"):
            object.__setattr__(self, name, tuple(int(c) for c in getattr(self, name)))
        object.__setattr__(
            self, "unet_cross_attention", tuple(bool(b) for b in self.unet_cross_attention)
        )
        if len(self.vae_channels) < 2 or len(self.unet_channels) < 3:
            raise ValueError(
                "ImproveConfig needs >= 2 VAE levels and >= 3 U-Net levels (DWEA injects at the "
                f"x2 and x4 stages of the expansive path), got {self.vae_channels}, {self.unet_channels}"
            )
        if len(self.unet_cross_attention) != len(self.unet_channels):
            raise ValueError(
                "ImproveConfig.unet_cross_attention needs one flag per U-Net level, got "
                f"{len(self.unet_cross_attention)} for {len(self.unet_channels)} levels"
            )
        for name, groups, widths in (
            ("vae", self.vae_groups, self.vae_channels),
            ("unet", self.unet_groups, self.unet_channels),
        ):
            if any(w % groups for w in widths):
                raise ValueError(
                    f"ImproveConfig.{name}_groups ({groups}) must divide every {name} width {widths}"
                )
        if not 0 <= self.timestep <= 999:
            raise ValueError(f"ImproveConfig.timestep must be in [0, 999], got {self.timestep}")
        if min(self.latent_channels, self.prompt_tokens, self.dwea_heads) < 1:
            raise ValueError(
                "ImproveConfig latent_channels, prompt_tokens, dwea_heads must be >= 1"
            )
        if self.padding not in PADDINGS:
            raise ValueError(
                f"ImproveConfig.padding must be one of {PADDINGS}, got {self.padding!r}"
            )
        if self.working_size < 0:
            raise ValueError(f"ImproveConfig.working_size must be >= 0, got {self.working_size}")
        if not self.scaling_factor > 0:
            raise ValueError(f"ImproveConfig.scaling_factor must be > 0, got {self.scaling_factor}")

    @property
    def size_multiple(self) -> int:
        """Image sizes must be a multiple of this (VAE and U-Net halvings)."""
        return 2 ** (len(self.vae_channels) - 1) * 2 ** (len(self.unet_channels) - 1)

    @property
    def bottleneck_stride(self) -> int:
        """Image pixels per bottleneck feature (the stride DWEA maps positions with)."""
        return self.size_multiple

    def with_(self, **changes: Any) -> ImproveConfig:
        """A copy with some fields changed (ablation variants)."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("vae_channels", "unet_channels", "unet_cross_attention"):
            d[k] = list(d[k])
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ImproveConfig:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"ImproveConfig JSON is not valid: {e}") from e
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known) if isinstance(data, dict) else []
        if not isinstance(data, dict) or unknown:
            raise ValueError(
                f"ImproveConfig JSON has unknown keys {unknown}; the checkpoint comes from another version"
            )
        return cls(**data)


#: Trainable on a 2-core CPU at 64-128 px (about 2.6 M parameters).
TINY = ImproveConfig()

#: The paper's ablation rows (Table IV) as config variants of a base config.
ABLATION_ROWS: dict[str, dict[str, bool]] = {
    "vae_unet": {"denoise": False, "reference": False},
    "one_step": {"denoise": True, "reference": False},
    "mori_dwea": {"denoise": True, "reference": True},
}

PRESETS: dict[str, ImproveConfig] = {"tiny": TINY}


def preset(name: str) -> ImproveConfig:
    try:
        return PRESETS[name.lower()]
    except KeyError:
        raise ValueError(
            f"unknown improvement preset {name!r}; use one of {sorted(PRESETS)}"
        ) from None
