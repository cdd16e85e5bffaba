"""Grow trained generator weights into a larger network that computes the same function.

Training a generator from scratch costs CPU hours that a fine-tune from the shipped weights
does not. When a change adds a module (the 1/2-resolution cost volume of
``fine_matching_channels``; the frozen AlexNet features of ``alexnet_layers``; the images' own
plane sweep of ``image_matching_window``; the learned depth sweep of ``band_candidates``), the
trained
weights are copied into the larger network and the new module enters through weights that
start at zero, so step 0 of the fine-tune reproduces the old generator exactly and training
only has to learn what the new input adds.
"""

from __future__ import annotations

import os
from dataclasses import replace

import torch
from torch import Tensor

from prosplat.generator.config import GeneratorConfig
from prosplat.generator.model import Generator

#: The first conv of the depth head's U-Net: its input is
#: concat(cost, [fine cost], [image cost], mono, feats).
_UNET_IN = "depth_head.unet.inc.0.0.weight"


def grow_fine_matching(
    config: GeneratorConfig, state: dict[str, Tensor], channels: int
) -> tuple[GeneratorConfig, dict[str, Tensor]]:
    """Weights of ``config`` (without fine matching) -> the same network with a
    ``channels``-wide 1/2-resolution cost volume, and a state dict that gives identical outputs.

    The fine cost volume reaches the depth through two paths, both closed at the start: the
    U-Net input channels it occupies get zero weights, and its gain on the logit prior is 0.
    The fine features' projection and pooling keep a fresh random init (seeded by the caller)
    so that gradients flow into them once the closed paths open.
    """
    if channels < 1:
        raise ValueError(f"grow_fine_matching: channels must be >= 1, got {channels}")
    if config.fine_matching_channels:
        raise ValueError(
            "grow_fine_matching: the weights already have a fine cost volume "
            f"(fine_matching_channels={config.fine_matching_channels})"
        )
    grown_config = replace(config, fine_matching_channels=channels)
    grown = Generator(grown_config).state_dict()
    missing = set(state) - set(grown)
    if missing:
        raise ValueError(f"grow_fine_matching: unexpected weights {sorted(missing)[:3]}")
    d = config.num_depth_candidates
    out: dict[str, Tensor] = {}
    for key, fresh in grown.items():
        old = state.get(key)
        if key == _UNET_IN:
            w = torch.zeros_like(fresh)  # [U0, 2D+Cm+C, 3, 3]
            w[:, :d] = old[:, :d]  # coarse cost
            w[:, 2 * d :] = old[:, d:]  # mono + matching features; [d:2d] (fine) stays 0
            out[key] = w
        elif key == "depth_head.fine_gain":
            out[key] = torch.zeros_like(fresh)
        elif old is None:
            out[key] = fresh  # the new module's own init
        elif old.shape != fresh.shape:
            raise ValueError(
                f"grow_fine_matching: {key} is {list(old.shape)} in the weights but "
                f"{list(fresh.shape)} in the grown network"
            )
        else:
            out[key] = old.clone()
    return grown_config, out


def grow_alexnet(
    config: GeneratorConfig,
    state: dict[str, Tensor],
    layers: int,
    lpips_weights: str | os.PathLike | None = None,
) -> tuple[GeneratorConfig, dict[str, Tensor]]:
    """Weights of ``config`` (without AlexNet features) -> the same network with AlexNet's
    relu1..relu``layers`` added to the monocular branch, and a state dict that gives identical
    outputs: the backbone's weights come from the LPIPS file (``lpips_weights``, default
    where :class:`prosplat.metrics.LPIPS` looks) and stay frozen; the projection's last 1x1
    convolution is zero (its init), its first keeps a fresh random init (seeded by the caller).
    """
    from prosplat.metrics import LPIPS

    if config.alexnet_layers:
        raise ValueError(
            f"grow_alexnet: the weights already have AlexNet features (alexnet_layers="
            f"{config.alexnet_layers})"
        )
    alexnet = LPIPS(lpips_weights).features  # checks the file; its error names the command
    grown_config = replace(config, alexnet_layers=layers)  # validates ``layers``
    grown = Generator(grown_config).state_dict()
    missing = set(state) - set(grown)
    if missing:
        raise ValueError(f"grow_alexnet: unexpected weights {sorted(missing)[:3]}")
    out: dict[str, Tensor] = {}
    for key, fresh in grown.items():
        if key.startswith("monocular.alexnet.conv"):
            conv, kind = key.rsplit(".", 1)[1].split("_")  # conv1_weight
            out[key] = getattr(getattr(alexnet, conv), kind).detach().to(fresh.dtype).clone()
        elif key in state:
            out[key] = state[key].clone()
        else:
            out[key] = fresh  # the projection's own init (last layer zero)
    return grown_config, out


def grow_image_matching(
    config: GeneratorConfig, state: dict[str, Tensor], window: int
) -> tuple[GeneratorConfig, dict[str, Tensor]]:
    """Weights of ``config`` (without the image cost volume) -> the same network with the
    images' ZNCC plane sweep of ``window`` pixels (:mod:`prosplat.generator.image_cost`), and
    a state dict that gives identical outputs: the D U-Net input channels it occupies get
    zero weights and its gain on the logit prior is 0. The volume itself has no weights, so
    gradients reach both closed paths from the first step."""
    if config.image_matching_window:
        raise ValueError(
            "grow_image_matching: the weights already have an image cost volume "
            f"(image_matching_window={config.image_matching_window})"
        )
    if window < 1:
        raise ValueError(f"grow_image_matching: window must be >= 1, got {window}")
    grown_config = replace(config, image_matching_window=window)  # validates: odd
    grown = Generator(grown_config).state_dict()
    if set(state) != set(grown) - {"depth_head.image_gain"}:
        raise ValueError(
            "grow_image_matching: the weights do not match the network of their config "
            f"({sorted(set(state) ^ (set(grown) - {'depth_head.image_gain'}))[:3]})"
        )
    d = config.num_depth_candidates
    at = d * (2 if config.fine_matching_channels else 1)  # after cost and fine cost
    out = {key: value.clone() for key, value in state.items()}
    old = state[_UNET_IN]  # [U0, at + Cm + C, 3, 3]
    w = torch.zeros_like(grown[_UNET_IN])  # [U0, at + D + Cm + C, 3, 3]
    w[:, :at] = old[:, :at]
    w[:, at + d :] = old[:, at:]
    out[_UNET_IN] = w
    out["depth_head.image_gain"] = torch.zeros_like(grown["depth_head.image_gain"])
    return grown_config, out


def grow_band(
    config: GeneratorConfig, state: dict[str, Tensor], candidates: int
) -> tuple[GeneratorConfig, dict[str, Tensor]]:
    """Weights of ``config`` (without the learned depth sweep) -> the same network with
    :class:`prosplat.generator.band.BandRefiner` over ``candidates`` depths, and a state dict
    that gives the same outputs: the band's last convolution is zero (its init), the rest
    keeps a fresh random init (seeded by the caller) so that gradients open it."""
    if config.band_candidates:
        raise ValueError(
            f"grow_band: the weights already have a band (band_candidates={config.band_candidates})"
        )
    if candidates < 2:
        raise ValueError(f"grow_band: candidates must be >= 2, got {candidates}")
    grown_config = replace(config, band_candidates=candidates)
    grown = Generator(grown_config).state_dict()
    if set(state) != {k for k in grown if not k.startswith("band.")}:
        raise ValueError("grow_band: the weights do not match the network of their config")
    out = {key: value.clone() for key, value in state.items()}
    out.update({key: value for key, value in grown.items() if key.startswith("band.")})
    return grown_config, out
