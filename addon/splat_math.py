"""How the add-on shows Gaussians, in numbers: display limits and the attribute layout of
Blender's native Gaussian-splat point clouds. No ``bpy`` and no ``prosplat``, only numpy:
Blender's Python may have no torch (jobs then run in an external Python), and ``import
prosplat`` imports torch, so display maths the add-on needs at object creation lives here.

The add-on draws each Gaussian as an ellipsoid of semi-axes ``sigma * exp(scale_i)``. A
generator's pixel-aligned Gaussians grow with depth, so far ground splats can be several
scene units across and, drawn as solids, hide the whole scene; :func:`default_max_size` picks a
clamp from the cloud itself so that only those outliers are limited.

:func:`native_attributes` converts our point attributes (the 3DGS PLY encodings, see
``prosplat.convert.pointcloud``) to the attributes of the Gaussian-splat point cloud that
Blender 5.3 renders natively. That Blender is not available here, so the layout follows its
release notes (``position``, ``rotation``, ``scale``, ``radiance:*``) and is checked only by
unit tests of this conversion.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

#: The degree-0 SH basis constant, 1 / (2 sqrt(pi)) (``prosplat.gaussians.SH_C0``).
SH_C0 = 0.28209479177387814

__all__ = [
    "DEFAULT_SIGMA",
    "DEFAULT_VIEWPORT_POINTS",
    "default_max_size",
    "native_attributes",
]

#: Semi-axes drawn, in standard deviations. 2 sigma holds 74% of a 3D Gaussian's mass and the
#: shader's radial falloff is at exp(-2) = 0.14 of the centre there; 3 (the rasterizer's
#: cut-off) roughly doubles the overlap Cycles has to trace through.
DEFAULT_SIGMA = 2.0
#: Most splats the viewport shows (a random, stable subset); renders show all of them.
DEFAULT_VIEWPORT_POINTS = 200_000
#: A splat this many times the median size is an outlier the display may clamp ...
OUTLIER_FACTOR = 10.0
#: ... unless it is still under this fraction of the cloud's robust extent.
EXTENT_FRACTION = 0.02


def default_max_size(
    position: np.ndarray, log_scales: np.ndarray, sigma: float = DEFAULT_SIGMA
) -> float:
    """The largest semi-axis (scene units) the display draws, for this cloud.

    The 99th percentile of the drawn size ``sigma * exp(max_i scale_i)``, but at most the
    larger of :data:`OUTLIER_FACTOR` times the median drawn size and :data:`EXTENT_FRACTION`
    of the diagonal of the box holding the middle 98% of the means. So a cloud whose splats
    are all alike is drawn as it is, while a few percent of huge splats (far ground,
    background) neither set the limit nor cover the scene.

    Args:
        position: [N, 3] means.
        log_scales: [N, 3] natural-log scales (the PLY's ``scale_*``).
        sigma: the display's sigma multiplier.

    Returns:
        A positive finite size; 1.0 for an empty cloud.
    """
    position = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    log_scales = np.asarray(log_scales, dtype=np.float64).reshape(-1, 3)
    if position.shape[0] == 0:
        return 1.0
    drawn = sigma * np.exp(np.clip(log_scales.max(axis=1), -80.0, 80.0))  # [N]
    lo, hi = np.percentile(position, [1.0, 99.0], axis=0)  # [3], [3]
    extent = float(np.linalg.norm(hi - lo))
    ceiling = max(OUTLIER_FACTOR * float(np.median(drawn)), EXTENT_FRACTION * extent)
    size = min(float(np.percentile(drawn, 99.0)), ceiling)
    return size if np.isfinite(size) and size > 0.0 else 1.0


def native_attributes(attributes: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Our point attributes -> Blender 5.3's Gaussian-splat point-cloud attributes (UNTESTED
    against Blender 5.3: the layout follows its release notes).

    * ``position`` [N, 3] as is;
    * ``rotation`` [N, 4] the unit quaternion (w, x, y, z), Blender's quaternion order and
      the PLY's ``rot_*`` order, normalised (a zero quaternion becomes the identity, as
      :func:`prosplat.read_ply` reads it);
    * ``scale`` [N, 3] linear standard deviations, ``exp(scale_*)``;
    * ``opacity`` [N] in [0, 1], ``sigmoid(opacity)``;
    * ``radiance:0`` [N, 3] the view-independent colour ``SH0 * C0 + 0.5`` (linear radiance
      as the rasterizer computes it, not clamped), and ``radiance:1`` .. ``radiance:K-1`` the
      higher SH coefficients per colour channel, from ``f_rest_*`` (channel-major in the PLY).

    All float32. Raises ``KeyError`` naming a missing attribute.
    """
    pos = np.asarray(attributes["position"], dtype=np.float32).reshape(-1, 3)
    n = pos.shape[0]

    def col(name: str) -> np.ndarray:
        return np.asarray(attributes[name], dtype=np.float64).reshape(n)

    quat = np.stack([col(f"rot_{i}") for i in range(4)], axis=1)  # [N, 4] wxyz
    norm = np.linalg.norm(quat, axis=1, keepdims=True)  # [N, 1]
    quat = np.where(norm > 0, quat / np.where(norm > 0, norm, 1.0), [1.0, 0.0, 0.0, 0.0])
    with np.errstate(over="ignore"):
        scale = np.exp(np.stack([col(f"scale_{i}") for i in range(3)], axis=1))  # [N, 3]
    opacity = np.exp(-np.logaddexp(0.0, -col("opacity")))  # [N] stable sigmoid
    out = {
        "position": pos,
        "rotation": quat.astype(np.float32),
        "scale": scale.astype(np.float32),
        "opacity": opacity.astype(np.float32),
        "radiance:0": (np.stack([col(f"f_dc_{i}") for i in range(3)], axis=1) * SH_C0 + 0.5)
        .astype(np.float32),
    }  # fmt: skip
    rest = sorted(
        (k for k in attributes if k.startswith("f_rest_")), key=lambda k: int(k.split("_")[-1])
    )
    if rest:
        k1 = len(rest) // 3  # coefficients per channel besides the DC
        block = np.stack([col(name) for name in rest], axis=1).reshape(n, 3, k1)  # [N, 3, K-1]
        for j in range(k1):
            out[f"radiance:{j + 1}"] = np.ascontiguousarray(block[:, :, j], dtype=np.float32)
    return out
