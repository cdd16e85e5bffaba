"""The artist's path end to end, on a seeded tabletop scene rendered with Cycles:
capture inputs -> reconstruct -> render view, compared with a Cycles render of the target.

The default run checks the plumbing and that the raw render agrees with Cycles far better
than chance; the slow test asks the issue's question (enhanced PSNR above raw), which needs
trained stage-2 weights and skips without them.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import ROOT, data_counts, ensure_registered, run_op  # noqa: E402

from addon.blender import api, capture  # noqa: E402
from addon.blender.pointcloud import point_count, read_arrays  # noqa: E402
from prosplat import Camera  # noqa: E402
from prosplat.convert.blender import blender_from_camera  # noqa: E402
from prosplat.core.image_io import read_image  # noqa: E402
from prosplat.data.rigs import choose_rig  # noqa: E402
from prosplat.metrics import psnr  # noqa: E402

SIZE, SEED = 64, 950002


def _place(name: str, eye, look, lens_mm: float):
    from mathutils import Matrix

    cam = Camera.look_at(eye, look, (0, 0, 1), lens_mm / 36.0 * SIZE, SIZE, SIZE)
    p = blender_from_camera(cam)
    obj = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    bpy.context.scene.collection.objects.link(obj)
    obj.matrix_world = Matrix(p.matrix_world.tolist())
    obj.data.lens, obj.data.sensor_width = p.lens, p.sensor_width
    obj.data.clip_start, obj.data.clip_end = 0.01, 1000.0
    return obj


@pytest.fixture(scope="module")
def tabletop(tmp_path_factory):
    """A tabletop scene, 3 wide-baseline input cameras and 1 interpolation target, all at 64²."""
    import sys

    sys.path.insert(0, str(ROOT))
    from scenes.builders import build_scene
    from scenes.render import configure_render

    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    info = build_scene("tabletop", SEED)
    configure_render(SIZE, 16, False, SEED, 2)
    rig = choose_rig(info.trajectory, 3, 2, SEED)
    inputs = [_place(f"in{i}", *info.trajectory[t], info.lens_mm) for i, t in enumerate(rig.inputs)]
    target_index = next(t for t, k in zip(rig.targets, rig.target_kinds) if k == "interpolation")
    target = _place("target", *info.trajectory[target_index], info.lens_mm)
    folder = tmp_path_factory.mktemp("work")
    scene = bpy.context.scene
    scene.camera = target
    bpy.ops.render.render()
    with capture._ImageSettings(scene):
        bpy.data.images["Render Result"].save_render(str(folder / "cycles.png"), scene=scene)
    return scene, inputs, target, folder


def _same_as_library(capture_dir: Path, obj) -> None:
    """The add-on (cameras read from Blender objects) gives the Gaussians the library gives
    from the captured transforms.json and images: the glue adds nothing and loses nothing."""
    import numpy as np

    from prosplat import ProSplat
    from prosplat.convert import read_transforms

    tf = read_transforms(capture_dir / "transforms.json")
    cams = [f.camera for f in tf.frames]
    images = torch.stack([read_image(capture_dir / f.file_path) for f in tf.frames])
    want = (
        ProSplat.from_pretrained(improve=False)
        .reconstruct(images, cams, tf.meta["near"], tf.meta["far"], generator_height=0)
        .gaussians
    )  # the generator, its depth sweep and the budget, as the worker runs them
    got, w = read_arrays(obj)["position"], want.means.numpy()
    assert got.shape[0] == len(w)
    # The two paths do not read the scene bit for bit alike (the add-on takes the cameras
    # from Blender's objects, the library from transforms.json). Most Gaussians still agree
    # to 1e-4, in order. Where matching is flat a last-bit difference can move a patch: with
    # generator v11 on this scene 80 Gaussians (0.7 %) of one view move by up to 5 cm, and
    # the budget then keeps a different one of two tied Gaussians, which shifts every later
    # row by one. So: 99 % agree to 1e-4 with the library's Gaussian in the same row or one up
    # to 2 rows away, and every other one lies within 2 % of the far distance of some library
    # Gaussian (the farthest of them measured 0.058 from its nearest). A glue error (a camera
    # convention, the view order, near/far) moves every Gaussian by far more.
    same = np.zeros(len(w), dtype=bool)
    for shift in (-2, -1, 0, 1, 2):
        a, b = (
            got[max(shift, 0) : len(w) + min(shift, 0)],
            w[max(-shift, 0) : len(w) - max(shift, 0)],
        )
        near = (np.abs(a - b) <= 1e-4 + 1e-4 * np.abs(b)).all(axis=1)
        same[max(shift, 0) : len(w) + min(shift, 0)] |= near
    assert same.mean() > 0.99, float(same.mean())
    rest = torch.from_numpy(got[~same]).double()
    nearest = torch.cdist(rest, torch.from_numpy(w).double()).min(dim=1).values
    far = float(np.max(tf.meta["far"]))
    assert (nearest <= 0.02 * far).all(), (float(nearest.max()), far)


def test_capture_reconstruct_render(tabletop) -> None:
    scene, inputs, target, folder = tabletop
    for o in scene.objects:
        o.select_set(o in inputs)
    scene.prosplat.capture_dir = str(folder / "capture")
    res, err = run_op(bpy.ops.prosplat.capture_inputs)
    assert res == {"FINISHED"}, err
    coll = scene.prosplat.inputs
    assert (folder / "capture" / "transforms.json").is_file() and len(coll.objects) == 3
    assert coll["prosplat_near"] > 0 and coll["prosplat_far"] > coll["prosplat_near"]
    assert scene.camera == target and scene.render.image_settings.file_format == "PNG"

    # refinement off (the default refines for a few seconds): the glue's Gaussians must be
    # the library's, bit for bit
    res, err = run_op(bpy.ops.prosplat.reconstruct, refine_seconds=0.0)
    assert res == {"FINISHED"}, err
    g = scene.prosplat.gaussians
    assert g is not None and point_count(g) > 1000 and g["prosplat_inputs"] == coll.name
    _same_as_library(folder / "capture", g)

    scene.prosplat.output_dir = str(folder / "renders")
    scene.prosplat.save_depth = True
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.render_view)
    assert res == {"FINISHED"}, err
    out = folder / "renders" / "target.png"
    assert out.is_file() and (folder / "renders" / "target_depth.exr").is_file()
    img = bpy.data.images["ProSplat target"]
    assert tuple(img.size) == (SIZE, SIZE) and data_counts()["images"] == before["images"] + 1
    raw = read_image(out)
    gt = read_image(folder / "cycles.png")
    score = float(psnr(raw, gt))
    print(f"\nraw render vs Cycles: {score:.2f} dB (mean-colour baseline "
          f"{float(psnr(gt.mean(dim=(1, 2), keepdim=True).expand_as(gt), gt)):.2f} dB)")  # fmt: skip
    assert score > 12.0


def test_reconstruct_with_a_refinement_time_budget(tabletop) -> None:
    """Reconstruct's Refine Seconds (and api.reconstruct's refine_steps) fit the Gaussians to
    the inputs in the worker: same count as the plain reconstruction, other positions."""
    import numpy as np

    def positions(obj) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(read_arrays(obj)["position"]))

    scene, inputs, target, folder = tabletop
    coll = scene.prosplat.inputs
    plain = api.reconstruct(coll, name="plain", refine_seconds=0.0)
    res, err = run_op(bpy.ops.prosplat.reconstruct, refine_seconds=0.5)
    assert res == {"FINISHED"}, err
    timed = scene.prosplat.gaussians
    stepped = api.reconstruct(coll, name="stepped", refine_steps=3)
    n = point_count(plain)
    assert point_count(timed) == n == point_count(stepped)
    assert not torch.equal(positions(plain), positions(stepped))


def test_render_view_distills_when_asked(tabletop, tmp_path: Path) -> None:
    """Distill Steps (off by default) makes Render View fit the Gaussians to the enhanced
    views first and render from them; the status line says so."""
    from addon.blender import runtime, steps

    scene, inputs, target, folder = tabletop
    coll = scene.prosplat.inputs
    g = api.reconstruct(coll, name="to distil", refine_seconds=0.0)
    assert steps.render_job(g, [], scene, str(tmp_path), None, coll)[1]["distill_steps"] == 0
    assert runtime.Defaults.distill_steps == 0
    res = api.render_views(g, [target], tmp_path / "out", inputs=coll, enhance=True,
                           distill_steps=20)  # fmt: skip
    assert res["views"][0]["distilled"] and Path(res["views"][0]["image"]).is_file()
    assert "distilled from every enhanced view" in steps.describe_render(res)


def test_render_jobs_carry_each_gaussians_view_while_the_inputs_are_those_used(
    tabletop, tmp_path: Path
) -> None:
    """A reconstruction's point cloud keeps each Gaussian's input view (the ``prosplat_view``
    attribute), and Render View sends it with the inputs in the order the reconstruction
    numbered them, so views favour the input nearest them; with one of those cameras renamed
    the numbers would point at the wrong input, so the attribute stays behind."""
    import numpy as np

    from addon.blender import steps

    scene, inputs, target, folder = tabletop
    coll = scene.prosplat.inputs
    g = api.reconstruct(coll, name="views", refine_seconds=0.0)
    used = [str(n) for n in g[steps.VIEWS_PROP]]
    params = steps.render_job(g, [], scene, str(tmp_path), None, coll)[1]
    assert [f["name"] for f in params["inputs"]] == used
    assert set(np.unique(params["arrays"][steps.VIEW_ATTR]).tolist()) == set(range(len(used)))
    assert params["notes"] == []
    cam = bpy.data.objects[used[0]]
    cam.name = used[0] + " (renamed)"
    try:
        params = steps.render_job(g, [], scene, str(tmp_path), None, coll)[1]
        assert steps.VIEW_ATTR not in params["arrays"]
        assert len(params["notes"]) == 1 and used[0] in params["notes"][0]
        res = api.render_views(g, [target], tmp_path / "renamed", inputs=coll, enhance=False)
        assert any("favouring the nearest" in w for w in res["warnings"])
    finally:
        cam.name = used[0]


def test_raw_render_views_fill_the_holes_by_default(tabletop, tmp_path: Path) -> None:
    """Fill Holes defaults to Raw Renders: a raw Render View shows the fill where no input
    saw the scene instead of black (which costs the shipped generator about 9 dB); "off" leaves
    the black."""
    from addon.blender import runtime, steps

    scene, inputs, target, folder = tabletop
    coll = scene.prosplat.inputs
    g = api.reconstruct(coll, name="holes", refine_seconds=0.0)
    assert runtime.Defaults.fill_holes == "RAW"
    assert steps.render_job(g, [], scene, str(tmp_path), None, coll)[1]["fill_holes"] == "raw"
    filled, black = (
        read_image(
            api.render_views(
                g, [target], tmp_path / str(m), inputs=coll, enhance=False, fill_holes=m
            )["views"][0]["image"]
        )  # fmt: skip
        for m in (None, "off")  # None: the job's own setting
    )
    dark = black.amax(0) < 1.5 / 255  # [H,W] the holes, black
    assert float(dark.float().mean()) > 0.01, "the target view should have holes to fill"
    assert float((filled[:, dark].amax(0) > 0.02).float().mean()) > 0.9
    assert float(psnr(filled, read_image(folder / "cycles.png"))) > float(
        psnr(black, read_image(folder / "cycles.png"))
    )


@pytest.mark.slow
def test_enhanced_beats_raw_against_cycles(tabletop, tmp_path: Path) -> None:
    from prosplat.worker.tasks import load_model

    if load_model(None, torch.device("cpu"), None).improver is None:
        pytest.skip("no trained improvement-model weights ship yet (prosplat/weights)")
    scene, inputs, target, folder = tabletop
    final, coll = api.capture_inputs(inputs, tmp_path / "capture")
    g = api.reconstruct(coll)
    res = api.render_views(g, [target], tmp_path / "out", inputs=coll, enhance=True,
                           save_raw=True)  # fmt: skip
    view = res["views"][0]
    assert view["enhanced"] and view["reference_name"] in {o.name for o in coll.objects}
    gt = read_image(folder / "cycles.png")
    enhanced, raw = (
        float(psnr(read_image(view["image"]), gt)),
        float(psnr(read_image(view["raw"]), gt)),
    )
    print(f"\nvs Cycles: enhanced {enhanced:.2f} dB, raw {raw:.2f} dB, reference "
          f"{view['reference_name']}")  # fmt: skip
    assert enhanced > raw
