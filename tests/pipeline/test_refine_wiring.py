"""Refinement wherever a scene is reconstructed: ProSplat.reconstruct, `prosplat eval
generator`, `prosplat demo`'s options and `prosplat train curate` (tiny synthetic scenes)."""

from __future__ import annotations

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat
from prosplat.cli import build_parser, main
from prosplat.cli.demo import DemoConfig
from prosplat.data import load_scene
from prosplat.data.rigs import pick_inputs
from prosplat.data.scene import resize_views
from prosplat.eval.generator import evaluate_scene, refine_label, refine_method
from prosplat.pipeline.model import TRAINED_SIZE


@pytest.fixture(scope="module")
def model(shipped_generator):
    return shipped_generator


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("refine") / "scenes" / "scene_a"
    write_synthetic_scene(folder, size=32, n_views=5)
    return load_scene(folder)


def scene_inputs(scene, n=3):
    idx = pick_inputs(scene, n)
    near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
    return scene.images[idx], [scene.cameras[i] for i in idx], near, far


def test_reconstruct_refines_the_pruned_gaussians(scene, model):
    images, cams, near, far = scene_inputs(scene)
    raw = model.reconstruct(images, cams, near, far, budget="all").gaussians
    assert len(raw) == 3 * 32 * 32  # every Gaussian: pixel-aligned, unpruned
    calls = []
    res = model.reconstruct(
        images, cams, near, far, refine_steps=4, progress=lambda *a: calls.append(a)
    )
    st = res.refine_stats
    assert st.steps == 4 and len(calls) == 4 and res.prune_stats["input"] == len(raw)
    assert 0 < st.n_gaussians == len(res.gaussians) <= len(raw)
    assert res.timings["generator"] > 0 and res.timings["prune"] >= 0
    assert res.timings["refine"] >= st.seconds > 0
    again = model.reconstruct(images, cams, near, far, refine_steps=4)
    assert torch.equal(again.gaussians.means, res.gaussians.means)  # same seed, same Gaussians
    timed = model.reconstruct(images, cams, near, far, refine_seconds=0.2)
    assert len(timed.gaussians) == len(again.gaussians)
    pruned = model.reconstruct(images, cams, near, far)  # no refinement: the budget's Gaussians
    assert pruned.refine_stats is None and pruned.timings["refine"] == 0
    assert len(pruned.gaussians) == len(res.gaussians)
    zero = model.reconstruct(images, cams, near, far, refine_steps=0)  # refines 0 steps
    assert zero.refine_stats.steps == 0 and len(zero.gaussians) == len(pruned.gaussians)


def test_the_generator_runs_at_its_trained_size_and_refinement_at_the_inputs(
    model, tmp_path_factory
):
    """The shipped weights were trained at up to T = 128 px: given 2T-px inputs, the pipeline
    matches on them resized to T px and places one Gaussian per 2T-px input pixel
    (:meth:`ProSplat.reconstruct`; with ``full_res_gaussians`` off, a quarter of them, at T px);
    the Gaussians render at 2T px, and refinement fits the 2T-px inputs.
    ``generator_height=0`` runs it all at the inputs' size; a saved model keeps its trained
    size."""
    t = TRAINED_SIZE
    folder = tmp_path_factory.mktemp("big") / "scene_b"
    write_synthetic_scene(folder, size=2 * t, n_views=5)
    big = load_scene(folder)
    images, cams, near, far = scene_inputs(big)
    assert model.trained_size == t == 128
    assert model.depth_sweep is not None  # on by default; off here to compare raw depths
    sweep, model.depth_sweep = model.depth_sweep, None
    try:
        out = model.reconstruct(images, cams, near, far, budget="all")
    finally:
        model.depth_sweep = sweep
    assert out.depths.shape[-2:] == (2 * t, 2 * t) and out.cameras == cams
    small, small_cams = resize_views(images, cams, t)  # what the generator matches on
    matched = model.run_generator(small, small_cams, near, far).depths[0]
    up = torch.nn.functional.interpolate(1 / matched[:, None], size=(2 * t, 2 * t), mode="bilinear")
    assert torch.allclose(1 / out.depths, up[:, 0], rtol=1e-4)  # matched at T px
    swept = model.reconstruct(images, cams, near, far, budget="all")  # depth moves, not layout
    assert swept.depths.shape == out.depths.shape and not torch.equal(swept.depths, out.depths)
    assert len(swept.gaussians) == 3 * 4 * t * t
    native = model.reconstruct(images, cams, near, far, budget="all", generator_height=0)
    assert len(native.gaussians) == 3 * 4 * t * t
    assert not torch.allclose(native.gaussians.means, out.gaussians.means)
    res = model.reconstruct(images, cams, near, far, refine_steps=3)
    assert res.prune_stats["input"] == 3 * 4 * t * t
    model.full_res_gaussians = False
    try:
        low = model.reconstruct(images, cams, near, far, budget="all")
        assert low.depths.shape[-2:] == (t, t) and len(low.gaussians) == 3 * t * t
        assert (low.cameras[0].width, low.cameras[0].height) == (t, t)
        assert torch.equal(low.cameras[0].center, cams[0].center)  # scaled intrinsics only
    finally:
        model.full_res_gaussians = True
    from prosplat.render import render

    assert render(res.gaussians, cams[0]).rgb.shape[-2:] == (2 * t, 2 * t)
    # inputs already at or below the trained size are left as they are
    same = model.reconstruct(small, small_cams, near, far, budget="all")
    assert same.cameras == small_cams and same.depths.shape[-2:] == (t, t)
    path = ProSplat(model.config, trained_size=96).save(
        tmp_path_factory.mktemp("w") / "g.safetensors"
    )
    assert ProSplat.from_pretrained(path, improve=False).trained_size == 96
    assert ProSplat(model.config).trained_size is None


def test_reconstruct_refusals_name_the_fix(scene, model):
    images, cams, near, far = scene_inputs(scene)
    with pytest.raises(ValueError, match="not both"):
        model.reconstruct(images, cams, near, far, refine_steps=3, refine_seconds=1.0)
    with pytest.raises(ValueError, match="integer >= 0"):
        model.reconstruct(images, cams, near, far, refine_steps=-2)
    with pytest.raises(ValueError, match="seconds must be a finite number > 0"):
        model.reconstruct(images, cams, near, far, refine_seconds=float("nan"))
    bad = images.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        model.reconstruct(bad, cams, near, far, refine_steps=3)
    with pytest.raises(ValueError, match="one camera per image"):
        model.reconstruct(images, cams[:2], near, far, refine_steps=3)


def test_refine_method_row_fits_inputs_better_than_the_generator(scene, model):
    """The refined row's input views (scored as targets here) beat the generator's: the
    method really refines what it returns."""
    from prosplat.eval.generator import generator_method

    methods = {
        "gen": generator_method(model),
        refine_label(steps=30): refine_method(model, steps=30),
    }
    sc = scene.select(scene.input_indices + scene.input_indices)
    n = len(scene.input_indices)
    sc.splits = ["input"] * n + ["target"] * n
    sc.target_kinds = [None] * n + ["interpolation"] * n
    rows = evaluate_scene(sc, methods, views=[3])
    mean = {
        m: sum(r.psnr for r in rows if r.method == m) / n for m in ("gen", "generator+refine 30")
    }
    assert mean["generator+refine 30"] > mean["gen"] + 0.5, mean


def test_eval_cli_adds_refine_rows(scene, tmp_path, capsys):
    argv = ["eval", "generator", "--data", str(scene.folder.parent), "--views", "2"]
    argv += ["--baselines", "--refine-steps", "3", "--refine-seconds", "0.2"]
    argv += ["--out", str(tmp_path / "eval")]
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 0
    out = capsys.readouterr().out
    for row in ("| generator |", "| generator+refine 3 |", "| generator+refine 0.2s |"):
        assert row in out
    with pytest.raises(SystemExit) as e:
        main(argv[:-2] + ["--refine-steps", "-1", "--out", str(tmp_path / "bad")])
    assert e.value.code == 2 and "--refine-steps must be >= 0" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_demo_refine_options_parse_and_check():
    args = build_parser().parse_args(["demo", "--refine-steps", "300"])
    assert (args.refine_steps, args.refine_seconds) == (300, None)
    assert build_parser().parse_args(["demo", "--refine-steps"]).refine_steps == 300  # the knee
    assert build_parser().parse_args(["demo"]).refine_steps == 0  # off unless asked for
    args = build_parser().parse_args(["demo", "--refine-seconds", "5"])
    assert (args.refine_steps, args.refine_seconds) == (0, 5.0)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["demo", "--refine-steps", "3", "--refine-seconds", "5"])
    for bad, message in (
        (dict(refine_steps=-1), "--refine-steps must be >= 0"),
        (dict(refine_seconds=0.0), "--refine-seconds must be"),
        (dict(refine_steps=3, refine_seconds=2.0), "not both"),
    ):
        with pytest.raises(ValueError, match=message):
            DemoConfig(**bad).check()
    DemoConfig(refine_steps=10).check()


def test_curate_renders_refined_scenes(scene, model, tmp_path):
    from prosplat.train.curate import curate, load_curated

    root = scene.folder.parent
    plain = curate(model, root, tmp_path / "plain.safetensors", views=(2,), progress=False)
    args = build_parser().parse_args(
        ["train", "curate", "--data", str(root), "--out", str(tmp_path / "refined.safetensors"),
         "--views", "2", "--refine-steps", "20"]
    )  # fmt: skip
    assert args.refine_steps == 20
    assert args.func(args) == 0
    a, b = load_curated(plain), load_curated(tmp_path / "refined.safetensors")
    assert a["render"].shape == b["render"].shape
    assert torch.equal(a["target"], b["target"]) and not torch.equal(a["render"], b["render"])
    from safetensors import safe_open

    with safe_open(str(tmp_path / "refined.safetensors"), "pt") as f:
        assert f.metadata()["refine_steps"] == "20"
    with pytest.raises(ValueError, match="refine_steps"):
        curate(model, root, tmp_path / "x.safetensors", views=(2,), refine_steps=-1)
