"""Rotation of real spherical-harmonic coefficients (degrees 0-2) by a 3x3 rotation.

DepthSplat rotates its camera-space SH into world space with e3nn's Wigner D matrices
(``wigner_D(l, *matrix_to_angles(R))``). In e3nn's real basis, degree 1 is (x, y, z), so
D1 = R, and degree 2 is
    (sqrt15 xz, sqrt15 xy, sqrt5 (y^2 - (x^2+z^2)/2), sqrt15 yz, sqrt15/2 (z^2 - x^2)),
with D(R) defined by Y(R d) = D(R) Y(d). We build D2 from that identity directly: evaluate
the basis at fixed sample directions X and at R X, then D2 = Y(RX) Y(X)^+ (exact, since
the five functions are independent on the samples). No e3nn needed.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

_S15 = math.sqrt(15.0)
_S5 = math.sqrt(5.0)


def _basis2(d: Tensor) -> Tensor:
    """[..., 3] unit directions -> [..., 5] the degree-2 basis above."""
    x, y, z = d.unbind(-1)
    return torch.stack(
        [
            _S15 * x * z,
            _S15 * x * y,
            _S5 * (y * y - 0.5 * (x * x + z * z)),
            _S15 * y * z,
            _S15 / 2 * (z * z - x * x),
        ],
        dim=-1,
    )


def _samples() -> tuple[Tensor, Tensor]:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(16, 3, generator=g, dtype=torch.float64)
    x = x / x.norm(dim=-1, keepdim=True)
    return x, torch.linalg.pinv(_basis2(x))  # [16,3], [5,16]


_X, _PINV = _samples()


def wigner_d2(R: Tensor) -> Tensor:
    """[..., 3, 3] rotations -> [..., 5, 5] degree-2 rotation in the basis above."""
    X = _X.to(R.device)
    P = _PINV.to(R.device)
    rx = (R.double() @ X.T).transpose(-1, -2)  # [..., 16, 3]
    return (_basis2(rx).transpose(-1, -2) @ P.T).to(R.dtype)  # [...,5,16] @ [16,5]


def rotate_sh(sh: Tensor, R: Tensor) -> Tensor:
    """sh [..., 9] (degree 2, e3nn ordering per degree), R [..., 3, 3] broadcastable to sh's
    leading dims -> rotated [..., 9]."""
    if sh.shape[-1] != 9:
        raise ValueError(f"rotate_sh handles degree 2 (9 coefficients), got {sh.shape[-1]}")
    d1 = R
    d2 = wigner_d2(R)
    out0 = sh[..., :1]
    out1 = (d1 @ sh[..., 1:4, None])[..., 0]
    out2 = (d2 @ sh[..., 4:9, None])[..., 0]
    return torch.cat([out0, out1, out2], dim=-1)
