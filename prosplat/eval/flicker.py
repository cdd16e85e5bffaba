"""Consistency along a camera path: how much a sequence of views flickers.

An enhancement model that treats every frame on its own can change the same surface point
differently from one frame to the next; the raw splat renders cannot (the Gaussians are
fixed). The flicker figure measures that: each frame is compared with the next one warped
onto it through the rendered geometry, so what is left is what the frames disagree on, not
the camera's motion. Only pixels that both frames see (the next frame's rendered depth agrees
with the reprojected one) count, so occlusions do not pass for flicker.

Scores come in pairs: the raw renders' figure is the floor set by the rasterizer's own
resampling, and an enhanced sequence is judged by its ratio to it (stage-2 issue: at most
1.2x).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.rotations import rotmat_to_quat
from prosplat.render.projection import quat_to_rotmat

#: A reprojected pixel counts as seen by both frames when the depths agree within this ratio.
DEPTH_AGREEMENT = 0.05


def _slerp(qa: Tensor, qb: Tensor, s: float) -> Tensor:
    """Spherical interpolation of unit quaternions [4] (shortest arc)."""
    dot = float((qa * qb).sum())
    if dot < 0:
        qb, dot = -qb, -dot
    if dot > 0.9995:  # nearly equal: linear is exact enough and avoids 0/0
        q = qa + s * (qb - qa)
        return q / q.norm()
    theta = torch.arccos(torch.tensor(dot, dtype=qa.dtype))
    return (torch.sin((1 - s) * theta) * qa + torch.sin(s * theta) * qb) / torch.sin(theta)


def camera_path(a: Camera, b: Camera, frames: int) -> list[Camera]:
    """``frames`` cameras from ``a`` to ``b`` (both included): centres and intrinsics linear,
    orientation by slerp. Sizes must match."""
    if frames < 2:
        raise ValueError(f"a camera path needs at least 2 frames, got {frames}")
    if (a.width, a.height) != (b.width, b.height):
        raise ValueError(
            f"camera_path: sizes differ ({a.width}x{a.height} vs {b.width}x{b.height})"
        )
    qa, qb = rotmat_to_quat(a.R[None].double())[0], rotmat_to_quat(b.R[None].double())[0]
    ca, cb = a.center.double(), b.center.double()
    out = []
    for i in range(frames):
        s = i / (frames - 1)
        R = quat_to_rotmat(_slerp(qa, qb, s)[None])[0]
        c = (1 - s) * ca + s * cb
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ c
        K = (1 - s) * a.K.double() + s * b.K.double()
        out.append(Camera(K, w2c, a.width, a.height))
    return out


def warp_next(
    frame_next: Tensor, depth: Tensor, depth_next: Tensor, cam: Camera, cam_next: Camera
) -> tuple[Tensor, Tensor]:
    """The next frame ``[3,H,W]`` resampled onto ``cam``'s pixels through ``depth [H,W]``
    (z-depth of ``cam``'s render; 0 or less = empty), and the mask [H,W] of pixels both
    frames see (in view, and ``depth_next`` agreeing with the reprojection)."""
    uv = cam.pixel_centers(torch.float64)  # [H,W,2]
    points = cam.unproject(uv, depth.double())  # [H,W,3]
    uv_next, z_next = cam_next.project(points)  # [H,W,2], [H,W]
    grid = torch.stack(
        [uv_next[..., 0] / cam_next.width * 2 - 1, uv_next[..., 1] / cam_next.height * 2 - 1], -1
    ).float()  # [H,W,2] in grid_sample's align_corners=False convention
    warped = F.grid_sample(frame_next[None].float(), grid[None], align_corners=False)[0]
    seen = F.grid_sample(
        depth_next[None, None].float(), grid[None], mode="nearest", align_corners=False
    )[0, 0]  # [H,W] the next frame's own depth where the point lands
    inside = (grid.abs() <= 1).all(-1) & (depth > 0) & (z_next > 0)
    agree = (seen - z_next.float()).abs() <= DEPTH_AGREEMENT * z_next.float().clamp_min(1e-6)
    return warped, inside & agree & (seen > 0)


def flicker(frames: Tensor, depths: Tensor, cameras: Sequence[Camera]) -> float:
    """Mean absolute difference (colour units) between each frame of ``frames [N,3,H,W]`` and
    the next one warped onto it through ``depths [N,H,W]``, over the pixels both see; NaN when
    no pair shares a pixel."""
    if frames.shape[0] != len(cameras) or depths.shape[0] != len(cameras) or len(cameras) < 2:
        raise ValueError(
            f"flicker needs >= 2 frames with one depth map and camera each; got "
            f"{frames.shape[0]} frames, {depths.shape[0]} depths, {len(cameras)} cameras"
        )
    total, count = 0.0, 0
    for i in range(len(cameras) - 1):
        warped, mask = warp_next(
            frames[i + 1], depths[i], depths[i + 1], cameras[i], cameras[i + 1]
        )
        diff = (frames[i].float() - warped).abs().mean(0)  # [H,W]
        total += float(diff[mask].sum())
        count += int(mask.sum())
    return total / count if count else float("nan")
