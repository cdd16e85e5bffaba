"""Put a structure-from-motion model upright, centred and at a sensible scale.

SfM returns poses in an arbitrary frame at an arbitrary scale (the first image pair decides
both). Blender's viewport and the generator's depth range want the scene standing on +Z
with cameras a few units away, so every pose folder is written in one normal form:

* **up**: people hold cameras level, so the mean of the cameras' up vectors (OpenCV -y,
  in world coordinates) is gravity's opposite; it is rotated onto +Z (Blender's up).
* **centre**: the median of the sparse points (robust to the far-away outliers SfM
  triangulates on the sky or through windows) moves to the origin.
* **scale**: the median distance of the camera centres to that centre becomes
  :data:`TARGET_DISTANCE` units.

:func:`near_far` gives the depth range from the points; it is the one rule:
:func:`prosplat.pipeline.posed_views.near_far_from_points` calls it for posed sets.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "TARGET_DISTANCE",
    "near_far",
    "rotation_between",
    "transform_world_to_cam",
    "upright_similarity",
]

TARGET_DISTANCE = 4.0
# the depth range from sparse points (SfM points sit on textured surfaces and have outliers)
NEAR_MARGIN = 0.8
FAR_MARGIN = 1.5
POINT_PERCENTILES = (2.0, 98.0)
MIN_POINTS = 8


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[3,3] the smallest rotation taking direction ``a`` onto direction ``b``."""
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def upright_similarity(
    rotations: np.ndarray, centres: np.ndarray, points: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity ``x' = s · R x + t`` that makes a model upright (see the module doc).

    Args:
        rotations: [N,3,3] world-to-camera rotations (OpenCV axes).
        centres: [N,3] camera centres in world coordinates.
        points: [P,3] sparse points (may be empty: the cameras' median centre is used).
    Returns:
        ``(s, R [3,3], t [3])``.
    """
    rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    up = (-rotations[:, 1, :]).mean(axis=0)  # row 1 of w2c = the camera's y axis in the world
    R = rotation_between(up, [0.0, 0.0, 1.0]) if np.linalg.norm(up) > 1e-6 else np.eye(3)
    anchor = points if len(points) else centres
    centre = np.median(anchor @ R.T, axis=0)  # per axis, in the upright frame
    dist = float(np.median(np.linalg.norm(centres @ R.T - centre, axis=1)))
    s = TARGET_DISTANCE / dist if dist > 1e-12 else 1.0
    return s, R, -s * centre


def transform_world_to_cam(
    world_to_cam: np.ndarray, s: float, R: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """[N,4,4] world-to-camera matrices after the world moves by ``x' = s · R x + t``
    (the cameras keep their images: rotation ``R_c Rᵀ``, centre ``s R c + t``)."""
    w2c = np.asarray(world_to_cam, dtype=np.float64).reshape(-1, 4, 4)
    rot = w2c[:, :3, :3] @ R.T
    centres = -np.einsum("nji,nj->ni", w2c[:, :3, :3], w2c[:, :3, 3])  # -Rᵀ t
    new_c = s * centres @ R.T + t
    out = np.tile(np.eye(4), (len(w2c), 1, 1))
    out[:, :3, :3] = rot
    out[:, :3, 3] = -np.einsum("nij,nj->ni", rot, new_c)
    return out


def near_far(
    points: np.ndarray,
    world_to_cam: np.ndarray,
    observed: Sequence[np.ndarray] | None = None,
    sizes: Sequence[tuple[int, int]] | None = None,
    intrinsics: np.ndarray | None = None,
) -> tuple[float, float] | None:
    """A depth range from sparse points: ``(0.8 · q2, 1.5 · q98)`` of the depths of the points
    each camera observes (``observed[i]``: indices into ``points``), or without tracks of every
    point in front of it (inside its image when ``sizes``/``intrinsics [N,3,3]`` are given).
    None when fewer than :data:`MIN_POINTS` points are seen."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    w2c = np.asarray(world_to_cam, dtype=np.float64).reshape(-1, 4, 4)
    depths, used = [], np.zeros(len(pts), dtype=bool)
    for i, m in enumerate(w2c):
        if observed is not None and len(observed[i]) > 0:
            idx = np.asarray(observed[i], dtype=np.int64)
        else:
            idx = np.arange(len(pts))
        cam = pts[idx] @ m[:3, :3].T + m[:3, 3]
        ok = np.isfinite(cam[:, 2]) & (cam[:, 2] > 0)
        if (
            (observed is None or len(observed[i]) == 0)
            and sizes is not None
            and intrinsics is not None
        ):
            uv = cam[:, :2] / np.maximum(cam[:, 2:], 1e-12) @ intrinsics[i][:2, :2].T
            uv = uv + intrinsics[i][:2, 2]
            w, h = sizes[i]
            ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)
        used[idx[ok]] = True
        depths.append(cam[ok, 2])
    if int(used.sum()) < MIN_POINTS:
        return None
    lo, hi = np.percentile(np.concatenate(depths), POINT_PERCENTILES)
    near, far = NEAR_MARGIN * float(lo), FAR_MARGIN * float(hi)
    return (near, far) if 0 < near < far else None
