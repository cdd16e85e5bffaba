"""``prosplat demo`` end to end on a tiny Blender scene: files, numbers, no clobbering."""

from __future__ import annotations

import json
import math

import pytest
import torch

from prosplat.cli import main
from prosplat.cli.demo import DemoConfig, downsample, run_demo
from prosplat.core.image_io import read_image
from prosplat.core.ply import read_ply
from prosplat.data import load_scene
from prosplat.metrics import psnr

pytestmark = pytest.mark.blender
pytest.importorskip("bpy")

TINY = dict(size=32, render_scale=2, inputs=2, targets=2, samples=2)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "demo"
    return run_demo(DemoConfig(out=out, **TINY))


def test_demo_writes_every_file_with_finite_scores(first_run):
    out = first_run.out
    for name in ("scene.blend", "gaussians.ply", "overview.png", "plot.png", "report.md"):
        assert (out / name).is_file(), name
    views = sorted((out / "views").glob("view_*.png"))
    assert len(views) == TINY["targets"]
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["views"]) == TINY["targets"]
    for row in metrics["views"]:
        for key in ("psnr_raw", "psnr_enhanced", "ssim_raw", "lpips_raw", "lpips_enhanced"):
            assert math.isfinite(row[key]), key
        assert row["kind"] in ("interpolation", "extrapolation")
    report = (out / "report.md").read_text()
    assert "overview.png" in report and all(f"views/{v.name}" in report for v in views)
    # the default denoiser, and Blender's size said as it is (render_scale 2 here)
    assert "2 samples at 64², denoised (fast), downsampled to the model's 32²" in report
    assert metrics["settings"]["denoise"] == "fast"
    assert {"ladder", "pictures"} <= set(metrics["timings_s"])
    assert len(read_ply(out / "gaussians.ply")) == first_run.gaussians["kept"]


def test_demo_scores_are_against_blender_ground_truth(first_run):
    """The reported PSNR is the generator render against the downsampled Blender image."""
    scene = load_scene(first_run.scene_folder)
    assert scene.images.shape[-1] == TINY["size"] * TINY["render_scale"]
    images, cameras = downsample(scene, TINY["size"])
    assert cameras[0].width == TINY["size"]
    for v in first_run.views:
        assert torch.equal(v.images["blender"], images[v.index])
        assert v.reference in scene.input_indices
        assert abs(v.psnr_raw - float(psnr(v.images["generator"], images[v.index]))) < 1e-4
    # side-by-side pictures hold four panels in a row: wider than tall
    pic = read_image(next((first_run.out / "views").glob("view_*.png")))
    assert pic.shape[2] > 3 * pic.shape[1]


def test_demo_pictures_never_downsample_a_panel(tmp_path):
    """A 256-px view's panels come out at least 256 px wide (the figure's resolution grows
    with the views; nearest-neighbour downsampling would drop pixels)."""
    from prosplat.cli.demo_report import PANELS, ViewResult, overview, side_by_side

    size = 256
    images = {key: torch.rand(3, size, size) for key, _ in PANELS}
    scores = dict.fromkeys(("psnr", "ssim", "lpips"), 0.5)
    v = ViewResult(
        index=1, kind="interpolation", reference=0,
        **{f"{m}_{w}": x for m, x in scores.items() for w in ("raw", "enhanced")},
        render_ms=1.0, mori_ms=1.0, enhance_ms=1.0, images=images,
    )  # fmt: skip
    side_by_side(v, tmp_path / "row.png")
    overview([v], tmp_path / "overview.png")
    for name in ("row.png", "overview.png"):
        assert read_image(tmp_path / name).shape[-1] > 4 * size, name


def test_demo_generator_panel_is_the_raw_view_with_its_holes_filled(first_run):
    """The generator column is the written Gaussians' raw view with the holes no input saw
    filled (``render_view(..., fill_holes=True)``), not the render on black."""
    from prosplat.pipeline.enhance import render_view

    scene = load_scene(first_run.scene_folder)
    images, cameras = downsample(scene, TINY["size"])
    ins = scene.input_indices
    gaussians = read_ply(first_run.out / "gaussians.ply")
    assert gaussians.views is not None  # the PLY keeps each Gaussian's input view
    for v in first_run.views:
        # with the inputs: the colour favours the input MORI picks, as every view does
        view = render_view(
            gaussians, cameras[v.index], images[ins], [cameras[i] for i in ins], fill_holes=True
        )
        assert torch.allclose(v.images["generator"], view.image.clamp(0, 1), atol=2e-3)
        if (view.alpha < 0.5).any():  # where the render on black has holes, the panel differs
            assert not torch.allclose(v.images["generator"], view.raw.clamp(0, 1), atol=2e-3)


def test_demo_rerun_does_not_clobber_and_overwrite_replaces(first_run, capsys):
    before = (first_run.out / "metrics.json").read_bytes()
    args = ["demo", "--out", str(first_run.out), "--size", "32", "--inputs", "2"]
    args += ["--targets", "1", "--samples", "1"]
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 0
    second = first_run.out.with_name("demo-2")
    assert (second / "report.md").is_file()
    assert (first_run.out / "metrics.json").read_bytes() == before
    keep = second / "notes.txt"  # a user's own file survives --overwrite
    keep.write_text("mine")
    with pytest.raises(SystemExit) as e:
        main([*args[:2], str(second), *args[3:], "--overwrite"])
    assert e.value.code == 0
    assert keep.read_text() == "mine"
    assert len(list((second / "views").glob("*.png"))) == 1
    # the default render scale 1: Blender renders at the model's size, nothing downsampled
    assert (
        "1 sample at 32², denoised (fast), the model's size" in (second / "report.md").read_text()
    )


@pytest.mark.parametrize(
    "bad, message",
    [
        (["--size", "48"], "multiple of 32"),
        (["--inputs", "7"], "2-6"),
        (["--budget", "0"], "budget"),
        (["--denoise", "slow"], "invalid choice"),
    ],
)
def test_demo_bad_arguments_exit_2(tmp_path, capsys, bad, message):
    with pytest.raises(SystemExit) as e:
        main(["demo", "--out", str(tmp_path / "d"), *bad])
    assert e.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("refine_steps", [0, 3])
def test_demo_refines_from_the_one_pass_gaussians(first_run, tmp_path, monkeypatch, refine_steps):
    """The demo asks the generator for the depth sweep's scene-wide factor whether or not it
    refines: refinement starts from the one-pass Gaussians, as everywhere else in the pipeline
    (ProSplat.reconstruct). Blender is replaced by a copy of the first run's scene."""
    import shutil

    import prosplat.cli.demo as demo
    from prosplat.pipeline.model import ProSplat

    asked: list[bool] = []
    reconstruct = ProSplat.reconstruct

    def spy(self, *args, **kwargs):
        asked.append(kwargs.get("depth_scale", True))
        return reconstruct(self, *args, **kwargs)

    def scene_copy(cfg, dest, blend):
        shutil.copytree(first_run.scene_folder, dest)
        return dest

    monkeypatch.setattr(ProSplat, "reconstruct", spy)
    monkeypatch.setattr(demo, "render_scene_with_blender", scene_copy)
    res = run_demo(DemoConfig(out=tmp_path / "d", refine_steps=refine_steps, **TINY))
    assert asked == [True, True]  # the demo's own Gaussians, then its ladder's generator row
    assert (res.timings["refine"] > 0) == bool(refine_steps)
