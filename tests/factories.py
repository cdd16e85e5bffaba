"""Random inputs that several test folders build the same way."""

from __future__ import annotations

import torch

from prosplat import Gaussians


def random_gaussians(n: int, degree: int, seed: int = 0, dtype=torch.float32) -> Gaussians:
    """``n`` seeded Gaussians of SH ``degree``: unit-normal means and quaternions, scales
    spread over about two decades, opacities uniform in [0, 1]."""
    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    r = lambda *s: torch.randn(*s, generator=gen, dtype=dtype)  # noqa: E731
    scales = torch.exp(r(n, 3) * 2 - 3)
    opac = torch.rand(n, generator=gen, dtype=dtype)
    return Gaussians(r(n, 3), r(n, 4), scales, opac, r(n, k, 3) * 0.5)
