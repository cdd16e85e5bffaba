"""Lens distortion: exact inverses, and undistorted checkerboards against the ideal image."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera
from prosplat.convert.colmap import read_colmap_model
from prosplat.convert.distortion import (
    Distortion,
    distort_points,
    undistort_image,
    undistort_points,
    undistorted_camera,
)

F64 = torch.float64
LENSES = {
    "barrel": Distortion("opencv", k1=-0.28, k2=0.07, p1=0.001, p2=-0.002),
    "pincushion": Distortion("opencv", k1=0.15, k2=0.02, k3=0.01),
    "fisheye": Distortion("fisheye", k1=0.05, k2=-0.01, k3=0.002, k4=-0.0005),
}


def test_opencv_formula_by_hand() -> None:
    d = Distortion("opencv", k1=0.1, k2=0.01, k3=0.001, k4=0.0001, p1=0.02, p2=0.03)
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    radial = 1 + 0.1 * r2 + 0.01 * r2**2 + 0.001 * r2**3 + 0.0001 * r2**4
    xd = x * radial + 2 * 0.02 * x * y + 0.03 * (r2 + 2 * x * x)
    yd = y * radial + 0.02 * (r2 + 2 * y * y) + 2 * 0.03 * x * y
    got = distort_points(torch.tensor([x, y], dtype=F64), d)
    torch.testing.assert_close(got, torch.tensor([xd, yd], dtype=F64), rtol=0, atol=1e-15)
    f = Distortion("fisheye", k1=0.1)
    r = math.hypot(x, y)
    th = math.atan(r)
    want = torch.tensor([x, y], dtype=F64) * th * (1 + 0.1 * th * th) / r
    got = distort_points(torch.tensor([x, y], dtype=F64), f)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-15)


@pytest.mark.parametrize("lens", LENSES)
def test_undistort_points_inverts_distort(lens: str) -> None:
    d = LENSES[lens]
    xy = torch.rand(2000, 2, dtype=F64, generator=torch.Generator().manual_seed(0)) * 1.2 - 0.6
    back = undistort_points(distort_points(xy, d), d)
    assert float((back - xy).abs().max()) < 1e-10
    assert float((distort_points(xy, d) - xy).abs().max()) > 1e-3  # the lens does move points


def _checker(xy: torch.Tensor) -> torch.Tensor:
    """A smooth checkerboard (so bilinear sampling error is small) on normalised coords."""
    v = 0.5 + 0.5 * torch.sin(14 * xy[..., 0]) * torch.sin(14 * xy[..., 1])
    return torch.stack([v, 1 - v, 0.5 + 0.4 * torch.sin(9 * xy[..., 0])], 0).float()


def _normalised(cam: Camera) -> torch.Tensor:
    uv = cam.pixel_centers(F64)
    return torch.stack([(uv[..., 0] - cam.cx) / cam.fx, (uv[..., 1] - cam.cy) / cam.fy], -1)


@pytest.mark.parametrize("lens", LENSES)
def test_undistorted_checkerboard_matches_the_ideal_image(lens: str) -> None:
    """Distort a checkerboard with known coefficients, undistort it, compare with the pinhole
    image of the same board through the new camera."""
    d = LENSES[lens]
    cam = Camera.from_intrinsics(150.0, 150.0, 122.0, 86.0, 240, 176)
    distorted = _checker(undistort_points(_normalised(cam), d))  # what the lens records
    new = undistorted_camera(cam, d)
    ideal = _checker(_normalised(new))  # the board through the pinhole `new`
    out = undistort_image(distorted, cam, d, new)
    err = (out - ideal).abs().mean()
    naive = (distorted - _checker(_normalised(cam))).abs().mean()  # ignoring the lens
    assert err < 0.01, err
    assert naive > 10 * err, (naive, err)


@pytest.mark.parametrize("lens", LENSES)
def test_new_camera_keeps_only_the_valid_area(lens: str) -> None:
    """Every pixel of the undistorted image samples inside the input (no borders), and the view
    is not needlessly small: a 3 % wider view would sample outside."""
    d = LENSES[lens]
    cam = Camera.from_intrinsics(150.0, 140.0, 122.0, 86.0, 240, 176)
    new = undistorted_camera(cam, d)
    assert new.fx / new.fy == pytest.approx(cam.fx / cam.fy)
    assert torch.equal(new.world_to_cam, cam.world_to_cam)

    def source_pixels(c: Camera) -> torch.Tensor:
        # pixel *edges*, not centres: the whole output area must map inside the input
        u = torch.linspace(0, c.width, 41, dtype=F64)
        v = torch.linspace(0, c.height, 31, dtype=F64)
        uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1)
        xy = torch.stack([(uv[..., 0] - c.cx) / c.fx, (uv[..., 1] - c.cy) / c.fy], -1)
        xd = distort_points(xy, d)
        return torch.stack([xd[..., 0] * cam.fx + cam.cx, xd[..., 1] * cam.fy + cam.cy], -1)

    src = source_pixels(new)
    tol = 1e-6
    assert float(src[..., 0].min()) >= -tol and float(src[..., 0].max()) <= cam.width + tol
    assert float(src[..., 1].min()) >= -tol and float(src[..., 1].max()) <= cam.height + tol
    wider = Camera.from_intrinsics(new.fx / 1.03, new.fy / 1.03, new.cx, new.cy, 240, 176)
    s = source_pixels(wider)
    outside = (s[..., 0] < 0) | (s[..., 0] > cam.width) | (s[..., 1] < 0) | (s[..., 1] > cam.height)
    assert bool(outside.any())


def test_identity_and_bad_coefficients() -> None:
    cam = Camera.from_intrinsics(50.0, 50.0, 16.0, 16.0, 32, 32)
    assert undistorted_camera(cam, Distortion()) is cam
    with pytest.raises(ValueError, match="k1"):
        Distortion("opencv", k1=float("nan"))
    with pytest.raises(ValueError, match="tangential"):
        Distortion("fisheye", p1=0.1)
    with pytest.raises(ValueError, match="model"):
        Distortion("division")


def test_colmap_distorted_models_give_their_lens(tmp_path) -> None:
    (tmp_path / "cameras.txt").write_text(
        "1 OPENCV 64 48 50 51 32 24 -0.1 0.02 0.001 0.002\n"
        "2 OPENCV_FISHEYE 64 48 50 50 32 24 0.1 0.01 0.001 0.0001\n"
        "3 SIMPLE_RADIAL 64 48 50 32 24 -0.05\n"
    )
    lines = [f"{i} 1 0 0 0 0 0 0 {i} im{i}.png\n\n" for i in (1, 2, 3)]
    (tmp_path / "images.txt").write_text("".join(lines))
    model = read_colmap_model(tmp_path)
    lens = {im.name: im.distortion for im in model.images}
    assert lens["im1.png"] == Distortion("opencv", k1=-0.1, k2=0.02, p1=0.001, p2=0.002)
    assert lens["im2.png"] == Distortion("fisheye", k1=0.1, k2=0.01, k3=0.001, k4=0.0001)
    assert lens["im3.png"] == Distortion("opencv", k1=-0.05)
    assert model.images[0].camera.fy == 51.0
    (tmp_path / "cameras.txt").write_text(
        "1 FULL_OPENCV 64 48 50 51 32 24 -0.1 0.02 0 0 0 0.5 0 0\n"
    )
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 1 im1.png\n\n")
    with pytest.raises(ValueError, match="k4-k6"):  # OpenCV's rational terms are not modelled
        read_colmap_model(tmp_path)


def test_truncated_binary_model_is_a_clear_error(tmp_path) -> None:
    import struct

    (tmp_path / "cameras.bin").write_bytes(struct.pack("<QiiQQ", 1, 1, 1, 64, 48) + b"\0" * 8)
    (tmp_path / "images.bin").write_bytes(struct.pack("<Q", 0))
    with pytest.raises(ValueError, match=r"cameras.bin ends early.*truncated"):
        read_colmap_model(tmp_path)
    with pytest.raises(FileNotFoundError, match="no COLMAP model"):
        read_colmap_model(tmp_path / "nowhere")
