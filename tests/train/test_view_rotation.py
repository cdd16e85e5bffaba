"""Quarter turns of a view and its camera (prosplat.train.view_rotation), checked against
torch.rot90 on pixel indices, against the camera's own projection, and against the rasterizer:
the turned camera must render exactly the turned image."""

from __future__ import annotations

import pytest
import torch

from prosplat import Camera
from prosplat.render import render
from prosplat.train.view_rotation import (
    quarter_turn_camera,
    quarter_turn_pixels,
    roll_views,
)
from tests.factories import random_gaussians


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_pixel_map_matches_rot90(k):
    w, h = 5, 3
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    index = (ys * w + xs).double()  # [H,W]: which input pixel sits here
    turned = torch.rot90(index, k, dims=(-2, -1))  # [H',W']
    A = quarter_turn_pixels(k, w, h)
    for y2 in range(turned.shape[0]):
        for x2 in range(turned.shape[1]):
            src = int(turned[y2, x2])
            centre = torch.tensor([src % w + 0.5, src // w + 0.5, 1.0], dtype=torch.float64)
            assert torch.allclose(
                A @ centre, torch.tensor([x2 + 0.5, y2 + 0.5, 1.0], dtype=torch.float64)
            )


@pytest.mark.parametrize("k", [1, 2, 3])
def test_turned_camera_projects_through_the_pixel_map(k):
    size = 40
    cam = Camera.look_at((0.3, -2.0, 0.5), (0, 0, 0), (0, 0, 1), 37.0, size, size)
    K = cam.K.clone()
    K[0, 0], K[0, 2], K[1, 2] = 41.0, 18.5, 22.0  # fx != fy, off-centre: the swap must show
    cam = Camera(K, cam.world_to_cam, size, size)
    K2, w2c2 = quarter_turn_camera(cam.K, cam.world_to_cam, k, size, size)
    turned = Camera(K2, w2c2, size, size)
    assert K2[1, 0] == 0 and K2[2, 0] == 0 and K2[2, 1] == 0 and K2[0, 1] == 0
    if k % 2:
        assert (K2[0, 0], K2[1, 1]) == (K[1, 1], K[0, 0])
    pts = torch.randn(50, 3, generator=torch.Generator().manual_seed(k)) * 0.5
    uv, z = cam.project(pts)
    uv2, z2 = turned.project(pts)
    A = quarter_turn_pixels(k, size, size).float()
    mapped = (torch.cat([uv, torch.ones(len(uv), 1)], 1) @ A.T)[:, :2]
    assert torch.allclose(uv2, mapped, atol=1e-4)
    assert torch.allclose(z2, z, atol=1e-5)  # a roll about the axis keeps depth


@pytest.mark.parametrize("k", [1, 3])
def test_turned_camera_renders_the_turned_image(k):
    size = 32
    g = random_gaussians(60, 0, seed=3)
    g = type(g)(g.means * 0.4, g.quats, g.scales * 0.3, g.opacities, g.sh)
    cam = Camera.look_at((0.2, -3.0, 0.4), (0, 0, 0), (0, 0, 1), 30.0, size, size)
    K2, w2c2 = quarter_turn_camera(cam.K, cam.world_to_cam, k, size, size)
    a = render(g, cam)
    b = render(g, Camera(K2, w2c2, size, size))
    assert float(a.alpha.mean()) > 0.05  # something is drawn
    assert torch.allclose(b.rgb, torch.rot90(a.rgb, k, dims=(-2, -1)), atol=2e-4)
    assert torch.allclose(b.depth, torch.rot90(a.depth, k, dims=(-2, -1)), atol=2e-4)


def _batch(size=8, b=2, v=3):
    g = torch.Generator().manual_seed(0)
    cam = Camera.look_at((0, -2.0, 0), (0, 0, 0), (0, 0, 1), 10.0, size, size)
    out = {}
    for group in ("input", "target"):
        out[f"{group}_images"] = torch.rand(b, v, 3, size, size, generator=g)
        out[f"{group}_depths"] = torch.rand(b, v, size, size, generator=g)
        out[f"{group}_K"] = cam.K.float().expand(b, v, 3, 3).clone()
        out[f"{group}_w2c"] = cam.world_to_cam.float().expand(b, v, 4, 4).clone()
    return out


def test_roll_views_off_and_on():
    batch = _batch()
    same = roll_views(batch, 0.0, torch.Generator().manual_seed(1))
    assert same is batch
    turned = roll_views(batch, 1.0, torch.Generator().manual_seed(1))
    again = roll_views(batch, 1.0, torch.Generator().manual_seed(1))
    for key in batch:
        assert torch.equal(turned[key], again[key])  # seeded
    for group in ("input", "target"):
        for i in range(2):
            for j in range(3):
                img, d = batch[f"{group}_images"][i, j], batch[f"{group}_depths"][i, j]
                got = turned[f"{group}_images"][i, j]
                k = next(k for k in (1, 3) if torch.equal(got, torch.rot90(img, k, dims=(-2, -1))))
                assert torch.equal(
                    turned[f"{group}_depths"][i, j], torch.rot90(d, k, dims=(-2, -1))
                )
                K2, w2c2 = quarter_turn_camera(
                    batch[f"{group}_K"][i, j], batch[f"{group}_w2c"][i, j], k, 8, 8
                )
                assert torch.allclose(turned[f"{group}_K"][i, j], K2)
                assert torch.allclose(turned[f"{group}_w2c"][i, j], w2c2)
    assert torch.equal(batch["input_images"], _batch()["input_images"])  # the input is not touched


def test_roll_views_leaves_non_square_batches():
    batch = _batch()
    batch["input_images"] = batch["input_images"][..., :6]
    assert roll_views(batch, 1.0, torch.Generator().manual_seed(1)) is batch
