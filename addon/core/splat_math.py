"""How the add-on shows Gaussians, in numbers: display limits and the attribute layout of
Blender's native Gaussian-splat point clouds. No ``bpy`` and no ``prosplat``, only numpy:
Blender's Python may have no torch (jobs then run in an external Python), and ``import
prosplat`` imports torch, so display maths the add-on needs at object creation lives here.

The add-on draws each Gaussian as an ellipsoid of semi-axes ``sigma * exp(scale_i)``. A
generator's pixel-aligned Gaussians grow with depth, so far ground splats can be several
scene units across and, drawn as solids, hide the whole scene; :func:`default_max_size` picks a
clamp from the cloud itself so that only those outliers are limited.

:func:`native_attributes` converts our point attributes (the 3DGS PLY encodings, see
``prosplat.convert.pointcloud``) to the attributes of the ``GAUSSIAN_SPLAT`` point cloud that
Blender 5.3 renders natively, in the layout its own PLY importer writes (checked against
bpy 5.3 in ``tests/addon/test_addon_native_splats.py``); :func:`ply_attributes` is the way back.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

#: The degree-0 SH basis constant, 1 / (2 sqrt(pi)) (``prosplat.core.gaussians.SH_C0``).
SH_C0 = 0.28209479177387814
#: Blender 5.3's ``GAUSSIAN_SPLAT`` attributes: the DC colour and linear opacity (FLOAT4) ...
NATIVE_BASE = "radiance:base"
#: ... and the PLY values Blender rounds, kept beside them on clouds made here (exact export).
EXACT_NAMES = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def native_sh_name(j: int) -> str:
    """Blender 5.3's name of the j-th higher SH coefficient (j = 0 is the PLY's first
    ``f_rest`` of each channel)."""
    return f"radiance:sh_{j}"


__all__ = [
    "DEFAULT_SIGMA",
    "DEFAULT_VIEWPORT_POINTS",
    "EXACT_NAMES",
    "NATIVE_BASE",
    "default_max_size",
    "native_attributes",
    "native_sh_name",
    "ply_attributes",
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


def _normalised_quaternions(quat: np.ndarray) -> np.ndarray:
    """[N, 4] wxyz -> unit quaternions as Blender 5.3's PLY importer computes them (float32,
    ``q * (1 / sqrt(w^2 + x^2 + y^2 + z^2))`` summed in that order: bit for bit the same); a
    zero quaternion becomes the identity, as :func:`prosplat.read_ply` reads it."""
    q = np.asarray(quat, dtype=np.float32).reshape(-1, 4)
    norm2 = q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3]  # [N]
    ok = norm2 > 0
    with np.errstate(divide="ignore"):
        inv = np.float32(1.0) / np.sqrt(np.where(ok, norm2, np.float32(1.0)))  # [N]
    return np.where(ok[:, None], q * inv[:, None], np.array([1, 0, 0, 0], np.float32))


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return np.exp(-np.logaddexp(0.0, -np.asarray(x, dtype=np.float64)))  # stable, float64


def native_attributes(attributes: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Our point attributes (the 3DGS PLY encodings) -> the attributes of a Blender 5.3
    ``GAUSSIAN_SPLAT`` point cloud, in the layout Blender's own PLY importer writes:

    * ``position`` [N, 3] as is;
    * ``rotation`` [N, 4] (QUATERNION) the unit quaternion (w, x, y, z), normalised as
      Blender does it (bit for bit);
    * ``scale`` [N, 3] (FLOAT_VECTOR) linear standard deviations, ``exp(scale_*)``;
    * ``radiance:base`` [N, 4] (FLOAT4) the raw ``f_dc_0..2`` and ``sigmoid(opacity)``;
    * ``radiance:sh_j`` [N, 3] (FLOAT_VECTOR), j = 0 .. K-2: the (R, G, B) of the j-th higher
      SH coefficient, from ``f_rest_*`` (channel-major in the PLY).

    The exponentials are computed in float64 and rounded, so ``scale`` and the opacity may
    differ from Blender's own ``expf`` by one unit in the last place (about 1 value in 1,000);
    the positions, SH and rotations are Blender's exactly. All float32. Raises ``KeyError``
    naming a missing attribute.
    """
    pos = np.asarray(attributes["position"], dtype=np.float32).reshape(-1, 3)
    n = pos.shape[0]

    def col(name: str) -> np.ndarray:
        return np.asarray(attributes[name], dtype=np.float32).reshape(n)

    quat = _normalised_quaternions(np.stack([col(f"rot_{i}") for i in range(4)], axis=1))
    log_scale = np.stack([col(f"scale_{i}") for i in range(3)], axis=1).astype(np.float64)
    with np.errstate(over="ignore"):
        scale = np.exp(log_scale)  # [N, 3]
    base = np.empty((n, 4), dtype=np.float32)
    base[:, :3] = np.stack([col(f"f_dc_{i}") for i in range(3)], axis=1)
    base[:, 3] = _sigmoid(col("opacity"))
    out = {
        "position": pos,
        "rotation": quat,
        "scale": scale.astype(np.float32),
        NATIVE_BASE: base,
    }
    rest = sorted(
        (k for k in attributes if k.startswith("f_rest_")), key=lambda k: int(k.split("_")[-1])
    )
    if rest:
        k1 = len(rest) // 3  # coefficients per channel besides the DC
        block = np.stack([col(name) for name in rest], axis=1).reshape(n, 3, k1)  # [N, 3, K-1]
        for j in range(k1):
            out[native_sh_name(j)] = np.ascontiguousarray(block[:, :, j])
    return out


def native_sh_count(names) -> int:
    """How many ``radiance:sh_j`` attributes (j = 0, 1, ... without a gap) ``names`` holds."""
    count = 0
    while native_sh_name(count) in names:
        count += 1
    return count


def ply_attributes(
    native: Mapping[str, np.ndarray], exact: Mapping[str, np.ndarray] | None = None
) -> dict[str, np.ndarray]:
    """Inverse of :func:`native_attributes`: a ``GAUSSIAN_SPLAT`` cloud's attributes -> our
    point attributes (the 3DGS PLY encodings), for Render View, Refine and Export PLY.

    Blender keeps only the rounded linear values (``exp(scale)``, ``sigmoid(opacity)``, the
    normalised quaternion), so a cloud made here also stores the PLY's own ``opacity``,
    ``scale_*`` and ``rot_*`` (:data:`EXACT_NAMES`); passed as ``exact``, each is used for a
    point where it still agrees with the native value (so the PLY round trip stays bit-exact)
    and the native value decoded (``logit``, ``log``) wherever it does not, as for a cloud
    Blender imported itself or one an artist edited. ``f_dc``/``f_rest`` are Blender's values
    as they are, so they are exact either way.
    """
    exact = exact or {}
    pos = np.asarray(native["position"], dtype=np.float32).reshape(-1, 3)
    n = pos.shape[0]
    base = np.asarray(native[NATIVE_BASE], dtype=np.float32).reshape(n, 4)
    scale = np.asarray(native["scale"], dtype=np.float32).reshape(n, 3)
    quat = np.asarray(native["rotation"], dtype=np.float32).reshape(n, 4)
    out: dict[str, np.ndarray] = {"position": pos}

    def kept(name: str, derived: np.ndarray, agrees) -> np.ndarray:
        raw = exact.get(name)
        if raw is None:
            return derived.astype(np.float32)
        raw = np.asarray(raw, dtype=np.float32).reshape(n)
        return np.where(agrees(raw), raw, derived).astype(np.float32)

    alpha = np.clip(base[:, 3].astype(np.float64), 1e-7, 1.0 - 1e-7)
    out["opacity"] = kept("opacity", np.log(alpha) - np.log1p(-alpha),
                          lambda raw: np.abs(_sigmoid(raw) - base[:, 3]) <= 1e-6)  # fmt: skip
    with np.errstate(divide="ignore"):
        log_scale = np.log(np.maximum(scale.astype(np.float64), 1e-30))  # [N, 3]
    for i in range(3):
        out[f"scale_{i}"] = kept(
            f"scale_{i}", log_scale[:, i],
            lambda raw, i=i: np.isclose(np.exp(raw.astype(np.float64)), scale[:, i], rtol=1e-5,
                                        atol=0.0),
        )  # fmt: skip
    raw_quat = np.stack(
        [np.asarray(exact.get(f"rot_{i}", quat[:, i]), np.float32).reshape(n) for i in range(4)],
        axis=1,
    )  # [N, 4]
    same = np.all(np.abs(_normalised_quaternions(raw_quat) - quat) <= 1e-6, axis=1)  # [N]
    for i in range(4):
        out[f"rot_{i}"] = np.where(same, raw_quat[:, i], quat[:, i]).astype(np.float32)
    for i in range(3):
        out[f"f_dc_{i}"] = np.ascontiguousarray(base[:, i])
    k1 = native_sh_count(native)
    for j in range(k1):
        sh = np.asarray(native[native_sh_name(j)], dtype=np.float32).reshape(n, 3)
        for c in range(3):
            out[f"f_rest_{c * k1 + j}"] = np.ascontiguousarray(sh[:, c])
    return out
