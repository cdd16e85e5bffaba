"""Rig geometry: where a set of input cameras looks, and the depth range they can measure.

The generator needs a depth range (near, far) to place its depth candidates. Data with known
bounds (Blender scenes, COLMAP points) passes one; otherwise it is derived here from the
cameras alone, with no scene content: :func:`convergence_point` finds where the optical axes
of an object-centric rig meet, and :func:`near_far_from_cameras` turns either that point or
the rig's baselines into near/far. Kept apart from the model (:mod:`prosplat.pipeline.model`,
which calls it when near/far are not given) because it is pure geometry with no network:
``prosplat reconstruct`` derives its depth range with it before any model runs.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from prosplat.core.camera import Camera

#: near = NEAR_FACTOR · (smallest camera distance) · f / image size (see near_far_from_cameras)
NEAR_FACTOR = 0.5
#: far = FAR_FACTOR · max(largest camera distance, near), for rigs that do not converge
FAR_FACTOR = 100.0
#: converging rigs: near/far = these factors times the nearest/farthest camera's depth of the
#: point the optical axes meet at
CONVERGING_NEAR = 0.5
CONVERGING_FAR = 2.5
#: axes converge when that point is in front of every camera, inside its image, and no farther
#: than this many times the rig's largest baseline (nearly parallel axes meet far away)
CONVERGING_MAX_DEPTH = 20.0


def convergence_point(cameras: Sequence[Camera]) -> Tensor | None:
    """The point the cameras' optical axes meet at (least squares), or None when they do not
    converge: the point must lie in front of every camera and project inside its image, and
    be at most :data:`CONVERGING_MAX_DEPTH` times the largest baseline from every camera (axes
    that are nearly parallel, e.g. a forward-facing capture, meet far away or nowhere)."""
    centers = torch.stack([c.center.double().cpu() for c in cameras])  # [N,3]
    fwd = torch.stack([c.forward.double().cpu() for c in cameras])  # [N,3]
    eye = torch.eye(3, dtype=torch.float64)
    P = eye[None] - fwd[:, :, None] * fwd[:, None, :]  # [N,3,3] projectors off each axis
    A, rhs = P.sum(0), (P @ centers[:, :, None]).sum(0)[:, 0]
    if float(torch.linalg.eigvalsh(A)[0]) < 1e-9 * len(cameras):
        return None  # all axes parallel
    p = torch.linalg.solve(A, rhs)
    baseline = float(torch.cdist(centers, centers).max())
    for cam in cameras:
        c = cam.to(dtype=torch.float64)
        uv, z = c.project(p[None].to(c.K))
        u, v = float(uv[0, 0]), float(uv[0, 1])
        if not (0 < float(z[0]) <= CONVERGING_MAX_DEPTH * baseline):
            return None
        if not (0 <= u <= cam.width and 0 <= v <= cam.height):
            return None
    return p


def near_far_from_cameras(cameras: Sequence[Camera]) -> tuple[float, float]:
    """A depth range from the cameras alone (no triangulation, no scene content).

    *Converging rigs* (object-centric captures such as NeRF-synthetic scenes, whose optical
    axes meet in front of the cameras, see :func:`convergence_point`): the scene is around the
    point p the axes meet at, so ``near`` is :data:`CONVERGING_NEAR` times the smallest depth
    of p over the cameras and ``far`` :data:`CONVERGING_FAR` times the largest. A lego-like
    rig (radius 4, object radius 1.5) gets near 2, in front of the object's surface at 2.5,
    and far 10, past its back at 5.5.

    *Other rigs* (forward-facing, diverging): two cameras a baseline b apart see a point at
    depth z shifted by about ``f·b/z`` pixels; once that shift exceeds the image size S the
    point cannot be in both views, so matching can only find depths beyond ``b·f/S``.
    ``near`` is half of that for the closest camera pair, with ``f/S`` the smallest ``fx/W``
    or ``fy/H`` over the cameras. ``far`` is 100 times the rig's largest camera distance: the
    depth candidates are uniform in inverse depth, so a generous far costs only the few
    candidates between 0 and 1/far.

    Data with known bounds (Blender scenes, COLMAP points) should pass near/far instead.

    Raises:
        ValueError: fewer than two cameras, or two cameras at the same place (zero baseline,
            e.g. a pure rotation), where the cameras carry no depth scale.
    """
    if len(cameras) < 2:
        raise ValueError(
            f"near/far need at least two cameras to derive a depth range, got {len(cameras)}"
        )
    centers = torch.stack([c.center.double().cpu() for c in cameras])  # [N,3]
    dist = torch.cdist(centers, centers)  # [N,N]
    n = len(cameras)
    iu = torch.triu_indices(n, n, offset=1)
    pair = dist[iu[0], iu[1]]  # [N(N-1)/2]
    scale = max(1.0, float(centers.abs().max()))
    k = int(pair.argmin())
    if float(pair[k]) <= 1e-6 * scale:
        i, j = int(iu[0, k]), int(iu[1, k])
        raise ValueError(
            f"cameras {i} and {j} are at the same place (zero baseline, e.g. a pure rotation), so the "
            "cameras give no depth scale; pass near= and far= (scene units) explicitly"
        )
    p = convergence_point(cameras)
    if p is not None:
        depths = [float(c.world_to_camera(p[None].to(c.K))[0, 2]) for c in cameras]
        return CONVERGING_NEAR * min(depths), CONVERGING_FAR * max(depths)
    f_over_size = min(min(c.fx / c.width, c.fy / c.height) for c in cameras)
    near = NEAR_FACTOR * float(pair.min()) * f_over_size
    far = FAR_FACTOR * max(float(pair.max()), near)
    return near, far
