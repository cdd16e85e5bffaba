"""What the generator returns: pixel-aligned Gaussians for a batch of scenes, plus the depth."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from prosplat.core.gaussians import Gaussians


@dataclass
class GeneratorOutput:
    """Gaussians of B scenes, one per input pixel, N = V·H·W ordered view-major then row-major
    (Gaussian ``v*H*W + r*W + c`` comes from pixel (c, r) of view v).

    Attributes:
        means: [B,N,3] world coordinates.
        quats: [B,N,4] unit quaternions (w, x, y, z), world frame.
        scales: [B,N,3] standard deviations (activated, > 0).
        opacities: [B,N] in (0, 1).
        sh: [B,N,K,3] SH coefficients, K = (sh_degree + 1)^2; colour = SH·basis + 0.5.
        depths: [B,V,H,W] z along each input camera's optical axis, in [near, far].
        confidence: [B,V,H,W] the largest candidate probability, in [1/D, 1].
        depth_logits: [B,V,D,h,w] the depth head's logits over its D candidates (uniform in
            inverse depth, near to far) at 1/4 of the matching size, for a loss on the
            distribution (``TrainConfig.input_depth_ce_weight``); None where a generator has
            no such head (the DepthSplat wrapper).
    """

    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    sh: Tensor
    depths: Tensor
    confidence: Tensor
    depth_logits: Tensor | None = None

    @property
    def batch_size(self) -> int:
        return self.means.shape[0]

    def gaussians(self, b: int = 0) -> Gaussians:
        """Scene ``b`` as :class:`prosplat.Gaussians` (keeps the autograd graph), each tagged
        with the input view it came from (``views``, view-major as the Gaussians are)."""
        if not -self.batch_size <= b < self.batch_size:
            raise IndexError(f"scene index {b} out of range for a batch of {self.batch_size}")
        _, v, h, w = self.depths.shape
        views = torch.arange(v, device=self.means.device).repeat_interleave(h * w)  # [N]
        return Gaussians(
            self.means[b], self.quats[b], self.scales[b], self.opacities[b], self.sh[b], views
        )

    def detach(self) -> GeneratorOutput:
        return GeneratorOutput(
            *(None if (x := getattr(self, f.name)) is None else x.detach() for f in fields(self))
        )
