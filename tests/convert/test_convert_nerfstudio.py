"""transforms.json in nerfstudio, instant-ngp and NeRF-synthetic forms."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from prosplat import Camera
from prosplat.convert.nerfstudio import Frame, read_transforms, write_transforms

F64 = torch.float64

# OpenGL camera-to-world: camera at (0, 0, 5) looking down −z at the origin, +y up.
GL_AT_Z5 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 5.0], [0, 0, 0, 1.0]]
# Camera at (3, 0, 0) looking down world −x. Columns are the GL camera axes in world
# coordinates: right = +y, up = +z, back = +x (so it looks along −x).
GL_AT_X3 = [[0.0, 0.0, 1.0, 3.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0, 0, 0, 1.0]]


def _write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def test_nerfstudio_form_projects_known_points(tmp_path: Path) -> None:
    data = {
        "camera_model": "OPENCV",
        "fl_x": 400.0, "fl_y": 380.0, "cx": 330.0, "cy": 235.0, "w": 640, "h": 480,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "aabb_scale": 16,
        "frames": [
            {"file_path": "images/a.png", "transform_matrix": GL_AT_Z5, "sharpness": 12.5},
            {"file_path": "images/b.png", "transform_matrix": GL_AT_X3, "fl_x": 500.0},
        ],
    }  # fmt: skip
    tf = read_transforms(_write(tmp_path / "transforms.json", data))
    assert tf.meta == {"aabb_scale": 16}
    a, b = tf.frames
    assert a.file_path == "images/a.png" and a.extra == {"sharpness": 12.5}
    assert (a.camera.fx, a.camera.fy, a.camera.cx, a.camera.cy) == (400.0, 380.0, 330.0, 235.0)
    assert (a.camera.width, a.camera.height) == (640, 480)
    # Origin straight ahead at depth 5; world +x to the right, world +y up (smaller v).
    pts = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=F64)
    uv, depth = a.camera.project(pts)
    expected = [[330.0, 235.0], [330.0 + 400.0 / 5, 235.0], [330.0, 235.0 - 380.0 / 5]]
    torch.testing.assert_close(uv, torch.tensor(expected, dtype=F64))
    torch.testing.assert_close(depth, torch.full((3,), 5.0, dtype=F64))
    # Per-frame fl_x overrides the global one; the rest falls back to the global values.
    assert (b.camera.fx, b.camera.fy) == (500.0, 380.0)
    torch.testing.assert_close(b.camera.center, torch.tensor([3.0, 0.0, 0.0], dtype=F64))
    torch.testing.assert_close(b.camera.forward, torch.tensor([-1.0, 0.0, 0.0], dtype=F64))
    uv, _ = b.camera.project(torch.tensor([[0.0, 0.0, 1.0]], dtype=F64))  # world +z is up
    assert uv[0, 1].item() == pytest.approx(235.0 - 380.0 / 3)


def test_nerf_synthetic_form_with_image_size(tmp_path: Path) -> None:
    data = {
        "camera_angle_x": 0.6911112070083618,
        "frames": [
            {"file_path": "./train/r_0", "rotation": 0.012566, "transform_matrix": GL_AT_Z5}
        ],
    }
    tf = read_transforms(_write(tmp_path / "transforms_train.json", data), image_size=(800, 800))
    cam = tf.frames[0].camera
    # The well-known focal of the Blender NeRF-synthetic scenes at 800 px.
    assert cam.fx == pytest.approx(1111.1110311937682, rel=1e-12)
    assert cam.fy == cam.fx and (cam.cx, cam.cy) == (400.0, 400.0)
    assert tf.frames[0].extra == {"rotation": 0.012566}


def test_camera_angle_y_and_size_from_image_file(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    (tmp_path / "train").mkdir()
    img = oiio.ImageBuf(oiio.ImageSpec(40, 30, 3, oiio.UINT8))
    assert img.write(str(tmp_path / "train" / "r_0.png"))
    data = {
        "camera_angle_x": 1.0,
        "camera_angle_y": 0.8,
        "frames": [{"file_path": "./train/r_0", "transform_matrix": GL_AT_Z5}],
    }
    _write(tmp_path / "transforms.json", data)
    tf = read_transforms(tmp_path)  # a folder works too; the extension is found
    cam = tf.frames[0].camera
    assert (cam.width, cam.height) == (40, 30)
    assert cam.fx == pytest.approx(20.0 / math.tan(0.5))
    assert cam.fy == pytest.approx(15.0 / math.tan(0.4))


def test_missing_size_and_image_is_explained(tmp_path: Path) -> None:
    data = {
        "camera_angle_x": 0.7,
        "frames": [{"file_path": "nowhere/x", "transform_matrix": GL_AT_Z5}],
    }
    with pytest.raises(FileNotFoundError, match=r"image_size=\(w, h\)"):
        read_transforms(_write(tmp_path / "t.json", data))


def test_distortion_is_refused(tmp_path: Path) -> None:
    data = {"fl_x": 100.0, "w": 64, "h": 48, "k1": -0.05,
            "frames": [{"file_path": "a.png", "transform_matrix": GL_AT_Z5}]}  # fmt: skip
    with pytest.raises(ValueError, match="undistort"):
        read_transforms(_write(tmp_path / "t.json", data))
    data = {"fl_x": 100.0, "w": 64, "h": 48, "camera_model": "OPENCV_FISHEYE",
            "frames": [{"file_path": "a.png", "transform_matrix": GL_AT_Z5}]}  # fmt: skip
    with pytest.raises(ValueError, match="OPENCV_FISHEYE"):
        read_transforms(_write(tmp_path / "t.json", data))


def test_nan_pose_names_the_frame(tmp_path: Path) -> None:
    bad = [row[:] for row in GL_AT_Z5]
    bad[0][3] = float("nan")
    data = {"fl_x": 100.0, "w": 64, "h": 48, "frames": [
        {"file_path": "ok.png", "transform_matrix": GL_AT_Z5},
        {"file_path": "bad.png", "transform_matrix": bad},
    ]}  # fmt: skip
    with pytest.raises(ValueError, match=r"frame 1 \(bad.png\).*NaN"):
        read_transforms(_write(tmp_path / "t.json", data))


def test_missing_keys_and_files(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="transforms file not found"):
        read_transforms(tmp_path / "nope.json")
    with pytest.raises(FileNotFoundError, match="transforms.json"):
        read_transforms(tmp_path)  # folder without transforms.json
    data = {"w": 64, "h": 48, "frames": [{"file_path": "a.png", "transform_matrix": GL_AT_Z5}]}
    with pytest.raises(ValueError, match="fl_x"):
        read_transforms(_write(tmp_path / "t.json", data))
    data = {"fl_x": 1.0, "w": 64, "h": 48, "frames": [{"file_path": "a.png"}]}
    with pytest.raises(ValueError, match="frame 0 has no 'transform_matrix'"):
        read_transforms(_write(tmp_path / "t.json", data))
    scaled = [[2.0, 0, 0, 0], [0, 2.0, 0, 0], [0, 0, 2.0, 5.0], [0, 0, 0, 1.0]]
    data = {"fl_x": 1.0, "w": 64, "h": 48,
            "frames": [{"file_path": "a.png", "transform_matrix": scaled}]}  # fmt: skip
    with pytest.raises(ValueError, match="orthonormal"):
        read_transforms(_write(tmp_path / "t.json", data))
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        read_transforms(tmp_path / "broken.json")


def _cameras() -> list[Camera]:
    a = Camera.look_at([2.0, -3.0, 1.5], [0.1, 0.2, 0.3], [0, 0, 1], 512.3, 640, 480)
    b = Camera.look_at([-1.0, 2.0, 0.5], [0.0, 0.0, 0.0], [0, 0, 1], 498.7, 640, 480)
    c = Camera.from_intrinsics(300.5, 310.25, 100.125, 80.0625, 200, 160, b.world_to_cam)
    return [a, b, c]


@pytest.mark.parametrize("shared", [True, False])
def test_write_read_round_trip(tmp_path: Path, shared: bool) -> None:
    cams = _cameras()
    if shared:  # same intrinsics everywhere -> written once at the top level
        cams = [Camera(cams[0].K, c.world_to_cam, cams[0].width, cams[0].height) for c in cams]
    frames = [Frame(c, f"images/{i:03d}.png", {"time": i * 0.5}) for i, c in enumerate(cams)]
    path = write_transforms(tmp_path, frames, meta={"aabb_scale": 4})
    assert path == tmp_path / "transforms.json"
    raw = json.loads(path.read_text())
    assert ("fl_x" in raw) == shared and ("fl_x" in raw["frames"][0]) != shared
    # transform_matrix is OpenGL camera-to-world: its z column points backwards.
    c2w = np.array(raw["frames"][0]["transform_matrix"])
    np.testing.assert_allclose(c2w[:3, 2], -cams[0].forward.numpy(), atol=1e-12)
    np.testing.assert_allclose(c2w[:3, 3], cams[0].center.numpy(), atol=1e-12)

    back = read_transforms(path)
    assert back.meta == {"aabb_scale": 4}
    for f, g in zip(frames, back.frames, strict=True):
        assert g.file_path == f.file_path and g.extra == f.extra
        torch.testing.assert_close(g.camera.K, f.camera.K, rtol=0, atol=1e-12)
        torch.testing.assert_close(g.camera.world_to_cam, f.camera.world_to_cam, rtol=0, atol=1e-12)
        assert (g.camera.width, g.camera.height) == (f.camera.width, f.camera.height)


def test_write_never_overwrites_by_default(tmp_path: Path) -> None:
    frames = [Frame(_cameras()[0], "a.png")]
    write_transforms(tmp_path / "t.json", frames)
    before = (tmp_path / "t.json").read_text()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_transforms(tmp_path / "t.json", [Frame(_cameras()[1], "b.png")])
    assert (tmp_path / "t.json").read_text() == before
    write_transforms(tmp_path / "t.json", [Frame(_cameras()[1], "b.png")], overwrite=True)
    assert read_transforms(tmp_path / "t.json").frames[0].file_path == "b.png"


def test_write_refuses_unrepresentable_input(tmp_path: Path) -> None:
    K = torch.tensor([[100.0, 1.0, 32.0], [0.0, 100.0, 24.0], [0.0, 0.0, 1.0]], dtype=F64)
    skewed = Camera(K, torch.eye(4, dtype=F64), 64, 48)
    with pytest.raises(ValueError, match="skew"):
        write_transforms(tmp_path / "a.json", [Frame(skewed, "a.png")])
    with pytest.raises(ValueError, match="fl_x"):
        write_transforms(tmp_path / "b.json", [Frame(_cameras()[0], "a.png")], meta={"fl_x": 3})
    assert not (tmp_path / "a.json").exists() and not (tmp_path / "b.json").exists()
