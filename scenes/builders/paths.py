"""Smooth camera paths (pure numpy, no bpy).

A trajectory is a list of ``(eye, look_at)`` pairs in order along a smooth path; the
renderer picks sparse, wide-baseline subsets of it. Families describe paths either
parametrically (orbits, loops) or by control points through a Catmull-Rom spline
resampled at equal arc length, so consecutive poses are evenly spaced.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

Pose = tuple[tuple[float, float, float], tuple[float, float, float]]
N_POSES = 64


@dataclass
class Built:
    """What a family builder hands back to ``build_scene`` (which adds name and bounds)."""

    eyes: np.ndarray  # [N, 3]
    targets: np.ndarray  # [N, 3]
    lens_mm: float
    tags: tuple[str, ...] = field(default=())

    def trajectory(self) -> list[Pose]:
        """The poses as plain float tuples (the ``SceneInfo`` form)."""
        return [
            (tuple(float(x) for x in e), tuple(float(x) for x in t))
            for e, t in zip(self.eyes, self.targets)
        ]


def catmull_rom(points: np.ndarray, samples_per_segment: int = 32) -> np.ndarray:
    """Dense uniform Catmull-Rom curve through ``points [K, 3]``.

    The end points are duplicated so the curve starts and ends at the first/last point.
    """
    p = np.asarray(points, dtype=np.float64)
    p = np.concatenate([p[:1], p, p[-1:]], axis=0)
    t = np.linspace(0.0, 1.0, samples_per_segment, endpoint=False)[:, None]
    out = []
    for i in range(1, len(p) - 2):
        p0, p1, p2, p3 = p[i - 1], p[i], p[i + 1], p[i + 2]
        out.append(
            0.5
            * (
                2 * p1
                + (-p0 + p2) * t
                + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3
            )
        )
    out.append(p[-2][None])
    return np.concatenate(out, axis=0)


def resample(curve: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points at equal arc length along a dense polyline; also returns the
    fractional index of each into ``curve`` (to resample companion curves alike)."""
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    target = np.linspace(0.0, s[-1], n)
    idx = np.interp(target, s, np.arange(len(curve)))
    return interp_rows(curve, idx), idx


def interp_rows(curve: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``curve`` rows at fractional indices ``idx``."""
    i0 = np.clip(np.floor(idx).astype(int), 0, len(curve) - 1)
    i1 = np.clip(i0 + 1, 0, len(curve) - 1)
    f = (idx - i0)[:, None]
    return curve[i0] * (1 - f) + curve[i1] * f


def loop_parameter(n: int = N_POSES) -> np.ndarray:
    """Angles of ``n`` poses once round a closed loop (the end does not repeat the start)."""
    return np.linspace(0.0, 2 * np.pi, n, endpoint=False)


def orbit(
    centre: np.ndarray,
    radius: float,
    heights: tuple[float, float],
    phase: float,
    wobble: float = 0.15,
    n: int = N_POSES,
    direction: float = 1.0,
) -> np.ndarray:
    """Eyes on a wobbly horizontal loop round ``centre``: radius varies by ``wobble``
    (relative), height between ``heights`` (absolute z), both smoothly."""
    a = loop_parameter(n)
    r = radius * (1 + wobble * np.sin(2 * a + phase))
    z = heights[0] + (heights[1] - heights[0]) * 0.5 * (1 + np.sin(3 * a + 2 * phase))
    ang = phase + direction * a
    return np.stack([centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang), z], axis=1)


def ring(
    centre: np.ndarray,
    distance: float,
    elevation: float,
    phase: float,
    wobble: float = 0.0,
    n: int = N_POSES,
    direction: float = 1.0,
) -> np.ndarray:
    """Eyes once round ``centre [3]`` at a constant ``distance`` from it, ``elevation``
    radians above its horizontal plane, the elevation swinging by ``wobble`` radians (two
    slow cycles a loop; 0: a level ring), starting at azimuth ``phase``.

    The turntable capture of object-centric photo sets (DTU, the Middlebury rings): every
    eye is equally far from the object, so only the viewpoint changes round the loop."""
    a = loop_parameter(n)
    el = elevation + wobble * np.sin(2 * a + phase)
    az = phase + direction * a
    offsets = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    return np.asarray(centre, dtype=np.float64)[None] + distance * offsets
