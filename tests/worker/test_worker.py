"""The add-on's bpy-free half: point attributes, camera dicts, posed images and the worker.

Everything the add-on shows in Blender passes through these conversions, so they are held to
exactness (PLY bytes, projections) here, where no Blender is needed.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from factories import random_gaussians
from synthetic_scenes import PLANE_Z, textured_plane_views, write_synthetic_scene

from prosplat import Camera, Gaussians, read_ply, render, write_ply
from prosplat.convert.colmap import ColmapImage, qvec_to_rotmat, write_colmap_text
from prosplat.convert.pointcloud import (
    attribute_names,
    from_attributes,
    to_attributes,
    transform_gaussians,
)
from prosplat.convert.posed import camera_from_dict, camera_to_blender_dict, read_posed_images
from prosplat.worker import Cancelled, Progress, paths_for, run_task

F64 = torch.float64


# ---- point attributes ---------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_attributes_ply_round_trip_is_byte_exact(tmp_path: Path, degree: int) -> None:
    write_ply(random_gaussians(2000, degree, degree), tmp_path / "a.ply")
    attrs = to_attributes(read_ply(tmp_path / "a.ply", dtype=F64))
    assert all(a.dtype == np.float32 for a in attrs.values())
    assert set(attrs) == {"position", "color", *attribute_names(degree)}
    write_ply(from_attributes(attrs), tmp_path / "b.ply")
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_attributes_hold_the_files_float32_codes(tmp_path: Path) -> None:
    """The mesh stores exactly the numbers in the file (logit opacity, log scale)."""
    from plyfile import PlyData

    write_ply(random_gaussians(500, 1), tmp_path / "a.ply")
    v = PlyData.read(str(tmp_path / "a.ply"))["vertex"].data
    attrs = to_attributes(read_ply(tmp_path / "a.ply", dtype=F64))
    for name in ("opacity", "scale_0", "scale_2", "rot_3", "f_dc_1", "f_rest_8"):
        np.testing.assert_array_equal(attrs[name], v[name])
    np.testing.assert_array_equal(attrs["position"][:, 1], v["y"])


def test_color_attribute_is_linear_rgb_with_opacity_alpha() -> None:
    rgb = torch.tensor([[0.0, 0.5, 1.0], [0.2, 0.04, 0.9]], dtype=F64)
    g = Gaussians.from_colors(torch.zeros(2, 3, dtype=F64), rgb, torch.ones(2, 3, dtype=F64),
                              torch.tensor([0.25, 1.0], dtype=F64))  # fmt: skip
    color = to_attributes(g)["color"]
    srgb = lambda x: np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)  # noqa: E731
    np.testing.assert_allclose(srgb(color[:, :3]), rgb.numpy(), atol=1e-6)
    np.testing.assert_allclose(color[:, 3], [0.25, 1.0])


def test_from_attributes_names_what_is_missing() -> None:
    attrs = to_attributes(random_gaussians(10, 0))
    del attrs["scale_1"]
    with pytest.raises(ValueError, match="scale_1"):
        from_attributes(attrs)
    attrs = to_attributes(random_gaussians(10, 1))
    del attrs["f_rest_4"]
    with pytest.raises(ValueError, match="f_rest"):
        from_attributes(attrs)


def _similarity(seed: int = 0, scale: float = 1.7) -> torch.Tensor:
    M = torch.eye(4, dtype=F64)
    M[:3, :3] = qvec_to_rotmat([0.9, 0.2, -0.3, 0.1]) * scale
    M[:3, 3] = torch.tensor([1.0, -2.0, 0.5], dtype=F64)
    return M


def test_transform_moves_gaussians_and_their_view_dependent_colour() -> None:
    """Moving the scene and the camera together leaves the render unchanged (SH degree 3)."""
    g = random_gaussians(300, 3, dtype=F64)
    g = Gaussians(g.means * 0.5, g.quats, g.scales.clamp(0.01, 0.2), g.opacities, g.sh * 0.6)
    cam = Camera.look_at((0.3, -0.5, -3.0), (0, 0, 0), (0, -1, 0), 90.0, 48, 40)
    M = _similarity()
    c2w = cam.cam_to_world.clone()
    c2w[:3, :3] = (M[:3, :3] / 1.7) @ c2w[:3, :3]
    c2w[:3, 3] = M[:3, :3] @ c2w[:3, 3] + M[:3, 3]
    moved_cam = Camera(cam.K, torch.linalg.inv(c2w), cam.width, cam.height)
    a = render(g, cam).rgb
    b = render(transform_gaussians(g, M.numpy()), moved_cam).rgb
    assert float(a.abs().max()) > 0.1
    torch.testing.assert_close(a, b, atol=1e-9, rtol=0)


def test_transform_refuses_non_uniform_scale() -> None:
    M = np.diag([1.0, 2.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="non-uniform"):
        transform_gaussians(random_gaussians(5, 0), M)


# ---- cameras and posed images -------------------------------------------------------------
def test_blender_camera_dict_round_trip() -> None:
    cam = Camera.from_intrinsics(70.0, 72.0, 30.5, 22.0, 64, 48)
    cam = Camera(cam.K, Camera.look_at((1, 2, 3), (0, 0, 0), (0, 0, 1), 1, 2, 2).world_to_cam,
                 64, 48)  # fmt: skip
    back = camera_from_dict(json.loads(json.dumps(camera_to_blender_dict(cam))))
    torch.testing.assert_close(back.K, cam.K, atol=1e-9, rtol=0)
    torch.testing.assert_close(back.world_to_cam, cam.world_to_cam, atol=1e-9, rtol=0)
    with pytest.raises(ValueError, match="target 'x'.*lens"):
        camera_from_dict({"matrix_world": np.eye(4).tolist()}, "target 'x'")


def test_read_posed_images_transforms_and_nerf_synthetic(tmp_path: Path) -> None:
    cams = write_synthetic_scene(tmp_path / "s", size=32, n_views=3)
    posed, meta = read_posed_images(tmp_path / "s" / "transforms.json")
    assert [p.name for p in posed] == ["000", "001", "002"] and meta["near"] == 0.5
    assert all(p.image and p.image.is_file() for p in posed)
    torch.testing.assert_close(posed[1].camera.K, cams[1].K.to(F64))
    # NeRF-synthetic form: camera_angle_x, no w/h, file paths without extension
    data = json.loads((tmp_path / "s" / "transforms.json").read_text())
    nerf = {"camera_angle_x": 2 * math.atan(16 / data["fl_x"]),
            "frames": [{"file_path": f"./images/{i:03d}", "transform_matrix": f["transform_matrix"]}
                       for i, f in enumerate(data["frames"])]}  # fmt: skip
    (tmp_path / "s" / "transforms_train.json").write_text(json.dumps(nerf))
    posed2, _ = read_posed_images(tmp_path / "s" / "transforms_train.json")
    assert posed2[2].image == posed[2].image
    torch.testing.assert_close(posed2[2].camera.K, posed[2].camera.K)


def test_read_posed_images_task_lists_a_repeated_frame_once_with_a_warning(tmp_path: Path):
    write_synthetic_scene(tmp_path / "s", size=32, n_views=3)
    data = json.loads((tmp_path / "s" / "transforms.json").read_text())
    data["frames"] = [data["frames"][1], *data["frames"], data["frames"][1]]
    (tmp_path / "s" / "transforms.json").write_text(json.dumps(data))
    res = run_task("read_posed_images", {"path": str(tmp_path / "s" / "transforms.json")})
    images = [Path(f["image"]).name for f in res["frames"]]
    assert images == ["001.png", "000.png", "002.png"]  # each image once, the first frame
    assert len({f["name"] for f in res["frames"]}) == 3
    assert len(res["warnings"]) == 1 and "left out 2 frames" in res["warnings"][0]


def test_read_posed_images_colmap_finds_images_beside_sparse(tmp_path: Path) -> None:
    cams = write_synthetic_scene(tmp_path / "s", size=32, n_views=3)
    images = [ColmapImage(f"{i:03d}.png", c, i + 1) for i, c in enumerate(cams)]
    write_colmap_text(tmp_path / "s" / "sparse" / "0", images)
    posed, meta = read_posed_images(tmp_path / "s")
    assert meta == {} and [p.image.name for p in posed] == ["000.png", "001.png", "002.png"]
    (tmp_path / "s" / "images" / "001.png").unlink()
    posed, _ = read_posed_images(tmp_path / "s" / "sparse" / "0" / "images.txt")
    assert posed[1].image is None and posed[0].image is not None


# ---- tasks ---------------------------------------------------------------------------------
def test_import_and_export_tasks(tmp_path: Path) -> None:
    write_ply(random_gaussians(100, 2), tmp_path / "a.ply")
    res = run_task("import_ply", {"path": str(tmp_path / "a.ply")})
    assert res["count"] == 100 and res["sh_degree"] == 2 and res["warnings"] == []
    out = run_task("export_ply", {"path": str(tmp_path / "b.ply"), "arrays": res["arrays"]})
    assert (tmp_path / "a.ply").read_bytes() == Path(out["path"]).read_bytes()
    with pytest.raises(FileExistsError):
        run_task("export_ply", {"path": str(tmp_path / "b.ply"), "arrays": res["arrays"]})
    (tmp_path / "junk.ply").write_text("ply\nformat ascii 1.0\nelement face 0\nend_header\n")
    with pytest.raises(ValueError, match="vertex"):
        run_task("import_ply", {"path": str(tmp_path / "junk.ply")})


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> tuple[Path, list[Camera]]:
    folder = tmp_path_factory.mktemp("scene") / "s"
    return folder, write_synthetic_scene(folder, size=64, n_views=4)


def _frames(folder: Path, cams, idx) -> list[dict]:
    return [{"name": f"{i:03d}", "image": str(folder / "images" / f"{i:03d}.png"),
             "camera": camera_to_blender_dict(cams[i])} for i in idx]  # fmt: skip


def test_reconstruct_then_render(scene, tmp_path: Path) -> None:
    folder, cams = scene
    params = {"frames": _frames(folder, cams, [0, 2]), "device": "cpu", "budget": 3000,
              "ply": str(tmp_path / "g.ply"), "near": 0.5, "far": 10.0}  # fmt: skip
    res = run_task("reconstruct", params)
    assert res["count"] <= 3000 and res["stats"]["input"] == 2 * 64 * 64
    assert res["trust"] is None and res["trust_warning"] is None  # 2 views: no estimate
    assert len(read_ply(tmp_path / "g.ply")) == res["count"]
    targets = [{"name": "cam 1", "camera": camera_to_blender_dict(cams[1])}]
    rp = {"arrays": res["arrays"], "targets": targets, "inputs": params["frames"],
          "output_dir": str(tmp_path / "out"), "save_depth": True, "device": "cpu"}  # fmt: skip
    first = run_task("render", rp)
    second = run_task("render", rp)  # never overwrites: a numbered name instead
    assert Path(first["views"][0]["image"]).name == "cam_1.png"
    assert 0 < first["views"][0]["seconds"] == first["seconds_per_view"]  # one view
    assert Path(second["views"][0]["image"]).name == "cam_1-2.png"
    assert Path(first["views"][0]["depth"]).is_file()
    rp["output_dir"] = str(folder / "images")
    with pytest.raises(ValueError, match="holds the input images"):
        run_task("render", rp)


def test_reconstruct_estimates_trust_from_three_views(scene) -> None:
    """With 3 or more views the task leaves each out in turn (prosplat.pipeline.trust): the
    scores come back, and the one-line warning exactly when the paste wins."""
    folder, cams = scene
    params = {"frames": _frames(folder, cams, [0, 1, 2]), "device": "cpu", "near": 0.5,
              "far": 10.0, "budget": 2000}  # fmt: skip
    res = run_task("reconstruct", params)
    trust = res["trust"]
    assert trust["views"] == [0, 1, 2] and len(trust["model_psnr"]) == 3
    assert (res["trust_warning"] is not None) == trust["loses_to_paste"]
    assert run_task("reconstruct", {**params, "trust_check": False})["trust"] is None


def test_reconstruct_without_near_far_triangulates_the_inputs(tmp_path: Path) -> None:
    """No near/far from the add-on: the inputs' own points give them (said in the progress and
    the result), close around the textured plane at depth PLANE_Z, and with ``anchors: True``
    the views' depth scaled to them; ``triangulate: False`` falls back to the cameras'
    estimate, several times wider."""
    from prosplat.core.image_io import write_image

    images, cams = textured_plane_views()
    frames = []
    for i, (img, cam) in enumerate(zip(images, cams, strict=True)):
        write_image(tmp_path / f"{i}.png", img)
        frames.append({"name": f"{i}", "image": str(tmp_path / f"{i}.png"),
                       "camera": camera_to_blender_dict(cam)})  # fmt: skip
    params = {"frames": frames, "device": "cpu", "budget": 2000, "trust_check": False}
    seen: list[str] = []
    res = run_task("reconstruct", params, Progress(lambda f, m: seen.append(m)))
    near, far = res["near_far"]
    assert "points triangulated from the 3 inputs" in res["near_far_source"]
    assert any("triangulating the inputs" in m for m in seen)
    assert 0.7 * PLANE_Z < near < PLANE_Z < far < 1.7 * PLANE_Z
    assert res["anchored_views"] == 0  # anchors are opt-in
    assert run_task("reconstruct", {**params, "anchors": True})["anchored_views"] > 0
    plain = run_task("reconstruct", {**params, "triangulate": False})
    assert plain["near_far_source"] == "the input cameras"
    assert plain["near_far"][1] / plain["near_far"][0] > 2 * far / near


def test_render_distills_the_views_into_one_set_of_gaussians(scene, tmp_path: Path) -> None:
    """``distill_steps``: every target enhanced, the Gaussians fitted to the inputs and those
    views (progress per step, Esc-able), then each target rendered from them: closer to its
    enhanced view than the raw render is, and marked distilled."""
    from prosplat.core.image_io import read_image

    folder, cams = scene
    params = {"frames": _frames(folder, cams, [0, 2]), "device": "cpu", "near": 0.5, "far": 10.0}
    res = run_task("reconstruct", params)
    targets = [{"name": f"cam {i}", "camera": camera_to_blender_dict(cams[i])} for i in (1, 3)]
    rp = {"arrays": res["arrays"], "targets": targets, "inputs": params["frames"],
          "device": "cpu", "save_raw": True}  # fmt: skip
    plain = run_task("render", {**rp, "output_dir": str(tmp_path / "plain")})
    seen: list[str] = []
    dis = run_task("render", {**rp, "output_dir": str(tmp_path / "dis"), "distill_steps": 60},
                   Progress(lambda f, m: seen.append(m)))  # fmt: skip
    assert any(m.startswith("distilling: step 60/60") for m in seen)
    assert all(v["distilled"] for v in dis["views"]) and not plain["views"][0]["distilled"]
    for p, d in zip(plain["views"], dis["views"]):
        enh, raw, ours = (read_image(x) for x in (p["image"], p["raw"], d["image"]))
        assert (ours - enh).abs().mean() < 0.8 * (raw - enh).abs().mean()  # measured 0.66
    wide = {"name": "wide", "camera": camera_to_blender_dict(cams[3].resized(128, 64))}
    mixed = run_task("render", {**rp, "targets": [*targets, wide], "distill_steps": 2,
                                "output_dir": str(tmp_path / "mixed")})  # fmt: skip
    assert any("1 target camera(s) of another aspect ratio" in w for w in mixed["warnings"])
    progress = Progress(lambda f, m: progress.cancel.set() if m.startswith("distilling") else None)
    with pytest.raises(Cancelled):
        run_task("render", {**rp, "output_dir": str(tmp_path / "esc"), "distill_steps": 60},
                 progress)  # fmt: skip
    assert not list((tmp_path / "esc").glob("*.png"))


def test_render_without_improver_warns_and_saves_raw(scene, tmp_path: Path, monkeypatch) -> None:
    """No improvement weights anywhere (shipped file absent): raw renders and a warning."""
    import prosplat.improve.io
    from prosplat.worker import tasks
    from prosplat.worker.models import ModelCache

    folder, cams = scene
    monkeypatch.setattr(
        prosplat.improve.io, "DEFAULT_IMPROVE_WEIGHTS", tmp_path / "missing.safetensors"
    )
    monkeypatch.setattr(tasks, "MODELS", ModelCache())
    assert tasks.load_model(None, torch.device("cpu"), None).improver is None
    g = to_attributes(random_gaussians(50, 0))
    targets = [{"name": "v", "camera": camera_to_blender_dict(cams[0])}]
    res = run_task("render", {"arrays": g, "targets": targets, "enhance": True, "device": "cpu",
                              "inputs": _frames(folder, cams, [0, 2]),
                              "output_dir": str(tmp_path)})  # fmt: skip
    assert res["views"][0]["enhanced"] is False and res["views"][0]["reference"] is None
    assert any("enhancement" in w for w in res["warnings"])


def test_render_fill_holes_shows_a_continuation_where_the_render_is_empty(scene, tmp_path):
    """``fill_holes`` (the add-on's Fill Holes, "raw" by default): a raw render's empty pixels
    get the pull-push fill of its own colours instead of black; covered pixels are unchanged.
    "off" leaves them black."""
    from prosplat.core.image_io import read_image
    from prosplat.pipeline.enhance import MAX_SPLAT_RADIUS, oversized_splats
    from prosplat.render.hole_fill import fill_holes

    folder, cams = scene
    g = random_gaussians(30, 0)
    targets = [{"name": "v", "camera": camera_to_blender_dict(cams[0])}]
    base = {"arrays": to_attributes(g), "targets": targets, "enhance": False, "device": "cpu"}
    plain = run_task("render", {**base, "fill_holes": "off", "output_dir": str(tmp_path / "p")})
    filled = run_task("render", {**base, "output_dir": str(tmp_path / "f")})
    also = run_task("render", {**base, "fill_holes": True, "output_dir": str(tmp_path / "t")})
    a, b, c = (read_image(r["views"][0]["image"]) for r in (plain, filled, also))
    assert torch.equal(b, c)  # "raw" (the default) and "all" (True) agree on a raw view
    out = render(g, cams[0])
    hole = out.alpha < 1e-3
    assert hole.float().mean() > 0.005  # the view has holes to fill
    assert (a[:, hole] < 1e-6).all() and (b[:, hole].sum(0) > 0.02).all()
    # the filled view leaves out the splats it would draw oversized (prosplat.pipeline.enhance)
    kept = render(g[~oversized_splats(g, cams[0], MAX_SPLAT_RADIUS)], cams[0])
    want = fill_holes(kept.rgb, kept.alpha).clamp(0, 1)
    assert torch.allclose(b, want, atol=1.5 / 255)  # the same fill, through an 8-bit PNG


def test_fill_holes_raw_leaves_enhanced_views_as_stage_2_made_them(scene, tmp_path, monkeypatch):
    """An enhanced view: "raw" (the default) writes stage 2's image unblended, as "off" does;
    "all" blends it with the fill where the Gaussians leave holes. A value outside the modes
    fails before any work, naming them. (Stage 2 is a gentle stand-in the guard lets through:
    the shipped one may be refused, and a refused view is raw.)"""
    from prosplat.core.image_io import read_image
    from prosplat.geometry.pixel_gaussians import pixel_gaussians
    from prosplat.pipeline import enhance as enhance_module

    monkeypatch.setattr(
        enhance_module, "enhance", lambda improver, raw, *a, **k: (0.9 * raw + 0.08).clamp(0, 1)
    )
    folder, cams = scene
    image = read_image(folder / "images" / "000.png")  # [3,H,W]
    depth = torch.full(image.shape[1:], 2.0)
    depth[:, : image.shape[-1] // 2] = 0  # view 0's right half only: the left is a hole
    g = pixel_gaussians(image, depth, cams[0], footprint=0.7, opacity=1.0)
    targets = [{"name": "v", "camera": camera_to_blender_dict(cams[0])}]
    base = {"arrays": to_attributes(g), "targets": targets, "device": "cpu",
            "inputs": _frames(folder, cams, [1, 2])}  # fmt: skip
    views = {
        m: run_task("render", {**base, "fill_holes": m, "output_dir": str(tmp_path / m)})
        for m in ("off", "raw", "all")
    }
    assert all(v["views"][0]["enhanced"] and v["views"][0]["guard"] is None for v in views.values())
    off, raw, full = (read_image(views[m]["views"][0]["image"]) for m in ("off", "raw", "all"))
    assert torch.equal(off, raw)
    assert (full - off).abs().amax() > 0.05  # the holes blended with the fill
    with pytest.raises(ValueError, match="off, raw, all"):
        run_task("render", {**base, "fill_holes": "some", "output_dir": str(tmp_path / "x")})
    assert not (tmp_path / "x").exists()


def test_cancelled_progress_stops_before_any_output(scene, tmp_path: Path) -> None:
    folder, cams = scene
    progress = Progress()
    progress.cancel.set()
    params = {"frames": _frames(folder, cams, [0, 2]), "ply": str(tmp_path / "g.ply")}
    with pytest.raises(Cancelled):
        run_task("reconstruct", params, progress)
    assert list(tmp_path.iterdir()) == []


def test_reconstruct_refines_from_the_one_pass_gaussians(scene, monkeypatch):
    """Plain and refining reconstructions both ask for the depth sweep's scene-wide factor:
    refinement starts from the one-pass Gaussians, as ProSplat.reconstruct does."""
    from prosplat.pipeline.model import ProSplat

    folder, cams = scene
    params = {"frames": _frames(folder, cams, [0, 2]), "device": "cpu", "near": 0.5, "far": 10.0}
    asked: list[bool] = []
    real = ProSplat.reconstruct

    def spy(self, *args, **kwargs):
        asked.append(kwargs.get("depth_scale", True))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(ProSplat, "reconstruct", spy)
    run_task("reconstruct", params)
    run_task("reconstruct", {**params, "refine_steps": 2})
    run_task("reconstruct", {**params, "refine_seconds": 0.2})
    assert asked == [True, True, True]


def test_reconstruct_refines_with_progress_and_esc_mid_refinement(scene, tmp_path: Path) -> None:
    folder, cams = scene
    params = {"frames": _frames(folder, cams, [0, 2]), "device": "cpu", "near": 0.5, "far": 10.0}
    seen: list[tuple[float, str]] = []
    plain = run_task("reconstruct", params)
    res = run_task(
        "reconstruct", {**params, "refine_steps": 3}, Progress(lambda f, m: seen.append((f, m)))
    )
    refining = [(f, m) for f, m in seen if m.startswith("refining against the inputs: step")]
    assert [m.split(",")[0] for _, m in refining] == [
        f"refining against the inputs: step {k}/3" for k in (1, 2, 3)
    ]
    assert all(0.8 <= f <= 0.9 for f, _ in refining)
    assert res["count"] == plain["count"] and res["seconds"]["refine"] > 0
    assert not np.array_equal(res["arrays"]["position"], plain["arrays"]["position"])
    refused = []
    with pytest.raises(ValueError, match="not both"):  # refused before any work
        run_task(
            "reconstruct", {**params, "refine_steps": 3, "refine_seconds": 1.0},
            Progress(lambda f, m: refused.append(m)),
        )  # fmt: skip
    assert refused == []

    def esc_after_two_steps(fraction: float, message: str) -> None:
        if message.startswith("refining against the inputs: step 2"):
            progress.cancel.set()  # Esc while refining

    progress = Progress(esc_after_two_steps)
    ply = tmp_path / "g.ply"
    with pytest.raises(Cancelled):
        run_task("reconstruct", {**params, "refine_seconds": 30.0, "ply": str(ply)}, progress)
    assert not ply.exists()  # a cancelled step creates nothing


def test_missing_input_image_is_named(scene) -> None:
    folder, cams = scene
    frames = _frames(folder, cams, [0, 2])
    frames[1]["image"] = None
    with pytest.raises(ValueError, match="input view '002' has no image"):
        run_task("reconstruct", {"frames": frames, "device": "cpu"})


def test_input_views_with_one_camera_pose_are_refused(scene, tmp_path: Path) -> None:
    """Frames that share one pose are one view (the choice takes the first of them): 3 frames
    from 2 poses reconstruct from those 2, and frames all from one pose are refused before
    any output."""
    folder, cams = scene
    frames = _frames(folder, cams, [0, 2, 3])
    frames[2]["camera"] = frames[0]["camera"]  # image 003 seen from view 000's camera
    rec = run_task("reconstruct", {"frames": frames, "device": "cpu", "near": 0.5, "far": 10.0})
    assert rec["views"] == ["000", "002"] and "repeat another's camera pose" in rec["view_reason"]
    for f in frames:
        f["camera"] = frames[0]["camera"]
    ply = tmp_path / "g.ply"
    with pytest.raises(ValueError, match="all have the same camera pose"):
        run_task("reconstruct", {"frames": frames, "device": "cpu", "ply": str(ply)})
    assert not ply.exists()


# ---- the external worker process --------------------------------------------------------
def _worker(job: Path) -> tuple[int, dict]:
    res = subprocess.run([sys.executable, "-m", "prosplat.worker", str(job)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    return res.returncode, json.loads(paths_for(job)["status"].read_text())


def test_worker_process_writes_status_and_arrays(tmp_path: Path) -> None:
    write_ply(random_gaussians(64, 1), tmp_path / "a.ply")
    job = tmp_path / "job.json"
    job.write_text(json.dumps({"task": "import_ply", "params": {"path": str(tmp_path / "a.ply")}}))
    code, status = _worker(job)
    assert code == 0 and status["state"] == "done" and status["progress"] == 1.0
    arrays = np.load(status["result"]["arrays_file"])
    assert arrays["position"].shape == (64, 3) and status["result"]["sh_degree"] == 1


@pytest.mark.parametrize(
    ("job", "code", "state", "match"),
    [
        ("{not json", 1, "error", "cannot read job file"),
        ('{"task": "explode", "params": {}}', 1, "error", "unknown worker task"),
        ('{"task": "import_ply", "params": {"path": "/no/such.ply"}}', 1, "error", "not found"),
    ],
)
def test_worker_process_reports_errors(tmp_path: Path, job, code, state, match) -> None:
    (tmp_path / "job.json").write_text(job)
    got_code, status = _worker(tmp_path / "job.json")
    assert (got_code, status["state"]) == (code, state)
    assert match in status["error"] and "traceback" not in status


def test_worker_process_honours_cancel_file(tmp_path: Path) -> None:
    write_ply(random_gaussians(8, 0), tmp_path / "a.ply")
    job = tmp_path / "job.json"
    params = {"path": str(tmp_path / "b.ply"), "ply_source": None}
    job.write_text(json.dumps({"task": "export_ply", "params": params}))
    paths_for(job)["cancel"].touch()
    code, status = _worker(job)
    assert (code, status["state"]) == (3, "cancelled") and not (tmp_path / "b.ply").exists()


def test_merge_flat_is_a_per_job_switch(tmp_path: Path) -> None:
    """``merge_flat``: at 256 px the Gaussians are placed at twice the generator's 128-px
    matching size, so flat 2x2 blocks merge and the stats say how many; the cached model
    keeps no switch from one job to the next (the next job without it merges nothing)."""
    folder = tmp_path / "s"
    cams = write_synthetic_scene(folder, size=256, n_views=3)
    params = {"frames": _frames(folder, cams, [0, 2]), "device": "cpu", "near": 0.5,
              "far": 10.0, "merge_flat": True}  # fmt: skip
    merged = run_task("reconstruct", params)
    assert merged["stats"]["merged"] > 0
    assert merged["count"] == merged["stats"]["kept"] < merged["stats"]["input"]
    plain = run_task("reconstruct", {**params, "merge_flat": False})
    assert "merged" not in plain["stats"] and plain["count"] > merged["count"]
