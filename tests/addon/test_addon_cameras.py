"""Import posed images: every supported file form gives cameras that project points exactly
as the file says, checked with Blender's own ``world_to_camera_view``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, run_op  # noqa: E402
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

from prosplat import Camera  # noqa: E402
from prosplat.convert import read_colmap_text, read_transforms, write_transforms  # noqa: E402
from prosplat.convert.colmap import ColmapImage, write_colmap_text  # noqa: E402
from prosplat.convert.nerfstudio import Frame  # noqa: E402
from prosplat.core.image_io import write_image  # noqa: E402

W, H = 64, 48
EYES = [(3.0, -1.0, 1.0), (-2.0, -2.5, 0.5), (0.5, 3.0, 2.0), (-3.0, 1.0, -1.0)]


def rig(fx=60.0, fy=66.0, cx=30.5, cy=25.0) -> list[Camera]:
    """Off-centre principal point and non-square pixels: shift and pixel aspect both matter."""
    out = []
    for eye in EYES:
        base = Camera.look_at(eye, (0, 0, 0), (0, 0, 1), fx, W, H)
        out.append(Camera.from_intrinsics(fx, fy, cx, cy, W, H, base.world_to_cam))
    return out


def _images(folder: Path, names: list[str]) -> None:
    gen = torch.Generator().manual_seed(0)
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        write_image(folder / name, torch.rand(3, H, W, generator=gen))


def nerfstudio(folder: Path) -> Path:
    cams = rig()
    frames = [Frame(c, f"images/{i:03d}.png") for i, c in enumerate(cams)]
    _images(folder, [f.file_path for f in frames])
    return write_transforms(folder / "transforms.json", frames, {"aabb_scale": 16})


def _gl_matrices(cams) -> list:
    from prosplat.convert import OPENGL_TO_OPENCV

    return [(c.cam_to_world @ OPENGL_TO_OPENCV).tolist() for c in cams]


def blendernerf_ngp(folder: Path) -> Path:
    """BlenderNeRF's NGP form: angles and pixels both, zero distortion, aabb_scale."""
    cams = rig(fx=60.0, fy=60.0, cx=32.0, cy=24.0)
    data = {"camera_angle_x": 2 * math.atan(W / 120), "camera_angle_y": 2 * math.atan(H / 120),
            "fl_x": 60.0, "fl_y": 60.0, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
            "cx": 32.0, "cy": 24.0, "w": W, "h": H, "aabb_scale": 4,
            "frames": [{"file_path": f"train/{i:04d}.png", "transform_matrix": m}
                       for i, m in enumerate(_gl_matrices(cams))]}  # fmt: skip
    _images(folder, [f["file_path"] for f in data["frames"]])
    (folder / "transforms_train.json").write_text(json.dumps(data))
    return folder / "transforms_train.json"


def blendernerf_nerf(folder: Path) -> Path:
    """NeRF-synthetic / BlenderNeRF NeRF form: camera_angle_x only, paths without extension."""
    cams = rig(fx=60.0, fy=60.0, cx=32.0, cy=24.0)
    data = {"camera_angle_x": 2 * math.atan(W / 120),
            "frames": [{"file_path": f"./train/r_{i}", "transform_matrix": m}
                       for i, m in enumerate(_gl_matrices(cams))]}  # fmt: skip
    _images(folder, [f"train/r_{i}.png" for i in range(len(cams))])
    (folder / "transforms_train.json").write_text(json.dumps(data))
    return folder / "transforms_train.json"


def colmap(folder: Path) -> Path:
    cams = rig()
    write_colmap_text(folder / "sparse" / "0",
                      [ColmapImage(f"{i:03d}.png", c, i + 1) for i, c in enumerate(cams)])  # fmt: skip
    _images(folder / "images", [f"{i:03d}.png" for i in range(len(cams))])
    return folder / "sparse" / "0" / "cameras.txt"


def expected(path: Path) -> dict[str, Camera]:
    if path.suffix == ".txt":
        return {Path(im.name).stem: im.camera for im in read_colmap_text(path.parent)}
    return {Path(f.file_path).stem: f.camera for f in read_transforms(path).frames}


def projection_error(scene, obj, camera: Camera) -> float:
    """Max pixel distance between Blender's projection and the file's, over 200 points."""
    size, aspect = obj["prosplat_size"], obj["prosplat_pixel_aspect"]
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = int(size[0]), int(size[1]), 100
    r.pixel_aspect_x, r.pixel_aspect_y = float(aspect[0]), float(aspect[1])
    gen = torch.Generator().manual_seed(1)
    uv = torch.rand(200, 2, generator=gen, dtype=torch.float64) * torch.tensor([W, H]) * 1.4 - 10
    depth = torch.rand(200, generator=gen, dtype=torch.float64) * 8 + 0.5
    pts = camera.unproject(uv, depth)
    want, _ = camera.project(pts)
    got = []
    for p in pts.tolist():
        x, y, _ = world_to_camera_view(scene, obj, Vector(p))
        got.append((x * size[0], (1 - y) * size[1]))
    return float((torch.tensor(got, dtype=torch.float64) - want).norm(dim=1).max())


@pytest.mark.parametrize("form", [nerfstudio, blendernerf_ngp, blendernerf_nerf, colmap])
def test_import_projects_like_the_file(blank, tmp_path: Path, form) -> None:
    path = form(tmp_path)
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(path))
    assert res == {"FINISHED"}, err
    coll = bpy.context.scene.prosplat.inputs
    want = expected(path)
    assert sorted(o.name for o in coll.objects) == sorted(want)
    worst = 0.0
    for obj in coll.objects:
        assert obj.data.show_background_images and obj.data.background_images[0].image
        assert Path(obj["prosplat_image"]).is_file()
        worst = max(worst, projection_error(bpy.context.scene, obj, want[obj.name]))
    print(f"\n{form.__name__}: max projection error {worst:.2e} px")
    assert worst < 1e-3


def test_import_sets_resolution_and_depth_range(blank, tmp_path: Path) -> None:
    path = nerfstudio(tmp_path)
    data = json.loads(path.read_text())
    data.update(near=0.7, far=42.0)
    path.write_text(json.dumps(data))
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(path))
    assert res == {"FINISHED"}, err
    scene = bpy.context.scene
    coll = scene.prosplat.inputs
    assert (scene.render.resolution_x, scene.render.resolution_y) == (W, H)
    assert (coll["prosplat_near"], coll["prosplat_far"]) == (0.7, 42.0)
    assert scene.render.pixel_aspect_y / scene.render.pixel_aspect_x == pytest.approx(60 / 66)


@pytest.mark.parametrize(
    ("breakage", "message"),
    [
        ("missing_image", "1 of 4 images were not found (002)"),
        ("malformed_json", "is not valid JSON"),
        ("no_frames", "no 'frames' list"),
        ("nan_pose", "NaN or Inf"),
    ],
)
def test_bad_posed_images_create_nothing(blank, tmp_path: Path, breakage, message) -> None:
    path = nerfstudio(tmp_path)
    if breakage == "missing_image":
        (tmp_path / "images" / "002.png").unlink()
    elif breakage == "malformed_json":
        path.write_text(path.read_text()[:-40])
    elif breakage == "no_frames":
        path.write_text('{"fl_x": 10}')
    else:
        data = json.loads(path.read_text())
        data["frames"][1]["transform_matrix"][0][0] = float("nan")
        path.write_text(json.dumps(data).replace("NaN", "NaN"))
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(path))
    assert res == {"CANCELLED"} and message in err, err
    assert "Traceback" not in err and data_counts() == before
    assert np.isfinite(bpy.context.scene.render.resolution_x)


def test_render_targets_active_selected_and_frame_range(blank) -> None:
    from addon.blender import steps

    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 80, 60
    scene.render.resolution_percentage = 50
    cams = []
    for name in ("b", "a"):
        obj = bpy.data.objects.new(name, bpy.data.cameras.new(name))
        scene.collection.objects.link(obj)
        cams.append(obj)
    mesh = bpy.data.objects.new("m", bpy.data.meshes.new("m"))
    with pytest.raises(ValueError, match="no active camera"):
        steps.target_views(scene, "ACTIVE")
    scene.camera = cams[0]
    (view,) = steps.target_views(scene, "ACTIVE")
    assert view["name"] == "b" and (view["camera"]["width"], view["camera"]["height"]) == (40, 30)
    names = [v["name"] for v in steps.target_views(scene, "SELECTED", [*cams, mesh])]
    assert names == ["a", "b"]
    with pytest.raises(ValueError, match="no camera is selected"):
        steps.target_views(scene, "SELECTED", [mesh])
    cams[0].location = (0, 0, 0)
    cams[0].keyframe_insert("location", frame=1)
    cams[0].location = (2, 0, 0)
    cams[0].keyframe_insert("location", frame=3)
    scene.frame_start, scene.frame_end, scene.frame_current = 1, 3, 2
    views = steps.target_views(scene, "FRAMES")
    assert [v["name"] for v in views] == ["b_0001", "b_0002", "b_0003"]
    xs = [v["camera"]["matrix_world"][0][3] for v in views]
    assert xs == pytest.approx([0.0, 1.0, 2.0]) and scene.frame_current == 2
