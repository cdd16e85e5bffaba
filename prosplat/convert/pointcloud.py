"""Gaussians <-> flat per-point attribute arrays, the form a Blender mesh stores (no ``bpy``).

The add-on shows Gaussians as a mesh whose vertices are the means and whose point attributes
are the 3DGS PLY properties under their PLY names, in the PLY's encodings: ``opacity`` is a
logit, ``scale_0..2`` are natural logs, ``rot_0..3`` the quaternion (w, x, y, z), ``f_dc_0..2``
and ``f_rest_*`` the SH coefficients (``f_rest`` channel-major, as INRIA writes it). Keeping
the file's encodings means the mesh holds exactly the float32 numbers of the file, so other
splat tools' node setups find the names they expect, and a PLY -> mesh -> PLY trip is exact:

* :func:`to_attributes` encodes in float64 and rounds once to float32, as
  :func:`prosplat.write_ply` does; :func:`from_attributes` decodes in float64. For Gaussians
  read with ``read_ply(path, dtype=torch.float64)`` the encode gives back the file's float32
  codes (checked by the tests), so ``write_ply`` writes the same bytes.
* ``color`` is extra: the view-independent colour ``SH0·C0 + 0.5`` (clamped to [0, 1],
  converted from display sRGB to the linear values Blender's colour attributes hold) with the
  opacity as alpha, for the viewport. It is derived, so it is ignored on the way back.
* ``prosplat_view`` (:data:`prosplat.core.ply.VIEW_PROPERTY`), when the Gaussians know it: the
  input view that predicted each one (:attr:`Gaussians.views`), so a view rendered from the
  object favours the input nearest it as the library's views do. Absent or edited into
  something that is not one index >= 0 per point, the views are unknown (None).

Everything is whole-array numpy; no per-Gaussian Python.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from prosplat.core.gaussians import SH_C0, Gaussians
from prosplat.core.ply import OPACITY_MAX, OPACITY_MIN, SCALE_MIN, VIEW_PROPERTY, view_indices
from prosplat.core.rotations import quat_multiply, rotmat_to_qvec
from prosplat.render.sh import sh_basis

__all__ = [
    "COLOR",
    "POSITION",
    "attribute_names",
    "from_attributes",
    "sh_degree_from_names",
    "to_attributes",
    "transform_gaussians",
]

POSITION = "position"  # [N, 3] float32: the mesh's vertex coordinates
COLOR = "color"  # [N, 4] float32 linear RGBA: a viewport colour, derived, never read back
_SCALARS = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
_F_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
_REST_BY_DEGREE = {0: 0, 1: 9, 2: 24, 3: 45}


def attribute_names(sh_degree: int) -> list[str]:
    """Names of the float point attributes for ``sh_degree`` (position and colour excluded)."""
    if sh_degree not in _REST_BY_DEGREE:
        raise ValueError(f"SH degree must be 0-3, got {sh_degree}")
    rest = [f"f_rest_{i}" for i in range(_REST_BY_DEGREE[sh_degree])]
    return [*_SCALARS, *_F_DC, *rest]


def sh_degree_from_names(names) -> int:
    """The SH degree implied by the ``f_rest_*`` names present (0 when there are none).

    Raises:
        ValueError: a count of ``f_rest_*`` that no degree has, or a gap in their numbering.
    """
    names = set(names)
    count = sum(1 for n in names if n.startswith("f_rest_"))
    degree = {v: k for k, v in _REST_BY_DEGREE.items()}.get(count)
    if degree is None or any(f"f_rest_{i}" not in names for i in range(count)):
        raise ValueError(
            f"found {count} f_rest_* attributes; expected 0, 9, 24 or 45 named f_rest_0.. "
            "(SH degree 0-3)"
        )
    return degree


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def to_attributes(gaussians: Gaussians) -> dict[str, np.ndarray]:
    """Gaussians -> ``{name: float32 array}``: ``position [N,3]``, ``color [N,4]`` and one
    ``[N]`` array per name in :func:`attribute_names`."""
    g = gaussians.detach().to("cpu", torch.float64)
    n, k = len(g), g.sh.shape[1]
    sh = g.sh.numpy()  # [N, K, 3]
    opacity = np.clip(g.opacities.numpy(), OPACITY_MIN, OPACITY_MAX)
    out: dict[str, np.ndarray] = {POSITION: g.means.numpy().astype(np.float32)}
    out["opacity"] = (np.log(opacity) - np.log1p(-opacity)).astype(np.float32)
    log_scales = np.log(np.maximum(g.scales.numpy(), SCALE_MIN)).astype(np.float32)
    quats = g.quats.numpy().astype(np.float32)
    for i in range(3):
        out[f"scale_{i}"] = np.ascontiguousarray(log_scales[:, i])
        out[f"f_dc_{i}"] = np.ascontiguousarray(sh[:, 0, i], dtype=np.float32)
    for i in range(4):
        out[f"rot_{i}"] = np.ascontiguousarray(quats[:, i])
    rest = sh[:, 1:].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major, as in the PLY
    for i in range(rest.shape[1]):
        out[f"f_rest_{i}"] = np.ascontiguousarray(rest[:, i], dtype=np.float32)
    rgb = np.clip(sh[:, 0] * SH_C0 + 0.5, 0.0, 1.0)
    color = np.empty((n, 4), dtype=np.float32)
    color[:, :3] = _srgb_to_linear(rgb)
    color[:, 3] = g.opacities.numpy()
    out[COLOR] = color
    if g.views is not None:  # the input view of each, so views of a target favour the nearest
        out[VIEW_PROPERTY] = g.views.numpy().astype(np.float32)
    return out


def from_attributes(
    attributes: Mapping[str, np.ndarray], dtype: torch.dtype = torch.float64
) -> Gaussians:
    """Inverse of :func:`to_attributes` (``color`` is ignored); the SH degree comes from the
    ``f_rest_*`` names present.

    Raises:
        ValueError: a missing attribute (named), arrays of different lengths, or values the
            Gaussians reject (NaN, zero quaternion).
    """
    degree = sh_degree_from_names(attributes)
    names = attribute_names(degree)
    missing = [m for m in (POSITION, *names) if m not in attributes]
    if missing:
        raise ValueError(
            f"not a Gaussian point cloud: attribute(s) {missing[:4]} missing; a Gaussian point "
            "cloud has position, opacity, scale_0-2, rot_0-3, f_dc_0-2 (and f_rest_* for SH > 0)"
        )
    pos = np.asarray(attributes[POSITION], dtype=np.float64).reshape(-1, 3)
    n = pos.shape[0]
    cols = {}
    for name in names:
        a = np.asarray(attributes[name], dtype=np.float64).reshape(-1)
        if a.shape[0] != n:
            raise ValueError(f"attribute '{name}' has {a.shape[0]} values for {n} points")
        cols[name] = a
    k = (degree + 1) ** 2
    sh = np.empty((n, k, 3), dtype=np.float64)
    sh[:, 0] = np.stack([cols[f] for f in _F_DC], axis=1)
    if k > 1:
        rest = np.stack([cols[f"f_rest_{i}"] for i in range(3 * (k - 1))], axis=1)
        sh[:, 1:] = rest.reshape(n, 3, k - 1).transpose(0, 2, 1)
    opacity = np.exp(-np.logaddexp(0.0, -cols["opacity"]))
    with np.errstate(over="ignore"):
        scales = np.exp(np.stack([cols[f"scale_{i}"] for i in range(3)], axis=1))
    quats = np.stack([cols[f"rot_{i}"] for i in range(4)], axis=1)
    zero = ~quats.any(axis=1)
    quats[zero] = (1.0, 0.0, 0.0, 0.0)  # as read_ply: zeros are "no rotation" in some tools
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(dtype)  # noqa: E731
    views = None  # absent, or not one index >= 0 per point (edited): the views are unknown
    if VIEW_PROPERTY in attributes:
        views = view_indices(attributes[VIEW_PROPERTY], n)
    return Gaussians(t(pos), t(quats), t(scales), t(opacity), t(sh), views)


# ---- rigid / similarity transforms ----------------------------------------------------------
def _rotmat_to_quat(R: torch.Tensor) -> torch.Tensor:

    return rotmat_to_qvec(R)


def _sh_rotation(degree: int, R: torch.Tensor) -> list[torch.Tensor]:
    """Per band l >= 1, the [2l+1, 2l+1] matrix D with ``c' = D c`` so that the rotated
    coefficients give, in direction ``R d``, the colour the old ones gave in ``d``.

    Each band's basis is closed under rotation, so ``Y(R^T d) = Y(d) D^T`` holds exactly for
    any directions; least squares over 64 random ones recovers D to float64 round-off.
    """

    gen = torch.Generator().manual_seed(0)
    d = torch.randn(64, 3, generator=gen, dtype=torch.float64)
    d = d / d.norm(dim=1, keepdim=True)
    Y = sh_basis(degree, d)  # [64, K]
    Y_rot = sh_basis(degree, d @ R)  # rows R^T d
    out = []
    for band in range(1, degree + 1):
        s = slice(band * band, (band + 1) ** 2)
        out.append(torch.linalg.lstsq(Y[:, s], Y_rot[:, s]).solution)
    return out


def transform_gaussians(gaussians: Gaussians, matrix) -> Gaussians:
    """Gaussians moved by an object's world matrix (rotation, uniform scale, translation).

    Means, rotations, scales and the view-dependent SH bands are all transformed, so a
    Gaussian object moved in Blender renders moved. Non-uniform scale or shear would need
    the covariances re-decomposed (and a mirror would flip handedness), so they are refused.

    Raises:
        ValueError: not a 4x4 affine similarity transform.
    """
    m = torch.as_tensor(np.asarray(matrix, dtype=np.float64))
    if tuple(m.shape) != (4, 4) or not torch.isfinite(m).all():
        raise ValueError("the object matrix must be a finite 4x4 matrix")
    if torch.allclose(m, torch.eye(4, dtype=torch.float64), rtol=0, atol=0):
        return gaussians
    A = m[:3, :3]
    det = float(torch.det(A))
    s = det ** (1 / 3) if det > 0 else -1.0
    eye = torch.eye(3, dtype=A.dtype)
    if s <= 0 or not torch.allclose(A.T @ A, eye * s * s, rtol=0, atol=1e-5 * s * s):
        raise ValueError(
            "the Gaussian object has non-uniform or negative scale (or shear); apply only "
            "rotation, location and uniform scale to it, or apply the transform first"
        )
    R = A / s
    g = gaussians.detach()
    dt = g.dtype
    means = (g.means.double() @ A.T + m[:3, 3]).to(dt)
    q = _rotmat_to_quat(R).to(torch.float64)
    quats = quat_multiply(q.expand(len(g), 4), g.quats.double()).to(dt)
    scales = (g.scales.double() * s).to(dt)
    sh = g.sh.double().clone()
    for band, D in enumerate(_sh_rotation(g.sh_degree, R), start=1):
        s_ = slice(band * band, (band + 1) ** 2)
        sh[:, s_] = torch.einsum("ij,njc->nic", D, sh[:, s_])
    return Gaussians(means, quats, scales, g.opacities, sh.to(dt), g.views)
