"""The add-on's inputs as an artist meets them (issue 15): a scene folder with input and
target frames goes import -> reconstruct -> render targets with no manual edits; views are
chosen (<= the generator's max_views) and the artist can override the choice; cameras are
named by their image stems; RGBA inputs go over the chosen background; rendering above the
input resolution warns; an unsaved file has no default output folder."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import run_op  # noqa: E402
from posed_data import scene_cameras, write_transforms_set  # noqa: E402
from synthetic_scenes import write_synthetic_scene  # noqa: E402

from addon.blender import api, cameras, runtime, steps  # noqa: E402
from prosplat.core.image_io import read_image  # noqa: E402
from prosplat.metrics import psnr  # noqa: E402

SIZE = 32


def names(coll) -> list[str]:
    return sorted(o.name for o in coll.objects)


def test_scene_folder_import_reconstruct_render_targets(blank, tmp_path: Path) -> None:
    """`prosplat scenes render`'s layout (4 inputs + 4 targets), with the panel's defaults only:
    the renders land beside the saved .blend and match the targets' ground truth."""
    write_synthetic_scene(tmp_path / "scene", size=SIZE, n_views=8)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "work.blend"))
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(tmp_path / "scene"))
    assert res == {"FINISHED"}, err
    s = bpy.context.scene.prosplat
    targets = steps.targets_of(s.inputs)
    assert names(s.inputs) == ["000", "002", "004", "006"]
    assert names(targets) == ["001", "003", "005", "007"]
    assert {o[steps.KIND_PROP] for o in targets.objects} == {"interpolation"}
    scene = bpy.context.scene
    assert scene.camera.name == "001" and scene.camera.name not in s.inputs.objects
    assert s.render_mode == "TARGETS" and not any("." in o.name for o in bpy.data.objects)

    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"FINISHED"}, err
    assert list(s.gaussians[steps.VIEWS_PROP]) == ["000", "002", "004", "006"]

    res, err = run_op(bpy.ops.prosplat.render_view)
    assert res == {"FINISHED"}, err
    out = tmp_path / "prosplat_renders"
    assert sorted(p.name for p in out.glob("*.png")) == ["001.png", "003.png", "005.png", "007.png"]
    for name in ("001", "003", "005", "007"):
        got = read_image(out / f"{name}.png")
        want = read_image(tmp_path / "scene" / "images" / f"{name}.png")
        assert got.shape == want.shape == (3, SIZE, SIZE)
        assert float(psnr(got[None], want[None])) > 14.0, name  # a flat grey scores ~8 dB


def _all_inputs_scene(folder: Path, n: int) -> Path:
    """A scene folder whose ``n`` frames are all inputs (no split): more than the generator
    takes, as a NeRF-synthetic training set is."""
    write_synthetic_scene(folder, size=SIZE, n_views=n)
    path = folder / "transforms.json"
    data = json.loads(path.read_text())
    for f in data["frames"]:
        f.pop("split", None)
        f.pop("target_kind", None)
    path.write_text(json.dumps(data))
    return path


def _reconstruct_result(coll) -> dict:
    return runtime.run_sync(*steps.reconstruct_job(coll, bpy.context.scene))


def test_view_choice_at_most_max_views_and_the_override(blank, tmp_path: Path) -> None:
    path = _all_inputs_scene(tmp_path / "s", 8)
    coll = api.import_posed_images(path)
    assert len(coll.objects) == 8 and steps.targets_of(coll) is None
    result = _reconstruct_result(coll)
    used = result["views"]
    assert len(used) == 6 and len(set(used)) == 6 and set(used) <= set(names(coll))
    why = result["view_reason"]
    assert "6 spread widely over the 8 of 8 views that see the region of interest" in why
    assert "views: 6 spread" in steps.describe_reconstruct(result)
    tri = {**result, "near_far_source": "71 points triangulated from the 4 inputs (0.5 s)",
           "anchored_views": 3}  # fmt: skip
    line = steps.describe_reconstruct(tri)
    assert "; depth range from 71 points triangulated from the 4 inputs (0.5 s), depth " in line
    assert "scaled to them in 3 views" in line
    plain = {**result, "near_far_source": "the input cameras", "anchored_views": 0}
    assert "depth range" not in steps.describe_reconstruct(plain)
    assert ", ".join(used) in result["view_reason"]

    # the artist's override: unchecked cameras are never used; few enough -> exactly those
    keep = ["001", "004", "006"]
    for obj in coll.objects:
        setattr(obj, cameras.USE_PROP, obj.name in keep)
    result = _reconstruct_result(coll)
    assert result["views"] == keep and "all 3 input views" in result["view_reason"]
    g = api.reconstruct(coll)
    assert list(g[steps.VIEWS_PROP]) == keep

    # nearest the active camera: the view it sits on and its neighbours on the orbit
    for obj in coll.objects:
        setattr(obj, cameras.USE_PROP, True)
    bpy.context.scene.camera = coll.objects["003"]
    bpy.context.scene.prosplat.view_choice = "NEAREST"
    result = _reconstruct_result(coll)
    assert len(result["views"]) == 6 and "003" in result["views"]
    assert "nearest the active camera" in result["view_reason"]
    far_side = {"007"}  # opposite 003 on the 8-camera orbit
    assert not far_side & set(result["views"])


def test_names_come_from_image_stems(blank, tmp_path: Path) -> None:
    cams = scene_cameras(3, SIZE, SIZE)
    path = write_transforms_set(tmp_path / "a", cams)
    data = json.loads(path.read_text())
    for f, new in zip(data["frames"], ["left/IMG_7.png", "right/IMG_7.png", "top/IMG_9.png"]):
        (path.parent / new).parent.mkdir(exist_ok=True)
        (path.parent / f["file_path"]).rename(path.parent / new)
        f["file_path"] = new
    path.write_text(json.dumps(data))
    first = api.import_posed_images(path)
    assert names(first) == ["left_IMG_7", "right_IMG_7", "top_IMG_9"]  # stems collide here
    second = api.import_posed_images(path)  # the same file again: one suffix for all
    assert names(second) == ["left_IMG_7-2", "right_IMG_7-2", "top_IMG_9-2"]
    assert not any("." in o.name for o in bpy.data.objects)
    # unique stems are the names as they are, and the scene camera is none of the inputs
    assert names(api.import_posed_images(write_transforms_set(tmp_path / "b", cams))) == [
        "000", "001", "002"]  # fmt: skip
    assert bpy.context.scene.camera.name == "ProSplat Camera"
    assert all(bpy.context.scene.camera.name not in c.objects for c in bpy.data.collections)


def _rgba_scene(folder: Path) -> Path:
    alpha = torch.ones(SIZE, SIZE)
    alpha[:, : SIZE // 4] = 0  # the left quarter of every image is transparent
    return write_transforms_set(folder, scene_cameras(3, SIZE, SIZE), rgba_alpha=alpha,
                                angle_x=True)  # fmt: skip


def test_rgba_inputs_go_over_the_background(blank, tmp_path: Path) -> None:
    from prosplat.worker import Progress
    from prosplat.worker.tasks import load_frames

    coll = api.import_posed_images(_rgba_scene(tmp_path / "lego"))
    scene = bpy.context.scene
    assert tuple(scene.prosplat.background) == (1.0, 1.0, 1.0)  # NeRF-synthetic's default
    seen = {}
    for colour in ((1.0, 1.0, 1.0), (0.0, 1.0, 0.0)):
        scene.prosplat.background = colour
        _, params = steps.reconstruct_job(coll, scene)
        assert params["merge_flat"] is False  # the preference's default (opt-in)
        # what the generator is given: exactly the colour where the images are transparent
        images, _ = load_frames(params["frames"], Progress(), 0, 1, params["background"])
        left = images[:, :, :, : SIZE // 4].permute(1, 0, 2, 3).reshape(3, -1)
        assert torch.equal(left, torch.tensor(colour)[:, None].expand_as(left))
        assert images[:, :, :, SIZE // 2 :].std() > 0.05  # the opaque part is the scene
        g = api.reconstruct(coll)
        result = api.render_views(g, [coll.objects["000"]], tmp_path / str(colour), enhance=False)
        img = read_image(result["views"][0]["image"])
        seen[colour] = img[:, 4:-4, 1 : SIZE // 4 - 2].reshape(3, -1).mean(1)
    white, green = seen[(1.0, 1.0, 1.0)], seen[(0.0, 1.0, 0.0)]
    assert float(white.min()) > 0.65 and float(white.max() - white.min()) < 0.15, white
    assert float(green[1]) > 0.8 and float(green[[0, 2]].max()) < 0.2, green


def test_render_above_the_input_resolution_warns(blank, tmp_path: Path) -> None:
    write_synthetic_scene(tmp_path / "s", size=SIZE, n_views=4)
    coll = api.import_posed_images(tmp_path / "s")
    g = api.reconstruct(coll)
    assert list(g[steps.MADE_SIZE_PROP]) == [SIZE, SIZE]
    scene = bpy.context.scene
    target = steps.targets_of(coll).objects["001"]
    same = api.render_views(g, [target], tmp_path / "a", enhance=False)
    assert not [w for w in same["warnings"] if "above" in w]
    scene.render.resolution_x = scene.render.resolution_y = 2 * SIZE
    big = api.render_views(g, [target], tmp_path / "b", enhance=False)
    (warning,) = [w for w in big["warnings"] if "above" in w]
    assert f"at {2 * SIZE}x{2 * SIZE}, above the {SIZE}x{SIZE}" in warning and "holes" in warning
    assert read_image(big["views"][0]["image"]).shape == (3, 2 * SIZE, 2 * SIZE)


def test_unsaved_file_has_no_default_output_folder(blank, tmp_path: Path) -> None:
    write_synthetic_scene(tmp_path / "s", size=SIZE, n_views=3)
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(tmp_path / "s"))
    assert res == {"FINISHED"}, err
    assert run_op(bpy.ops.prosplat.reconstruct)[0] == {"FINISHED"}
    s = bpy.context.scene.prosplat
    assert s.output_dir == "//prosplat_renders" and not bpy.data.filepath
    res, err = run_op(bpy.ops.prosplat.render_view)
    assert res == {"CANCELLED"} and "not saved" in err and "save the file" in err, err
    for blend_relative in ("", "//renders"):
        with pytest.raises(ValueError, match="not saved"):
            steps.resolve_dir(blend_relative, "renders")
    s.output_dir = str(tmp_path / "chosen")
    assert run_op(bpy.ops.prosplat.render_view)[0] == {"FINISHED"}
    assert (tmp_path / "chosen" / "001.png").is_file()
    (tmp_path / "work").mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "work" / "w.blend"))
    assert steps.resolve_dir("//prosplat_renders", "renders") == tmp_path / "work" / (
        "prosplat_renders"
    )
    assert steps.resolve_dir("", "capture") == tmp_path / "work" / "prosplat_capture"
