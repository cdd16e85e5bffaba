"""What a render returns, shared by every backend."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor


@dataclass
class RenderOutput:
    """What one render returns.

    rgb [3,H,W] composited over the background; alpha [H,W] = 1 − final transmittance;
    depth [H,W] the alpha-normalised z along the optical axis (0 where nothing was drawn);
    visible [N] bool, Gaussians that touched the image.
    """

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    visible: Tensor
