"""Small improvement-model configs shared by the stage-2 tests (fast on the CPU)."""

from __future__ import annotations

from prosplat.improve.config import ImproveConfig

#: Two VAE levels and three U-Net levels of 16 channels: sizes in multiples of 8, 150k parameters.
SMALL = ImproveConfig(
    vae_channels=(16, 16),
    vae_groups=8,
    unet_channels=(16, 16, 16),
    unet_groups=8,
    cross_attention_dim=16,
)
