"""MORI: pick the input view that overlaps the target view most, as the reference for stage 2.

Two scores:

* :func:`mori_scores`, the paper's ``1/‖T_t − T_j‖ + ½(cos(z_t, z_j) + 1)``. Cheap and needs
  no depth, but its first term has units (1/metres) while the second has none, so the choice
  depends on the scene's scale: in a scene modelled in millimetres the angle always wins, in
  one modelled in kilometres the distance always wins.
* :func:`overlap_scores`, the geometric overlap: the fraction of the target's pixels whose
  surface point is seen by input j (inside its frame, in front of it and, given input depth,
  not occluded). Unit-free, and what "overlap" means; needs the target's rendered depth,
  which stage 1 gives for free.

:func:`select_reference` wraps both.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from prosplat.core.camera import Camera

__all__ = ["centre_distances", "mori_scores", "overlap_scores", "select_reference"]

# A target closer to an input than this fraction of the rig's scale counts as coincident with
# it: 1/distance is clamped there, so the score stays finite (≈1e9 / scale, far above any
# real camera's) and the coincident input wins.
_COINCIDENT_REL_EPS = 1e-9


def _check_cameras(target: Camera, inputs: Sequence[Camera], caller: str) -> None:
    if not isinstance(target, Camera):
        raise ValueError(f"{caller}: target must be a prosplat.Camera, got {type(target).__name__}")
    if len(inputs) == 0:
        raise ValueError(f"{caller}: inputs is empty; pass at least one input camera")
    for j, cam in enumerate(inputs):
        if not isinstance(cam, Camera):
            raise ValueError(
                f"{caller}: inputs[{j}] must be a prosplat.Camera, got {type(cam).__name__}"
            )
    for name, cam in [("target", target)] + [(f"inputs[{j}]", c) for j, c in enumerate(inputs)]:
        if not (torch.isfinite(cam.K).all() and torch.isfinite(cam.world_to_cam).all()):
            raise ValueError(
                f"{caller}: {name} has a non-finite pose or intrinsics; fix the camera"
            )


def centre_distances(target: Camera, inputs: Sequence[Camera]) -> Tensor:
    """[N] float64 on the CPU: the distance from ``target``'s camera centre to each input's
    (MORI's first term; :func:`prosplat.pipeline.enhance.view_weights` weighs the views by them)."""
    c_t = target.center.double().cpu()  # [3]
    centres = torch.stack([c.center.double().cpu() for c in inputs])  # [N, 3]
    return (centres - c_t).norm(dim=-1)


def mori_scores(target: Camera, inputs: Sequence[Camera]) -> Tensor:
    """The paper's MORI score of every input view for ``target`` (higher overlaps more).

    ``score_j = 1 / max(‖T_t − T_j‖, ε) + ½(cos(z_t, z_j) + 1)`` with T the camera centres and
    z the viewing directions in world space. ε = 1e-9 × the largest target-to-input distance
    (1 if every input coincides with the target): a coincident input then scores ~1e9/scale
    and wins, with no division by zero.

    Args:
        target: the view to enhance.
        inputs: N input cameras.
    Returns:
        [N] float64 scores.
    """
    _check_cameras(target, inputs, "mori_scores")
    z_t = target.forward.double().cpu()
    forwards = torch.stack([c.forward.double().cpu() for c in inputs])  # [N, 3]
    dist = centre_distances(target, inputs)  # [N]
    scale = float(dist.max())
    eps = _COINCIDENT_REL_EPS * scale if scale > 0 else 1.0
    cos = torch.nn.functional.cosine_similarity(forwards, z_t[None], dim=-1)  # [N]
    return 1.0 / dist.clamp_min(eps) + 0.5 * (cos + 1.0)


def _camera_for(cam: Camera, depth: Tensor, name: str) -> Camera:
    """``cam`` at the depth map's resolution (depth maps may be rendered at any size)."""
    if depth.dim() != 2:
        raise ValueError(f"overlap_scores: {name} must be [H, W], got {tuple(depth.shape)}")
    h, w = depth.shape
    return cam if (w, h) == (cam.width, cam.height) else cam.resized(w, h)


def overlap_scores(
    target: Camera,
    target_depth: Tensor,
    inputs: Sequence[Camera],
    input_depths: Tensor | None = None,
    rel_tol: float = 0.05,
) -> Tensor:
    """Fraction of the target's pixels whose surface point input j sees.

    Every target pixel with depth > 0 is lifted to its 3D point and projected into input j; it
    counts if it lands inside j's frame, in front of j, and (when ``input_depths`` is given) is
    not occluded there: its depth in view j is at most ``(1 + rel_tol)`` × j's depth at the
    nearest pixel (j's depth 0 means nothing is there, so nothing occludes). The fraction is
    over ALL target pixels, so empty target pixels count as not overlapping; it is unit-free.

    Depth maps may be at any resolution; the cameras are rescaled to match (the field of view
    is what matters).

    Args:
        target: the view to enhance.
        target_depth: [H, W] z along the target's optical axis, 0 where empty.
        inputs: N input cameras.
        input_depths: optional [N, H', W'] input depth maps, 0 where empty.
        rel_tol: relative depth tolerance of the occlusion test.
    Returns:
        [N] float64 fractions in [0, 1].
    """
    _check_cameras(target, inputs, "overlap_scores")
    target_depth = torch.as_tensor(target_depth)
    if not torch.isfinite(target_depth).all():
        raise ValueError("overlap_scores: target_depth contains NaN or Inf; use 0 for empty pixels")
    if not rel_tol >= 0:
        raise ValueError(f"overlap_scores: rel_tol must be >= 0, got {rel_tol}")
    cam_t = _camera_for(target, target_depth, "target_depth").to("cpu", torch.float64)
    depth = target_depth.detach().to("cpu", torch.float64)
    if input_depths is not None:
        input_depths = torch.as_tensor(input_depths)
        if input_depths.dim() != 3 or input_depths.shape[0] != len(inputs):
            raise ValueError(
                f"overlap_scores: input_depths must be [N={len(inputs)}, H, W], got {tuple(input_depths.shape)}"
            )
        if not torch.isfinite(input_depths).all():
            raise ValueError(
                "overlap_scores: input_depths contains NaN or Inf; use 0 for empty pixels"
            )
        input_depths = input_depths.detach().to("cpu", torch.float64)

    filled = depth > 0  # [H, W]
    total = depth.numel()
    uv = cam_t.pixel_centers(torch.float64)[filled]  # [M, 2]
    points = cam_t.unproject(uv, depth[filled])  # [M, 3]
    scores = torch.zeros(len(inputs), dtype=torch.float64)
    if points.shape[0] == 0:
        return scores
    for j, cam in enumerate(inputs):
        if input_depths is None:
            cam_j = cam.to("cpu", torch.float64)
        else:
            cam_j = _camera_for(cam, input_depths[j], f"input_depths[{j}]").to("cpu", torch.float64)
        col, row, z, seen = cam_j.nearest_pixels(points)  # [M] each
        if input_depths is not None:
            d_j = input_depths[j][row, col]  # [M]
            seen = seen & ((d_j <= 0) | (z <= d_j * (1.0 + rel_tol)))
        scores[j] = seen.sum().double() / total
    return scores


def select_reference(
    target: Camera,
    inputs: Sequence[Camera],
    method: str = "paper",
    target_depth: Tensor | None = None,
    input_depths: Tensor | None = None,
) -> int:
    """Index of the input view to use as the reference for ``target``.

    ``method="paper"`` maximises :func:`mori_scores`; ``"overlap"`` maximises
    :func:`overlap_scores` (needs ``target_depth``; ``input_depths`` adds the occlusion test).
    Ties go to the lowest index. If no input sees any of the target (all overlaps 0, e.g. an
    empty render), the overlap carries no information and the paper's score decides.
    """
    if method == "paper":
        scores = mori_scores(target, inputs)
    elif method == "overlap":
        if target_depth is None:
            raise ValueError(
                "select_reference: method='overlap' needs target_depth (render the target's depth); "
                "or use method='paper'"
            )
        scores = overlap_scores(target, target_depth, inputs, input_depths)
        if not (scores > 0).any():
            scores = mori_scores(target, inputs)
    else:
        raise ValueError(f"select_reference: unknown method {method!r}; use 'paper' or 'overlap'")
    return int((scores == scores.max()).nonzero()[0, 0])  # the first maximum on ties
