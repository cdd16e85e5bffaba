"""COLMAP text models: parsing against hand-computed poses, errors, exact round trips."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from prosplat import Camera
from prosplat.convert.colmap import (
    ColmapImage,
    qvec_to_rotmat,
    read_colmap_text,
    rotmat_to_qvec,
    write_colmap_text,
)
from prosplat.convert.nerfstudio import Frame, read_transforms, write_transforms

F64 = torch.float64
S = math.sqrt(0.5)

CAMERAS = """# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
# Number of cameras: 2
1 PINHOLE 640 480 500.5 490.25 321.0 239.5
2 SIMPLE_PINHOLE 320 240 250.0 160.0 120.0
"""

# Image 7: 90 degrees about +y (qw = qy = sqrt(1/2)), written with an unnormalised quaternion.
# Image 3: identity rotation. Image 3's POINTS2D line holds observations, image 7's is empty.
IMAGES = f"""# Image list with two lines of data per image:
#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME
#   POINTS2D[] as (X, Y, POINT3D_ID)
# Number of images: 2, mean observations per image: 1
7 {2 * S} 0 {2 * S} 0 0.5 -1.0 4.0 1 zebra.png

3 1 0 0 0 0 0 2 2 apple.jpg
100.5 80.25 -1 12.0 14.0 5
"""


def _model(folder: Path, cameras: str = CAMERAS, images: str = IMAGES) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text(cameras)
    (folder / "images.txt").write_text(images)
    return folder


def test_read_known_model(tmp_path: Path) -> None:
    images = read_colmap_text(_model(tmp_path))
    assert [im.name for im in images] == ["apple.jpg", "zebra.png"]  # sorted by name
    assert [im.image_id for im in images] == [3, 7]
    apple, zebra = images

    # SIMPLE_PINHOLE: one focal for both axes; principal point copied as is (COLMAP, like
    # us, centres the top-left pixel at (0.5, 0.5)).
    torch.testing.assert_close(
        apple.camera.K, torch.tensor([[250.0, 0, 160.0], [0, 250.0, 120.0], [0, 0, 1]], dtype=F64)
    )
    assert (apple.camera.width, apple.camera.height) == (320, 240)
    torch.testing.assert_close(apple.camera.center, torch.tensor([0.0, 0.0, -2.0], dtype=F64))

    assert (zebra.camera.fx, zebra.camera.fy, zebra.camera.cx, zebra.camera.cy) == (
        500.5, 490.25, 321.0, 239.5
    )  # fmt: skip
    # R_y(90°) maps world +x to camera −z and world +z to camera +x.
    R = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]], dtype=F64)
    torch.testing.assert_close(zebra.camera.R, R, rtol=0, atol=1e-15)
    torch.testing.assert_close(zebra.camera.t, torch.tensor([0.5, -1.0, 4.0], dtype=F64))
    # A world point at camera-space (0, 0, 4) = R^T (p_c - t) projects to the principal point.
    p = R.T @ (torch.tensor([0.0, 0.0, 4.0], dtype=F64) - zebra.camera.t)
    uv, depth = zebra.camera.project(p[None])
    torch.testing.assert_close(uv[0], torch.tensor([321.0, 239.5], dtype=F64))
    assert depth.item() == pytest.approx(4.0)


def test_quaternion_conversions() -> None:
    g = torch.Generator().manual_seed(3)
    for _ in range(50):
        q = torch.randn(4, generator=g, dtype=F64)
        q = q / q.norm()
        q = -q if q[0] < 0 else q
        R = qvec_to_rotmat(q)
        torch.testing.assert_close(R @ R.T, torch.eye(3, dtype=F64))
        assert torch.det(R).item() == pytest.approx(1.0)
        torch.testing.assert_close(rotmat_to_qvec(R), q, rtol=0, atol=1e-12)
    # 180-degree turns (trace -1) take the non-trace branches.
    for axis in range(3):
        q = torch.zeros(4, dtype=F64)
        q[axis + 1] = 1.0
        torch.testing.assert_close(rotmat_to_qvec(qvec_to_rotmat(q)), q, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="non-zero"):
        qvec_to_rotmat([0.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("model", ["SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"])
def test_distorted_models_are_refused(tmp_path: Path, model: str) -> None:
    cameras = f"1 {model} 640 480 500 320 240 0.01 0.02 0.0 0.0\n"
    images = "1 1 0 0 0 0 0 0 1 a.png\n\n"
    with pytest.raises(ValueError, match=rf"{model}.*image_undistorter"):
        read_colmap_text(_model(tmp_path, cameras, images))


def test_missing_files_are_explained(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="cameras.txt"):
        read_colmap_text(tmp_path)
    (tmp_path / "cameras.bin").write_bytes(b"")
    with pytest.raises(FileNotFoundError, match="model_converter"):
        read_colmap_text(tmp_path)
    _model(tmp_path / "scene" / "sparse" / "0")
    with pytest.raises(FileNotFoundError, match=r"sparse/0"):
        read_colmap_text(tmp_path / "scene")


@pytest.mark.parametrize(
    ("images", "match"),
    [
        ("1 nan 0 0 0 0 0 0 1 a.png\n\n", "NaN"),
        ("1 1 0 0 0 0 0 inf 1 a.png\n\n", "NaN"),
        ("1 0 0 0 0 0 0 0 1 a.png\n\n", "non-zero"),
        ("1 1 0 0 0 0 0 0 9 a.png\n\n", "CAMERA_ID 9"),
        ("1 1 0 0 0 0 0 0 1\n\n", "IMAGE_ID QW"),
        ("1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0 0 0 1 a.png\n\n", "duplicate"),
    ],
)
def test_bad_images_txt(tmp_path: Path, images: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        read_colmap_text(_model(tmp_path, images=images))


def test_bad_cameras_txt(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="needs 4 parameters"):
        read_colmap_text(_model(tmp_path, cameras="1 PINHOLE 64 48 10 10 32\n"))
    with pytest.raises(ValueError, match="NaN"):
        read_colmap_text(_model(tmp_path, cameras="1 PINHOLE 64 48 nan 10 32 24\n"))


def _images() -> list[ColmapImage]:
    a = Camera.look_at([2.0, -3.0, 1.5], [0.1, 0.2, 0.3], [0, 0, 1], 512.3, 640, 480)
    b = Camera.look_at([-1.0, 2.0, 0.5], [0.0, 0.0, 0.0], [0, 0, 1], 512.3, 640, 480)
    b = Camera(a.K, b.world_to_cam, 640, 480)  # shares a's intrinsics
    c = Camera.from_intrinsics(300.5, 310.25, 100.125, 80.0625, 200, 160, b.world_to_cam)
    d = Camera.look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], [0, 1, 0], 100.0, 64, 48)  # 180° turn
    return [ColmapImage("b.png", b, 5), ColmapImage("a.png", a, 2), ColmapImage("c.png", c, 9),
            ColmapImage("d.png", d, 11)]  # fmt: skip


def test_write_read_round_trip(tmp_path: Path) -> None:
    images = _images()
    write_colmap_text(tmp_path / "sparse", images)
    cam_lines = [
        ln for ln in (tmp_path / "sparse" / "cameras.txt").read_text().splitlines()
        if ln and not ln.startswith("#")
    ]  # fmt: skip
    assert len(cam_lines) == 3  # a and b share one camera
    assert (tmp_path / "sparse" / "points3D.txt").is_file()
    back = read_colmap_text(tmp_path / "sparse")
    assert [im.name for im in back] == ["a.png", "b.png", "c.png", "d.png"]
    by_name = {im.name: im for im in images}
    for im in back:
        ref = by_name[im.name]
        assert im.image_id == ref.image_id
        torch.testing.assert_close(im.camera.K, ref.camera.K, rtol=0, atol=1e-12)
        torch.testing.assert_close(
            im.camera.world_to_cam, ref.camera.world_to_cam, rtol=0, atol=1e-12
        )


def test_write_never_overwrites_by_default(tmp_path: Path) -> None:
    write_colmap_text(tmp_path, _images()[:1])
    before = (tmp_path / "images.txt").read_text()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_colmap_text(tmp_path, _images()[1:2])
    assert (tmp_path / "images.txt").read_text() == before
    write_colmap_text(tmp_path, _images()[1:2], overwrite=True)
    assert [im.name for im in read_colmap_text(tmp_path)] == ["a.png"]


def test_write_refuses_bad_names_and_skew(tmp_path: Path) -> None:
    cam = _images()[0].camera
    with pytest.raises(ValueError, match="whitespace"):
        write_colmap_text(tmp_path / "x", [ColmapImage("my photo.png", cam, 1)])
    K = cam.K.clone()
    K[0, 1] = 0.5
    with pytest.raises(ValueError, match="skew"):
        write_colmap_text(
            tmp_path / "y", [ColmapImage("a.png", Camera(K, cam.world_to_cam, 640, 480), 1)]
        )


def test_colmap_and_transforms_agree(tmp_path: Path) -> None:
    # The same cameras through both formats project identically.
    images = read_colmap_text(_model(tmp_path / "model"))
    write_transforms(tmp_path / "ns", [Frame(im.camera, im.name) for im in images])
    frames = read_transforms(tmp_path / "ns").frames
    pts = torch.tensor([[0.3, -0.2, 1.0], [1.0, 0.5, -0.5]], dtype=F64)
    for im, fr in zip(images, frames, strict=True):
        uv_a, d_a = im.camera.project(pts)
        uv_b, d_b = fr.camera.project(pts)
        torch.testing.assert_close(uv_b, uv_a, rtol=0, atol=1e-9)
        torch.testing.assert_close(d_b, d_a, rtol=0, atol=1e-12)
