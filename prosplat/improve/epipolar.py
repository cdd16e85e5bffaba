"""Epipolar geometry between a target view and a reference view, for DWEA.

The improvement model attends from every target feature to the reference features near the
target feature's epipolar line. This module gives the fundamental matrix of a camera pair and
the point-to-line distance table that DWEA turns into its modulation.

Convention (the project's): homogeneous pixel coordinates ``x = (u, v, 1)`` with pixel
(col, row) centred at (col + 0.5, row + 0.5), and ``x_refᵀ F x_tgt = 0`` for any 3D point's
projections. The paper prints ``F = K_ref⁻¹ [t]ₓ R_ref R_tgtᵀ K_tgt⁻¹`` with
``t = T_ref − R_tgtᵀ T_tgt``; both the missing transpose on ``K_ref⁻¹`` and that ``t`` are
wrong for world-to-camera poses, so we use the textbook relative pose instead.
"""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.core.camera import Camera

__all__ = ["epipolar_distances", "fundamental_matrices", "fundamental_matrix"]

# A baseline shorter than this fraction of the cameras' distance from the world origin is
# rounding noise of a zero baseline (pure rotation or coincident cameras): no epipolar
# geometry exists, and F is returned as exact zeros so callers can detect it. Poses in a
# lower precision than float64 raise it to 64 ulps of their dtype (float32: ~7.6e-6).
_BASELINE_REL_EPS = 1e-9
# A line l = F x with a² + b² below this fraction of |F|²|x|² is the null line (x is the
# target epipole) or the line at infinity: it constrains nothing.
_LINE_REL_EPS = 1e-10


def _skew(t: Tensor) -> Tensor:
    """[..., 3] -> [..., 3, 3] cross-product matrix, ``skew(t) @ v == t × v``."""
    zero = torch.zeros_like(t[..., 0])
    tx, ty, tz = t.unbind(-1)
    rows = (
        torch.stack([zero, -tz, ty], -1),
        torch.stack([tz, zero, -tx], -1),
        torch.stack([-ty, tx, zero], -1),
    )
    return torch.stack(rows, -2)


def work_dtype(device: torch.device) -> torch.dtype:
    """float64 wherever the device has it (MPS has not, so it gets float32)."""
    return torch.float32 if device.type == "mps" else torch.float64


def fundamental_matrices(K_tgt: Tensor, w2c_tgt: Tensor, K_ref: Tensor, w2c_ref: Tensor) -> Tensor:
    """Batched fundamental matrices, ``x_refᵀ F x_tgt = 0``.

    ``F = K_ref⁻ᵀ [t]ₓ R K_tgt⁻¹`` with the relative pose ``R = R_ref R_tgtᵀ``,
    ``t = T_ref − R T_tgt`` (so ``X_ref = R X_tgt + t``). Each F is scaled to unit Frobenius
    norm, which leaves the lines unchanged and makes thresholds unit-free. A pair whose
    baseline vanishes (pure rotation, coincident cameras: ``‖C_tgt − C_ref‖`` at most 1e-9,
    or 64 ulps of the poses' dtype, times the centres' distance from the origin) has no
    epipolar geometry; its F is exact zeros, the signal :func:`epipolar_distances` and DWEA
    read as "no constraint".

    Args:
        K_tgt, K_ref: [B, 3, 3] intrinsics in pixels (any float dtype).
        w2c_tgt, w2c_ref: [B, 4, 4] world-to-camera matrices (OpenCV axes).
    Returns:
        [B, 3, 3] float64 (float32 on MPS), not differentiable.
    """
    for name, t, shape in (
        ("K_tgt", K_tgt, (3, 3)),
        ("w2c_tgt", w2c_tgt, (4, 4)),
        ("K_ref", K_ref, (3, 3)),
        ("w2c_ref", w2c_ref, (4, 4)),
    ):
        if t.dim() != 3 or tuple(t.shape[1:]) != shape:
            raise ValueError(
                f"fundamental_matrices: {name} must be [B, {shape[0]}, {shape[1]}], got {tuple(t.shape)}"
            )
        if t.shape[0] != K_tgt.shape[0]:
            raise ValueError(
                f"fundamental_matrices: {name} has batch {t.shape[0]}, K_tgt has "
                f"{K_tgt.shape[0]}; pass one camera pair per row"
            )
        if not torch.isfinite(t).all():
            raise ValueError(
                f"fundamental_matrices: {name} contains NaN or Inf; check the camera poses"
            )
    dtype = work_dtype(K_tgt.device)
    with torch.no_grad():
        K_t, K_r = K_tgt.to(dtype), K_ref.to(dtype)
        R_t, T_t = w2c_tgt[:, :3, :3].to(dtype), w2c_tgt[:, :3, 3].to(dtype)
        R_r, T_r = w2c_ref[:, :3, :3].to(dtype), w2c_ref[:, :3, 3].to(dtype)
        R = R_r @ R_t.transpose(1, 2)  # [B, 3, 3]
        # t = T_ref − R T_tgt, written as R_ref (C_tgt − C_ref) with the centres C = −Rᵀ T:
        # equal for rigid poses, and exactly zero for coincident cameras even when the poses
        # are float32 (where R_tgt R_tgtᵀ is only I to ~1e-7).
        C_t = -(R_t.transpose(1, 2) @ T_t[..., None])[..., 0]  # [B, 3]
        C_r = -(R_r.transpose(1, 2) @ T_r[..., None])[..., 0]  # [B, 3]
        baseline = C_t - C_r  # [B, 3]
        t = (R_r @ baseline[..., None])[..., 0]  # [B, 3]
        E = _skew(t) @ R  # [B, 3, 3] essential matrix
        F = torch.linalg.inv(K_r).transpose(1, 2) @ E @ torch.linalg.inv(K_t)
        # Relative to the cameras' distance from the origin (the scale of the rig's
        # coordinates) and to the poses' precision: float32 centres are only good to ~1e-7.
        scale = torch.maximum(C_t.norm(dim=-1), C_r.norm(dim=-1))  # [B]
        eps = max(
            torch.finfo(w.dtype if w.is_floating_point() else torch.float64).eps
            for w in (w2c_tgt, w2c_ref)
        )
        rel = max(_BASELINE_REL_EPS, 64.0 * eps)
        vanishing = baseline.norm(dim=-1) <= rel * scale  # [B]
        norm = F.flatten(1).norm(dim=-1)  # [B]
        vanishing = vanishing | (norm == 0)
        F = F / torch.where(vanishing, torch.ones_like(norm), norm)[:, None, None]
        return torch.where(vanishing[:, None, None], torch.zeros_like(F), F)


def fundamental_matrix(target: Camera, ref: Camera) -> Tensor:
    """[3, 3] fundamental matrix with ``x_refᵀ F x_tgt = 0``; zeros where the baseline vanishes.

    See :func:`fundamental_matrices` for the construction.
    """
    for name, cam in (("target", target), ("ref", ref)):
        if not isinstance(cam, Camera):
            raise ValueError(
                f"fundamental_matrix: {name} must be a prosplat.Camera, got {type(cam).__name__}"
            )
    device = target.K.device
    return fundamental_matrices(
        target.K[None],
        target.world_to_cam[None],
        ref.K[None].to(device),
        ref.world_to_cam[None].to(device),
    )[0]


def feature_positions(
    hw: tuple[int, int], stride: float, dtype: torch.dtype, device=None
) -> Tensor:
    """[h*w, 3] homogeneous image-pixel coordinates of a feature map's cells, row-major.

    Cell (c, r) of a map with stride ``s`` covers pixels [c·s, (c+1)·s), so its centre is the
    pixel coordinate ((c + 0.5)·s, (r + 0.5)·s).
    """
    h, w = hw
    rows = (torch.arange(h, dtype=dtype, device=device) + 0.5) * stride
    cols = (torch.arange(w, dtype=dtype, device=device) + 0.5) * stride
    v, u = torch.meshgrid(rows, cols, indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1), torch.ones_like(u).reshape(-1)], -1)


def _check_hw(hw, name: str) -> tuple[int, int]:
    if len(hw) != 2 or any(int(n) != n or n < 1 for n in hw):
        raise ValueError(
            f"epipolar_distances: {name} must be (height, width) positive integers, got {hw}"
        )
    return int(hw[0]), int(hw[1])


def epipolar_distances(
    F: Tensor, target_hw: tuple[int, int], ref_hw: tuple[int, int], stride: float
) -> tuple[Tensor, Tensor]:
    """Distance in image pixels from every reference feature to every target feature's epipolar line.

    Target feature i sits at pixel x_i (see :func:`feature_positions`); its epipolar line in
    the reference image is ``l = F x_i = (a, b, c)`` and the distance of reference feature j
    at y_j is ``|lᵀ y_j| / √(a² + b²)``. Both maps use the same ``stride`` (pixels per
    feature cell) and F is in full-image pixel coordinates.

    Rows whose line is degenerate (x_i at the target epipole, where F x_i = 0, or a line at
    infinity) get distance 0 everywhere: no constraint, never NaN/Inf. Batch elements whose F
    vanishes (all zeros: pure rotation or coincident cameras) get ``valid = False`` and zero
    distances; callers must treat them as unconstrained.

    Args:
        F: [B, 3, 3] fundamental matrices (from :func:`fundamental_matrices`).
        target_hw: (h_t, w_t) of the target feature map.
        ref_hw: (h_r, w_r) of the reference feature map.
        stride: image pixels per feature cell, > 0.
    Returns:
        distances: [B, h_t*w_t, h_r*w_r] in pixels, F's dtype (computed in float64 where the
            device supports it);
        valid: [B] bool, False where F vanishes.
    """
    if F.dim() != 3 or tuple(F.shape[1:]) != (3, 3):
        raise ValueError(f"epipolar_distances: F must be [B, 3, 3], got {tuple(F.shape)}")
    if not torch.isfinite(F).all():
        raise ValueError(
            "epipolar_distances: F contains NaN or Inf; rebuild it with fundamental_matrices"
        )
    if not (float(stride) > 0):
        raise ValueError(
            f"epipolar_distances: stride must be > 0 (pixels per feature cell), got {stride}"
        )
    target_hw, ref_hw = _check_hw(target_hw, "target_hw"), _check_hw(ref_hw, "ref_hw")
    work = work_dtype(F.device)
    with torch.no_grad():
        Fw = F.to(work)
        norm = Fw.flatten(1).norm(dim=-1)  # [B]
        valid = norm > 0
        Fw = Fw / torch.where(valid, norm, torch.ones_like(norm))[:, None, None]
        x_t = feature_positions(target_hw, float(stride), work, F.device)  # [Nt, 3]
        y_r = feature_positions(ref_hw, float(stride), work, F.device)  # [Nr, 3]
        lines = x_t @ Fw.transpose(1, 2)  # [B, Nt, 3], row i = F x_i
        ab = lines[..., :2].norm(dim=-1)  # [B, Nt]
        degenerate = ab <= _LINE_REL_EPS * x_t.norm(dim=-1)  # |F| = 1 after normalising
        d = (lines @ y_r.T).abs()  # [B, Nt, Nr]
        d = d / torch.where(degenerate, torch.ones_like(ab), ab)[..., None]
        keep = valid[:, None, None] & ~degenerate[..., None]
        d = torch.where(keep, d, torch.zeros_like(d))
    return d.to(F.dtype), valid
