"""Depth anchors against a known truth: a tilted plane seen by a pinhole camera, its depth map
distorted by an affine map in inverse depth, and 3D points on the true plane (some of them
gross outliers, as SfM's are)."""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.geometry.anchors import anchor_depths, fit_inverse_depth, point_depths


def plane_scene(h: int = 48, w: int = 64) -> tuple[Camera, Tensor, Tensor]:
    """A camera at the origin looking down +z at the plane z = 4 + 0.05·x_pixel-ish tilt:
    (camera, true depth [H,W], world points on the plane [P,3] at random pixels)."""
    K = torch.tensor([[60.0, 0, w / 2], [0, 60.0, h / 2], [0, 0, 1]], dtype=torch.float64)
    cam = Camera(K=K, world_to_cam=torch.eye(4, dtype=torch.float64), width=w, height=h)
    cols = torch.arange(w, dtype=torch.float64) + 0.5
    rows = torch.arange(h, dtype=torch.float64) + 0.5
    depth = 4.0 + 0.04 * cols[None, :] + 0.02 * rows[:, None]  # [H,W]
    g = torch.Generator().manual_seed(0)
    r = torch.randint(0, h, (200,), generator=g)
    c = torch.randint(0, w, (200,), generator=g)
    z = depth[r, c]
    x = (c.double() + 0.5 - w / 2) / 60.0 * z
    y = (r.double() + 0.5 - h / 2) / 60.0 * z
    return cam, depth, torch.stack([x, y, z], dim=-1)


def test_fit_recovers_affine_map_despite_outliers():
    g = torch.Generator().manual_seed(1)
    d = torch.rand(300, generator=g, dtype=torch.float64) + 0.2
    y = 0.7 * d + 0.05
    y[:30] += torch.rand(30, generator=g, dtype=torch.float64) * 2  # 10 % gross outliers
    a, b = fit_inverse_depth(d, y)
    assert abs(a - 0.7) < 1e-3 and abs(b - 0.05) < 1e-3


def test_point_depths_land_on_their_pixels():
    cam, depth, pts = plane_scene()
    idx, z = point_depths(pts, cam, 48, 64)
    assert len(idx) == len(pts)
    torch.testing.assert_close(depth.reshape(-1)[idx], z, rtol=0, atol=1e-9)
    # the same points on a half-size map of the same camera
    idx2, z2 = point_depths(pts, cam, 24, 32)
    assert int(idx2.max()) < 24 * 32 and torch.equal(z2, z)


def test_anchor_depths_undo_a_wrong_scale_and_offset():
    cam, depth, pts = plane_scene()
    wrong = 1.0 / (1.3 / depth + 0.04)  # the generator's view: off by an inverse-depth affine map
    pts = pts.clone()
    pts[:15] *= 1.6  # outliers along their rays: wrong depth, same pixel
    out, fits = anchor_depths(wrong[None].float(), [cam], pts)
    assert fits[0].used and fits[0].points == 200
    assert fits[0].before > 0.05 and fits[0].after < 1e-3
    rel = ((out[0].double() - depth).abs() / depth).max()
    assert rel < 1e-3


def test_views_without_enough_trustworthy_points_are_left_alone():
    cam, depth, pts = plane_scene()
    d = depth[None].float()
    out, fits = anchor_depths(d, [cam], pts[:5])  # too few
    assert not fits[0].used and torch.equal(out, d)
    # points whose inverse depth falls where the map's rises: a negative slope is no alignment
    z = pts[:, 2]
    flipped = pts * ((1.0 / (0.6 - 1.0 / z)) / z)[:, None]  # same pixels, depths reversed
    out, fits = anchor_depths(d, [cam], flipped)
    assert fits[0].scale < 0 and not fits[0].used and torch.equal(out, d)
    # observed indices restrict a view to its own points
    out, fits = anchor_depths(d, [cam], pts, [torch.arange(8)])
    assert fits[0].points == 8 and not fits[0].used
