"""Depth anchors against a known truth: a tilted plane seen by a pinhole camera, its depth map
distorted by an affine map in inverse depth, and 3D points on the true plane (some of them
gross outliers, as SfM's are)."""

from __future__ import annotations

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.geometry.anchors import anchor_depths, fit_scale, point_depths


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


def test_fit_recovers_the_factor_despite_outliers():
    g = torch.Generator().manual_seed(1)
    z = torch.rand(300, generator=g, dtype=torch.float64) * 3 + 1
    z_pt = 0.8 * z * (1 + 0.002 * torch.randn(300, generator=g, dtype=torch.float64))
    z_pt[:40] *= torch.rand(40, generator=g, dtype=torch.float64) * 3 + 1.2  # 13 % outliers
    assert abs(fit_scale(z, z_pt) - 0.8) < 0.003
    assert abs((z_pt / z).mean() - 0.8) > 0.1  # a plain mean would be far off


def test_point_depths_land_on_their_pixels():
    cam, depth, pts = plane_scene()
    idx, z = point_depths(pts, cam, 48, 64)
    assert len(idx) == len(pts)
    torch.testing.assert_close(depth.reshape(-1)[idx], z, rtol=0, atol=1e-9)
    # the same points on a half-size map of the same camera
    idx2, z2 = point_depths(pts, cam, 24, 32)
    assert int(idx2.max()) < 24 * 32 and torch.equal(z2, z)


def test_anchor_depths_undo_a_wrong_scale():
    cam, depth, pts = plane_scene()
    wrong = depth / 1.3  # the generator's view: 30 % too near
    pts = pts.clone()
    pts[:15] *= 1.6  # outliers along their rays: wrong depth, same pixel
    out, fits = anchor_depths(wrong[None].float(), [cam], pts)
    assert fits[0].used and fits[0].points == 200
    assert fits[0].before > 0.2 and fits[0].after < 1e-3
    assert ((out[0].double() - depth).abs() / depth).max() < 1e-3


def test_views_without_enough_trustworthy_points_are_left_alone():
    cam, depth, pts = plane_scene()
    d = depth[None].float()
    out, fits = anchor_depths(d, [cam], pts[:5])  # too few
    assert not fits[0].used and torch.equal(out, d)
    # a third each at half, the same and twice the depth: the factor stays 1, which does not
    # lower their error, so none is applied
    k = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)[torch.arange(len(pts)) % 3]
    spread = pts * k[:, None]
    out, fits = anchor_depths(d, [cam], spread)
    assert abs(fits[0].scale - 1) < 0.05 and not fits[0].used and torch.equal(out, d)
    # observed indices restrict a view to its own points
    out, fits = anchor_depths(d, [cam], pts, [torch.arange(8)])
    assert fits[0].points == 8 and not fits[0].used
