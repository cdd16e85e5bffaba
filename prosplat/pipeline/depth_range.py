"""The scene's depth range (near/far) for one set of posed inputs, and where it came from.

Why (issue 68, item 3): the generator's cost volume spreads its depth candidates uniformly in
inverse depth between near and far, so a range three times too wide leaves a third of the
candidates on the scene. Camera geometry alone (:func:`prosplat.geometry.rig.near_far_from_cameras`)
can only bound where a scene may be; sparse 3D points say where it is. Posed sets rarely
bring points (``transforms.json``, Middlebury and DTU do not), so the inputs are triangulated
with their known poses (:func:`prosplat.poses.triangulate_inputs`: SIFT, matching and COLMAP's
triangulator, about 0.4 s for four 256-px inputs): on the Middlebury temple the range shrinks
from 0.28-1.44 to 0.42-0.90 and the enhanced view gains (BENCHMARKS "Depth range from the
inputs' own points").

The order: the caller's near/far, else the pose file's own, else its COLMAP points the inputs
observe, else points triangulated from the inputs (pycolmap installed and at least
:data:`~prosplat.poses.frame.MIN_POINTS` points), else the cameras.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass

from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.geometry.anchors import DepthAnchors
from prosplat.geometry.rig import near_far_from_cameras
from prosplat.pipeline.posed_views import near_far_from_points

__all__ = ["DepthRange", "depth_range"]


@dataclass(frozen=True)
class DepthRange:
    """near/far for one set of inputs, a phrase saying where they came from, and the points
    that gave them as depth anchors for :meth:`prosplat.ProSplat.reconstruct` (None when the
    range did not come from points)."""

    near: float
    far: float
    source: str
    anchors: DepthAnchors | None = None


def can_triangulate() -> bool:
    """Whether :func:`prosplat.poses.triangulate_inputs` can run here (pycolmap installed)."""
    return importlib.util.find_spec("pycolmap") is not None


def depth_range(
    images: Tensor,
    cameras: Sequence[Camera],
    *,
    near: float | None = None,
    far: float | None = None,
    file_range: tuple[float, float] | None = None,
    file_name: str = "the pose file",
    points: Tensor | None = None,
    observed: Sequence[Tensor] | None = None,
    triangulate: bool = True,
    given_name: str = "near/far given",
) -> DepthRange:
    """The depth range of ``images [V,3,H,W]`` seen by ``cameras``, in the order of the module
    docstring. ``near``/``far``: the caller's (either may be given alone; the other is
    estimated). ``file_range``: the pose file's own near/far for these inputs; ``points
    [P,3]``/``observed``: a COLMAP model's points and each input's indices into them.
    ``triangulate=False`` skips the triangulation (e.g. a caller that needs no SIFT);
    ``given_name`` names the caller's near/far in ``source`` (the CLI: "--near/--far").

    Raises:
        ValueError: near/far that do not satisfy 0 < near < far, or cameras at one place
            where nothing else gives a range.
    """
    cameras = list(cameras)
    est, src, anchors = None, [], None
    if near is None or far is None:
        if file_range is not None:
            est = file_range
            src.append(f"the near/far in {file_name}")
        if est is None and points is not None and len(points):
            est = near_far_from_points(points, cameras, observed)
            if est is not None:
                src.append(f"COLMAP points seen by the inputs ({len(points)} points)")
                anchors = DepthAnchors(points, None if observed is None else list(observed))
        if est is None and triangulate and len(cameras) >= 2 and can_triangulate():
            from prosplat.poses import quiet_colmap, triangulate_inputs

            quiet_colmap()
            sparse = triangulate_inputs(images, cameras)
            est = near_far_from_points(sparse.points, cameras, sparse.observed)
            if est is not None:
                src.append(
                    f"{len(sparse.points)} points triangulated from the {len(cameras)} inputs "
                    f"({sparse.seconds:.1f} s)"
                )
                anchors = DepthAnchors(sparse.points, sparse.observed)
        if est is None:
            est = near_far_from_cameras(cameras)
            src.append("the input cameras")
    n = near if near is not None else est[0]
    f = far if far is not None else est[1]
    if near is not None or far is not None:
        src.insert(0, given_name)
    if not (0 < n < f) or n != n or f != f:
        raise ValueError(f"near/far must satisfy 0 < near < far, got near={n}, far={f}")
    return DepthRange(float(n), float(f), " + ".join(src), anchors)
