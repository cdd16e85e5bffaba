"""Quaternions and rotation matrices ((w, x, y, z) order): the one place every part converts
between them (generator adapter, COLMAP files, baselines, point clouds)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product of [...,4] (w, x, y, z) quaternions: rotation b first, then a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def qvec_to_rotmat(qvec: Sequence[float] | Tensor) -> Tensor:
    """[4] quaternion (w, x, y, z) -> [3, 3] rotation (float64). Normalises, as COLMAP does."""
    q = torch.as_tensor(qvec, dtype=torch.float64)
    n = q.norm()
    if not torch.isfinite(q).all() or n < 1e-12:
        raise ValueError(f"quaternion must be finite and non-zero, got {q.tolist()}")
    w, x, y, z = (q / n).tolist()
    return torch.tensor(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ],
        dtype=torch.float64,
    )


def rotmat_to_qvec(R: Tensor) -> Tensor:
    """[3, 3] rotation -> [4] unit quaternion (w, x, y, z) with w >= 0 (float64).

    Shepperd's method: take the square root of the largest of the four diagonal combinations,
    so no branch divides by a small number and the result is accurate for every rotation.
    """
    m = torch.as_tensor(R, dtype=torch.float64).tolist()
    tr = m[0][0] + m[1][1] + m[2][2]
    cands = [tr, m[0][0], m[1][1], m[2][2]]
    k = max(range(4), key=lambda i: cands[i])
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = [(m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s]
    qt = torch.tensor(q, dtype=torch.float64)
    qt = qt / qt.norm()
    return -qt if qt[0] < 0 else qt


def rotmat_to_quat(R: Tensor) -> Tensor:
    """[...,3,3] rotations -> [...,4] unit quaternions (w, x, y, z), Shepperd's method: every
    branch is computed and the best-conditioned one (largest square root) is kept."""
    m = R
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    cands = torch.stack([tr, m00, m11, m22], dim=-1)  # [...,4]
    s = 2.0 * torch.sqrt(
        (1.0 + torch.stack([tr, m00 - m11 - m22, m11 - m00 - m22, m22 - m00 - m11], -1)).clamp_min(
            1e-12
        )
    )  # [...,4]
    d21, d02, d10 = (
        m[..., 2, 1] - m[..., 1, 2],
        m[..., 0, 2] - m[..., 2, 0],
        m[..., 1, 0] - m[..., 0, 1],
    )
    s01, s02, s12 = (
        m[..., 0, 1] + m[..., 1, 0],
        m[..., 0, 2] + m[..., 2, 0],
        m[..., 1, 2] + m[..., 2, 1],
    )
    q = torch.stack(
        [
            torch.stack([0.25 * s[..., 0], d21 / s[..., 0], d02 / s[..., 0], d10 / s[..., 0]], -1),
            torch.stack([d21 / s[..., 1], 0.25 * s[..., 1], s01 / s[..., 1], s02 / s[..., 1]], -1),
            torch.stack([d02 / s[..., 2], s01 / s[..., 2], 0.25 * s[..., 2], s12 / s[..., 2]], -1),
            torch.stack([d10 / s[..., 3], s02 / s[..., 3], s12 / s[..., 3], 0.25 * s[..., 3]], -1),
        ],
        dim=-2,
    )  # [...,4 branches,4]
    best = cands.argmax(-1)  # [...]
    q = torch.gather(q, -2, best[..., None, None].expand(*best.shape, 1, 4))[..., 0, :]
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)
