"""Own posed images: depth ranges, image checks, RGBA backgrounds, input picking."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import numpy as np
import pytest
import torch
from posed_data import scene_cameras, scene_points, write_colmap_project, write_transforms_set

from prosplat import Camera, ProSplat
from prosplat.convert.distortion import Distortion
from prosplat.core.image_io import check_images, composite, read_image, read_image_rgba
from prosplat.eval.demo_scene import raycast
from prosplat.geometry.rig import near_far_from_cameras
from prosplat.pipeline.posed_views import (
    load_posed_set,
    load_views,
    near_far_from_points,
    parse_background,
    pick_views,
    resolve_background,
)

LEGO_RADIUS, RIG_RADIUS = 1.5, 4.0


def _lego_camera(az: float, el: float, width: int = 64) -> Camera:
    """A NeRF-synthetic camera: on a sphere of radius 4 looking at the origin, 0.69 rad FOV."""
    a, e = math.radians(az), math.radians(el)
    eye = [RIG_RADIUS * math.cos(e) * math.cos(a), RIG_RADIUS * math.cos(e) * math.sin(a),
           RIG_RADIUS * math.sin(e)]  # fmt: skip
    fx = 0.5 * width / math.tan(0.5 * 0.6911112070083618)
    return Camera.look_at(eye, (0, 0, 0), (0, 0, 1), fx, width, width)


def test_lego_rig_near_far_brackets_the_object() -> None:
    """2 views of a lego-like rig (radius 4, object radius 1.5): near in front of the object's
    surface (not inside it), far past its back but not absurdly far (< 3x the rig radius)."""
    rng = random.Random(0)
    pairs = [(0, 30, 90, 30), (0, 10, 180, 60), (0, 45, 20, 40), (30, 80, 250, 5)]
    pairs += [tuple(rng.uniform(0, 360) if k % 2 == 0 else rng.uniform(5, 85) for k in range(4))
              for _ in range(20)]  # fmt: skip
    for a1, e1, a2, e2 in pairs:
        near, far = near_far_from_cameras([_lego_camera(a1, e1), _lego_camera(a2, e2)])
        where = f"views at ({a1:.0f}, {e1:.0f}) and ({a2:.0f}, {e2:.0f})"
        assert 0 < near < RIG_RADIUS - LEGO_RADIUS, (where, near)
        assert RIG_RADIUS + LEGO_RADIUS < far < 3 * RIG_RADIUS, (where, far)


def test_near_far_from_points_brackets_the_true_depths() -> None:
    cams = scene_cameras(4, 32, 24)
    pts, tracks = scene_points(cams, stride=2)
    observed = [torch.tensor([k for k, t in enumerate(tracks) if i in t]) for i in range(4)]
    near, far = near_far_from_points(pts, cams, observed)
    depths = torch.cat([raycast(c)[0].flatten() for c in cams])
    assert 0 < near <= float(depths.min())
    assert float(depths.max()) <= far < 2 * float(depths.max())
    # without tracks: the points each camera sees in its image
    untracked = near_far_from_points(pts, cams)
    assert untracked == pytest.approx((near, far), rel=0.1)
    # outliers far away (behind the wall, in view) barely move far (percentiles)
    outliers = torch.tensor([[0.0, 0.2, 1e4]] * 5, dtype=pts.dtype)
    assert near_far_from_points(torch.cat([pts, outliers]), cams)[1] < 1.05 * untracked[1]
    # too few points give None (the caller falls back to the cameras)
    assert near_far_from_points(pts[:3], cams, [torch.arange(3)] * 4) is None


def test_library_refuses_uint8_and_0_255_images() -> None:
    torch.manual_seed(0)
    model = ProSplat()
    cams = scene_cameras(2, 32, 32)
    u8 = torch.randint(0, 256, (2, 3, 32, 32), dtype=torch.uint8)
    with pytest.raises(ValueError, match=r"float tensor in \[0, 1\], got torch.uint8.*/ 255"):
        model.reconstruct(u8, cams, 1.0, 10.0)
    with pytest.raises(ValueError, match=r"values in \[0, 255\].*divide by 255"):
        model.reconstruct(u8.float(), cams, 1.0, 10.0)
    with pytest.raises(ValueError, match="clamp"):
        model.reconstruct(torch.full((2, 3, 32, 32), 1.2), cams, 1.0, 10.0)
    with pytest.raises(ValueError, match="NaN"):
        check_images(torch.full((2, 3, 4, 4), float("nan")))
    g = model.reconstruct(torch.rand(2, 3, 32, 32), cams, 1.0, 10.0, budget="all").gaussians
    with pytest.raises(ValueError, match="uint8"):
        model.render(g, cams[0], u8, cams, enhance=False)


def _write(path: Path, arr: np.ndarray, fmt) -> None:
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(arr.shape[1], arr.shape[0], arr.shape[2], fmt))
    out.write_image(np.ascontiguousarray(arr))
    out.close()


def test_8_and_16_bit_files_load_in_0_1(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    a16 = np.array([[[0, 32768, 65535]]], dtype=np.uint16)
    _write(tmp_path / "a.png", a16, oiio.UINT16)
    img = read_image(tmp_path / "a.png")
    assert img.dtype == torch.float32
    torch.testing.assert_close(img[:, 0, 0], torch.tensor([0, 32768 / 65535, 1.0]))
    a8 = np.array([[[0, 128, 255]]], dtype=np.uint8)
    _write(tmp_path / "b.png", a8, oiio.UINT8)
    torch.testing.assert_close(
        read_image(tmp_path / "b.png")[:, 0, 0], torch.tensor([0, 128 / 255, 1])
    )
    check_images(read_image(tmp_path / "a.png"))  # what files give passes the check


def test_rgba_composited_over_the_chosen_background(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    arr = np.zeros((1, 3, 4), dtype=np.uint8)
    arr[0, 0] = [255, 0, 0, 255]  # opaque red
    arr[0, 1] = [255, 0, 0, 0]  # transparent (colour to be ignored)
    arr[0, 2] = [255, 0, 0, 128]  # half red
    _write(tmp_path / "rgba.png", arr, oiio.UINT8)
    rgb, alpha = read_image_rgba(tmp_path / "rgba.png")
    a = 128 / 255
    white = composite(rgb, alpha, parse_background("white"))
    torch.testing.assert_close(white[:, 0, 0], torch.tensor([1.0, 0.0, 0.0]))
    torch.testing.assert_close(white[:, 0, 1], torch.tensor([1.0, 1.0, 1.0]))
    torch.testing.assert_close(white[:, 0, 2], torch.tensor([1.0, 1 - a, 1 - a]))
    grey = composite(rgb, alpha, parse_background("0,128,255"))
    torch.testing.assert_close(grey[:, 0, 1], torch.tensor([0.0, 128 / 255, 1.0]))
    assert read_image(tmp_path / "rgba.png")[:, 0, 1].tolist() == [0, 0, 0]  # old default: black
    with pytest.raises(ValueError, match="white, black or R,G,B"):
        parse_background("pink")


def test_nerf_synthetic_rgba_defaults_to_white(tmp_path: Path) -> None:
    cams = scene_cameras(3, 32, 32)
    alpha = torch.ones(32, 32)
    alpha[:, :8] = 0  # a transparent band on the left
    path = write_transforms_set(tmp_path / "lego", cams, rgba_alpha=alpha, angle_x=True)
    posed = load_posed_set(path)
    assert posed.nerf_synthetic
    bg, why = resolve_background(posed, None)
    assert bg.tolist() == [1, 1, 1] and "NeRF-synthetic" in why
    images, _ = load_views(posed, [0, 1], None, bg)
    assert images[:, :, :, :8].min() == 1.0 and images[:, :, :, 8:].min() < 0.9
    bg, why = resolve_background(posed, "black")
    assert bg.tolist() == [0, 0, 0] and "--background" in why
    images, _ = load_views(posed, [0], None, bg)
    assert images[:, :, :, :8].max() == 0.0
    # an RGBA set that is not NeRF synthetic keeps black by default, and says so
    other = write_transforms_set(tmp_path / "ngp", cams, rgba_alpha=alpha)
    assert resolve_background(load_posed_set(other), None)[0].tolist() == [0, 0, 0]


def test_pick_views_spreads_inputs_and_takes_names(tmp_path: Path) -> None:
    cams = scene_cameras(7, 32, 32)  # on an arc, in order
    posed = load_posed_set(write_colmap_project(tmp_path / "p", cams, points=False))
    assert pick_views(posed, None, 2) == [0, 6]  # the two ends of the arc
    assert pick_views(posed, None, 3) == [0, 3, 6]
    assert pick_views(posed, ["002", "5"], 4) == [2, 5]
    with pytest.raises(ValueError, match="no frame named 'nope'"):
        pick_views(posed, ["nope", "1"])
    with pytest.raises(ValueError, match="2-6"):
        pick_views(posed, None, 7)
    with pytest.raises(ValueError, match="twice"):
        pick_views(posed, ["1", "001"])


def test_undistorted_inputs_match_pinhole_renders(tmp_path: Path) -> None:
    """Images of a distorted instant-ngp set come out as the pinhole images of their new
    cameras (up to resampling; compared at 1/4 resolution, where the scene's hard checker
    edges no longer dominate), with global or per-frame intrinsics."""
    import torch.nn.functional as F
    from posed_data import scene_image

    def err(a: torch.Tensor, b: torch.Tensor) -> float:
        return float((F.avg_pool2d(a[None], 4) - F.avg_pool2d(b[None], 4)).abs().mean())

    cams = scene_cameras(3, 192, 144)
    lenses = [
        (Distortion("opencv", k1=-0.25, k2=0.06, p1=0.002, p2=-0.001), False),
        (Distortion("opencv", k1=0.1, k2=0.06, p1=0.002, p2=-0.001), True),
        (Distortion("fisheye", k1=0.08, k2=-0.01, k3=0.002), False),  # camera_model key
    ]
    for k, (d, per_frame) in enumerate(lenses):
        path = write_transforms_set(tmp_path / f"ngp{k}", cams, d, per_frame=per_frame)
        posed = load_posed_set(path)
        assert posed.views[0].distortion == d
        images, new_cams = load_views(posed, [0, 2], None, torch.zeros(3))
        for i, img, cam in zip([0, 2], images, new_cams, strict=True):
            good = err(img, scene_image(cam))
            file = read_image(posed.views[i].image)  # skipping undistortion, either camera
            assert good < 0.012, good
            assert good < 0.4 * min(err(file, scene_image(cam)), err(file, scene_image(cams[i])))


def test_file_near_far_per_frame_then_top_level(tmp_path: Path) -> None:
    path = write_transforms_set(tmp_path / "s", scene_cameras(3, 32, 32))
    posed = load_posed_set(path)
    assert posed.file_near_far([0, 1]) is None  # the file gives none: estimate instead
    data = json.loads(path.read_text())
    data.update(near=0.5, far=20.0)
    data["frames"][0].update(near=1.0, far=6.0)
    data["frames"][1].update(near=1.5, far=8.0)
    path.write_text(json.dumps(data))
    posed = load_posed_set(path)
    assert posed.file_near_far([0, 1]) == (1.0, 8.0)  # per-frame bounds of the inputs
    assert posed.file_near_far([0, 2]) == (0.5, 20.0)  # frame 2 has none: the top level


def test_instant_ngp_fisheye_flag(tmp_path: Path) -> None:
    from prosplat.convert.nerfstudio import read_transforms

    path = write_transforms_set(tmp_path / "s", scene_cameras(2, 32, 32))
    data = json.loads(path.read_text())
    data.update(is_fisheye=True, k1=0.1, k2=0.01)
    path.write_text(json.dumps(data))
    frames = read_transforms(path, allow_distortion=True).frames
    assert frames[0].distortion == Distortion("fisheye", k1=0.1, k2=0.01)
    with pytest.raises(ValueError, match="fisheye"):
        read_transforms(path)  # the pinhole-only reader still refuses it


def test_load_views_cameras_match_view_camera(tmp_path: Path) -> None:
    """Inputs (undistorted at twice the model size, then resized) and targets (view_camera)
    get the same pinhole camera for the same frame."""
    from prosplat.pipeline.posed_views import view_camera

    cams = scene_cameras(2, 192, 144)
    d = Distortion("opencv", k1=-0.2, k2=0.05)
    posed = load_posed_set(write_transforms_set(tmp_path / "s", cams, d))
    _, loaded = load_views(posed, [0, 1], (32, 32), torch.zeros(3))
    for i, cam in enumerate(loaded):
        torch.testing.assert_close(cam.K, view_camera(posed.views[i], (32, 32)).K)
