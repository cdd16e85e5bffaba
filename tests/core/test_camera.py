"""Camera basics: projection geometry, construction helpers, validation, batching."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera, stack_cameras


def _rotation(rx: float, ry: float, rz: float) -> torch.Tensor:
    """[3, 3] rotation Rz @ Ry @ Rx (float64)."""
    cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                              math.cos(rz), math.sin(rz))  # fmt: skip
    Rx = torch.tensor([[1, 0, 0], [0, cx, -sx], [0, sx, cx]], dtype=torch.float64)
    Ry = torch.tensor([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]], dtype=torch.float64)
    Rz = torch.tensor([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]], dtype=torch.float64)
    return Rz @ Ry @ Rx


def _camera(skew: float = 0.0) -> Camera:
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = _rotation(0.3, -0.7, 1.1)
    w2c[:3, 3] = torch.tensor([0.2, -0.5, 4.0], dtype=torch.float64)
    K = torch.tensor(
        [[500.0, skew, 330.0], [0.0, 480.0, 230.0], [0.0, 0.0, 1.0]], dtype=torch.float64
    )
    return Camera(K, w2c, 640, 480)


def test_project_known_point() -> None:
    # Identity pose: a point 2 m ahead, 0.5 right and 0.25 down lands at cx + fx*0.25 etc.
    cam = Camera.from_intrinsics(100.0, 200.0, 32.0, 24.0, 64, 48)
    uv, depth = cam.project(torch.tensor([[0.5, 0.25, 2.0]], dtype=torch.float64))
    assert uv[0].tolist() == pytest.approx([32.0 + 25.0, 24.0 + 25.0])
    assert depth.item() == pytest.approx(2.0)


@pytest.mark.parametrize("skew", [0.0, 3.5])
def test_project_unproject_round_trip(skew: float) -> None:
    cam = _camera(skew)
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(100, 2, generator=g, dtype=torch.float64) * torch.tensor([640.0, 480.0])
    depth = 0.5 + 10 * torch.rand(100, generator=g, dtype=torch.float64)
    pts = cam.unproject(uv, depth)  # [100, 3]
    uv2, depth2 = cam.project(pts)
    torch.testing.assert_close(uv2, uv, rtol=0, atol=1e-9)
    torch.testing.assert_close(depth2, depth, rtol=0, atol=1e-12)


def test_center_forward_and_cam_to_world() -> None:
    cam = _camera()
    c = cam.center
    # The centre maps to the camera origin; forward is the optical axis (+z row of R).
    torch.testing.assert_close(cam.world_to_camera(c), torch.zeros(3, dtype=torch.float64))
    ahead = cam.world_to_camera(c + 2.0 * cam.forward)
    torch.testing.assert_close(ahead, torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64))
    torch.testing.assert_close(
        cam.cam_to_world @ cam.world_to_cam, torch.eye(4, dtype=torch.float64)
    )
    assert cam.forward.norm().item() == pytest.approx(1.0)


def test_look_at_orientation() -> None:
    # Looking along +Y with +Z up: world +X is image right, world +Z is image up.
    cam = Camera.look_at([0, -5, 1], [0, 0, 1], [0, 0, 1], fx=100.0, width=200, height=100)
    torch.testing.assert_close(cam.center, torch.tensor([0.0, -5.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(cam.forward, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    pts = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 0.0, 2.0]], dtype=torch.float64)
    uv, depth = cam.project(pts)
    torch.testing.assert_close(uv[0], torch.tensor([100.0, 50.0], dtype=torch.float64))
    torch.testing.assert_close(uv[1], torch.tensor([120.0, 50.0], dtype=torch.float64))  # right
    torch.testing.assert_close(uv[2], torch.tensor([100.0, 30.0], dtype=torch.float64))  # up
    torch.testing.assert_close(depth, torch.full((3,), 5.0, dtype=torch.float64))
    assert torch.det(cam.R).item() == pytest.approx(1.0)


def test_look_at_errors() -> None:
    with pytest.raises(ValueError, match="coincide"):
        Camera.look_at([1, 2, 3], [1, 2, 3], [0, 0, 1], fx=10.0, width=4, height=4)
    with pytest.raises(ValueError, match="parallel"):
        Camera.look_at([0, 0, 0], [0, 0, 5], [0, 0, 1], fx=10.0, width=4, height=4)


def _w2c() -> torch.Tensor:
    return torch.eye(4, dtype=torch.float64)


def _K(fx: float = 10.0) -> torch.Tensor:
    return torch.tensor([[fx, 0.0, 2.0], [0.0, fx, 2.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


@pytest.mark.parametrize(
    ("K", "w2c", "size", "match"),
    [
        (_K()[:2], _w2c(), (4, 4), "shape"),
        (_K(float("nan")), _w2c(), (4, 4), "NaN"),
        (_K(-1.0), _w2c(), (4, 4), "positive"),
        (_K(), _w2c(), (0, 4), "at least 1x1"),
        (_K(), _w2c(), (4.5, 4), "integers"),
        (_K(), torch.diag(torch.tensor([2.0, 1.0, 1.0, 1.0], dtype=torch.float64)), (4, 4),
         "orthonormal"),
        (_K(), torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=torch.float64)), (4, 4),
         "det"),
        (_K(), torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]), (4, 4),
         "last row"),
    ],
)  # fmt: skip
def test_validation_errors(K, w2c, size, match) -> None:
    with pytest.raises(ValueError, match=match):
        Camera(K, w2c, *size)


def test_int_K_is_promoted_to_float() -> None:
    cam = Camera(torch.tensor([[10, 0, 2], [0, 10, 2], [0, 0, 1]]), _w2c(), 4, 4)
    assert cam.K.dtype == torch.float64 and cam.world_to_cam.dtype == torch.float64


def test_stack_cameras() -> None:
    cams = [_camera(), Camera.look_at([3, 1, 2], [0, 0, 0], [0, 0, 1], 80.0, 32, 24)]
    batch = stack_cameras(cams)
    assert len(batch) == 2
    assert batch.K.shape == (2, 3, 3) and batch.world_to_cam.shape == (2, 4, 4)
    assert batch.sizes.tolist() == [[640, 480], [32, 24]]
    torch.testing.assert_close(batch.centers, torch.stack([c.center for c in cams]))
    torch.testing.assert_close(batch.forwards, torch.stack([c.forward for c in cams]))
    back = batch[1]
    torch.testing.assert_close(back.K, cams[1].K)
    assert (back.width, back.height) == (32, 24)
    with pytest.raises(ValueError, match="at least one"):
        stack_cameras([])


def test_resized_scales_pixels() -> None:
    cam = Camera.look_at([0, -4, 0], [0, 0, 0], [0, 0, 1], fx=300.0, width=640, height=480)
    small = cam.resized(160, 96)
    # Centred principal point stays centred: pixel centres at +0.5 scale with the image.
    assert (small.cx, small.cy) == (80.0, 48.0)
    pts = torch.tensor([[0.3, 0.1, -0.2], [-1.0, 2.0, 0.5]], dtype=torch.float64)
    uv, d = cam.project(pts)
    uv_s, d_s = small.project(pts)
    torch.testing.assert_close(uv_s, uv * torch.tensor([0.25, 0.2], dtype=torch.float64))
    torch.testing.assert_close(d_s, d)


def test_pixel_centers_and_rays() -> None:
    cam = Camera.look_at([1, 2, 3], [0, 0, 0], [0, 0, 1], fx=10.0, width=4, height=2)
    centers = cam.pixel_centers(torch.float64)
    assert centers.shape == (2, 4, 2)
    assert centers[0, 0].tolist() == [0.5, 0.5] and centers[1, 3].tolist() == [3.5, 1.5]
    rays = cam.ray_directions(torch.float64)  # [2, 4, 3]
    torch.testing.assert_close(rays.norm(dim=-1), torch.ones(2, 4, dtype=torch.float64))
    # The image is 4x2 around the principal point (2, 1): the four middle rays straddle it
    # symmetrically, so their mean points along the optical axis.
    mean = rays[:, 1:3].reshape(-1, 3).mean(0)
    torch.testing.assert_close(mean / mean.norm(), cam.forward)


def test_nearest_pixels_finds_the_pixel_and_flags_outside_points():
    cam = Camera.from_intrinsics(10.0, 10.0, 4.0, 3.0, 8, 6)
    uv = torch.tensor([[2.5, 1.5], [7.9, 5.9], [0.01, 0.01]], dtype=torch.float64)
    pts = cam.unproject(uv, torch.tensor([2.0, 3.0, 1.0], dtype=torch.float64))
    pts = torch.cat([pts, torch.tensor([[0.0, 0.0, -1.0], [100.0, 0.0, 1.0]], dtype=torch.float64)])
    col, row, z, inside = cam.nearest_pixels(pts)
    assert col.tolist()[:3] == [2, 7, 0] and row.tolist()[:3] == [1, 5, 0]
    assert inside.tolist() == [True, True, True, False, False]
    assert z.tolist()[:3] == pytest.approx([2.0, 3.0, 1.0])
    assert 0 <= col.min() and col.max() <= 7 and 0 <= row.min() and row.max() <= 5  # clamped
