"""The pose step's parts without Blender: photos in (EXIF orientation, unreadable files), the
upright frame, the depth range, the transforms.json lens round trip, and the failures an artist
sees (no overlap, too few photos, the CLI's exit 2)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
import torch

from prosplat.cli import main as cli_main
from prosplat.convert.distortion import Distortion
from prosplat.convert.nerfstudio import Frame, read_transforms, write_transforms
from prosplat.core.camera import Camera
from prosplat.poses import PoseCancelled, PoseError, estimate_poses, list_photos, work_folder
from prosplat.poses.frame import (
    TARGET_DISTANCE,
    transform_world_to_cam,
    upright_similarity,
)
from prosplat.poses.photos import working_names, write_working_copy


def _write(path: Path, pixels: np.ndarray, **attributes) -> Path:
    """An 8-bit image file with extra header attributes (e.g. EXIF Orientation)."""
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    for k, v in attributes.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels)
    out.close()
    return path


def _read(path: Path) -> np.ndarray:
    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.UINT8))


def _noise_photo(path: Path, seed: int, size: int = 256) -> Path:
    """Grey noise in 4-px blocks: SIFT finds hundreds of features, no two photos share any."""
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 256, (size // 4, size // 4, 1), dtype=np.uint8)
    img = np.kron(blocks, np.ones((4, 4, 1), np.uint8)).repeat(3, axis=2)
    return _write(path, img)


# ---- photos -------------------------------------------------------------------------------
def test_exif_orientation_is_honoured(tmp_path):
    """Orientation 6 (a phone held upright: stored landscape, shown turned 90° clockwise):
    the copy is portrait, with the pixels where a viewer shows them."""
    h, w = 48, 96
    img = np.zeros((h, w, 3), np.uint8)
    img[:, : w // 2] = (255, 0, 0)  # left half red, right half blue in the stored pixels
    img[:, w // 2 :] = (0, 0, 255)
    src = _write(tmp_path / "phone.jpg", img, Orientation=6)
    photo = write_working_copy(src, tmp_path / "copy" / "phone.jpg", image_size=1600)
    copy = _read(tmp_path / "copy" / "phone.jpg")
    assert (photo.width, photo.height) == (h, w) and copy.shape == (w, h, 3)
    # turned clockwise: the stored left (red) comes on top, the right (blue) at the bottom
    assert copy[5, h // 2, 0] > 200 and copy[5, h // 2, 2] < 60
    assert copy[-5, h // 2, 2] > 200 and copy[-5, h // 2, 0] < 60
    spec = oiio.ImageInput.open(str(tmp_path / "copy" / "phone.jpg")).spec()
    assert spec.get_int_attribute("Orientation", 1) == 1  # never turned twice


def test_copies_are_bounded_8bit_and_exr_is_tone_mapped(tmp_path):
    big = np.tile(np.linspace(0, 255, 300, dtype=np.uint8)[None, :, None], (200, 1, 3))
    photo = write_working_copy(_write(tmp_path / "big.png", big), tmp_path / "c" / "big.png", 150)
    assert (photo.width, photo.height) == (150, 100)
    exr = tmp_path / "lin.exr"
    spec = oiio.ImageSpec(16, 16, 3, oiio.FLOAT)
    out = oiio.ImageOutput.create(str(exr))
    out.open(str(exr), spec)
    out.write_image(np.full((16, 16, 3), 0.2140, np.float32))  # linear 0.214 = sRGB 0.5
    out.close()
    write_working_copy(exr, tmp_path / "c" / "lin.png", 1600)
    assert abs(int(_read(tmp_path / "c" / "lin.png")[8, 8, 0]) - 128) <= 2


def test_unreadable_photo_is_named(tmp_path):
    bad = tmp_path / "broken.jpg"
    bad.write_bytes(b"\xff\xd8 not a jpeg at all" * 10)
    with pytest.raises(ValueError, match="broken.jpg"):
        write_working_copy(bad, tmp_path / "c" / "broken.jpg", 1600)


def test_list_photos_and_names(tmp_path):
    for name in ("b.JPG", "a.png", ".hidden.jpg", "notes.txt", "c d.jpeg", "a.exr"):
        (tmp_path / name).write_bytes(b"x")
    files = list_photos(tmp_path)
    assert [f.name for f in files] == ["a.exr", "a.png", "b.JPG", "c d.jpeg"]
    assert working_names(files) == ["a.png", "a_2.png", "b.jpg", "c_d.jpg"]


# ---- the upright frame ---------------------------------------------------------------------
def _random_rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_upright_frame_puts_up_on_z_and_cameras_at_four_units():
    # a ring of level cameras round a point cloud, then an arbitrary similarity of the world
    cams = [Camera.look_at((3 * math.cos(a), 3 * math.sin(a), 1.0), (0, 0, 0.3), (0, 0, 1), 100,
                           64, 64) for a in np.linspace(0, 2, 9)]  # fmt: skip
    w2c = np.stack([c.world_to_cam.numpy() for c in cams])
    pts = np.random.default_rng(0).normal(scale=0.5, size=(500, 3)) + (0, 0, 0.3)
    Q, s0, t0 = _random_rotation(3), 0.37, np.array([5.0, -2.0, 7.0])
    w2c = transform_world_to_cam(w2c, s0, Q, t0)
    pts = s0 * pts @ Q.T + t0
    centres = -np.einsum("nji,nj->ni", w2c[:, :3, :3], w2c[:, :3, 3])
    s, R, t = upright_similarity(w2c[:, :3, :3], centres, pts)
    up = w2c.copy()
    up = transform_world_to_cam(w2c, s, R, t)
    new_pts = s * pts @ R.T + t
    mean_up = (-up[:, 1, :3]).mean(axis=0)
    assert np.allclose(mean_up / np.linalg.norm(mean_up), [0, 0, 1], atol=1e-9)
    new_centres = -np.einsum("nji,nj->ni", up[:, :3, :3], up[:, :3, 3])
    dist = np.linalg.norm(new_centres - np.median(new_pts, axis=0), axis=1)
    assert np.median(dist) == pytest.approx(TARGET_DISTANCE)
    assert np.allclose(np.median(new_pts, axis=0), 0, atol=1e-9)


def test_transforms_json_keeps_the_lens(tmp_path):
    cam = Camera.look_at((0, -3, 1), (0, 0, 0), (0, 0, 1), 300, 320, 240)
    lens = Distortion("opencv", k1=-0.05, k2=0.01, p1=0.001)
    write_transforms(tmp_path / "transforms.json", [Frame(cam, "a.jpg", {}, lens)])
    back = read_transforms(tmp_path / "transforms.json", allow_distortion=True).frames[0]
    assert back.distortion == lens
    assert torch.allclose(back.camera.world_to_cam, cam.world_to_cam)


# ---- failures -----------------------------------------------------------------------------
def test_photos_without_overlap_fail_with_the_count(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(3):
        _noise_photo(photos / f"p{k}.png", seed=k)
    out = tmp_path / "out"
    with pytest.raises(PoseError, match=r"only 0 of 3 photos could be matched.*overlap"):
        estimate_poses(photos, out)
    assert not out.exists()
    assert (work_folder(out) / "database.db").is_file()  # the features stay for a re-run


def test_cli_exits_2_with_one_line(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    _noise_photo(photos / "only.png", seed=0)
    (photos / "broken.jpg").write_bytes(b"garbage")
    with pytest.raises(SystemExit) as stop:
        cli_main(["poses", str(photos), "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()  # the bars, then the one message line
    message = [line for line in err if line.startswith("prosplat poses:")]
    assert len(message) == 1 and message[0] == err[-1]
    assert "only 1 readable photo of 2" in err[-1] and "broken.jpg" in err[-1]
    assert not (tmp_path / "out").exists()


def test_cancel_at_once_writes_nothing(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(2):
        _noise_photo(photos / f"p{k}.png", seed=k)
    with pytest.raises(PoseCancelled):
        estimate_poses(photos, tmp_path / "out", cancel=lambda: True)
    assert not (tmp_path / "out").exists()


def test_refuses_a_non_empty_out(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="--overwrite"):
        estimate_poses(tmp_path, tmp_path / "out")


def test_arc_rig_is_an_even_sweep():
    """``scenes.render --arc N``'s views: N poses evenly over the first quarter of the loop."""
    from prosplat.data.rigs import arc_rig

    trajectory = [((math.cos(a), math.sin(a), 1.0), (0.0, 0.0, 0.0)) for a in
                  np.linspace(0, 2 * math.pi, 64, endpoint=False)]  # fmt: skip
    rig = arc_rig(trajectory, 16, n_inputs=2)
    views = sorted(rig.inputs + rig.targets)
    assert len(views) == 16 and views[0] == 0 and views[-1] == 16
    assert len(rig.inputs) == 2 and set(rig.target_kinds) == {"interpolation"}
    with pytest.raises(ValueError):
        arc_rig(trajectory, 1)
