"""prosplat.eval.generator and `prosplat eval generator` on tiny synthetic scenes (no Blender)."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat
from prosplat.data import load_scene
from prosplat.eval.demo_scene import pixel_aligned_gaussians, raycast
from prosplat.eval.generator import (
    evaluate_scene,
    generator_method,
    markdown_table,
    pick_inputs,
    plane_sweep_method,
    scene_at,
    summarise,
)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("eval") / "scene_a"
    write_synthetic_scene(folder, size=32, n_views=5)
    return load_scene(folder)


def exact_method(images, cameras, near, far):
    """The scene's own generator-style Gaussians and exact depths: the best a method can do."""
    return pixel_aligned_gaussians(cameras), torch.stack([raycast(c)[0].float() for c in cameras])


def wrong_method(images, cameras, near, far):
    """Mid-grey Gaussians pushed 30 % farther from the first camera: wrong colour and depth."""
    g, depths = exact_method(images, cameras, near, far)
    g.sh[:, 0] = 0.0
    c0 = cameras[0].center.float()
    g.means = c0 + 1.3 * (g.means - c0)
    return g, depths * 1.3


def test_exact_method_beats_a_wrong_one_and_depth_is_exact(scene):
    rows = evaluate_scene(scene, {"exact": exact_method, "wrong": wrong_method}, views=[2, 3])
    summary = {(s["method"], s["views"]): s for s in summarise(rows)}
    for v in (2, 3):
        assert summary[("exact", v)]["psnr"] > summary[("wrong", v)]["psnr"] + 3
        # mean AbsRel of exact geometry: only blended depth edges (many at 32 px) miss
        assert summary[("exact", v)]["abs_rel"] < 0.08 < summary[("wrong", v)]["abs_rel"]
        assert summary[("exact", v)]["recon_s"] >= 0 and summary[("exact", v)]["render_ms"] > 0
    assert len(rows) == 2 * 2 * 2  # methods x view counts x targets
    assert {r.kind for r in rows} == {"interpolation"}
    table = markdown_table(summarise(rows))
    assert table.count("\n") == 1 + 4 and "| 3 | interpolation | exact |" in table


def test_pick_inputs_spreads_views_and_refuses_too_many(scene):
    assert pick_inputs(scene, 3) == [0, 2, 4]
    two = pick_inputs(scene, 2)
    assert len(two) == 2 and set(two) <= {0, 2, 4}
    with pytest.raises(ValueError, match="input views"):
        pick_inputs(scene, 4)


def test_scene_at_resizes_every_view_and_picks_the_inputs(scene):
    at = scene_at(scene, 3, 64)
    assert at.images.shape == (5, 3, 64, 64) and at.inputs == pick_inputs(scene, 3)
    assert [(c.width, c.height) for c in at.cameras] == [(64, 64)] * 5
    assert torch.equal(at.input_images, at.images[[0, 2, 4]])
    assert at.input_cameras[1] is at.cameras[2]
    assert at.near == float(scene.near[[0, 2, 4]].min()) < at.far
    # the resize is the antialiased one every evaluation uses: its mean colour is kept
    assert torch.allclose(at.images.mean((2, 3)), scene.images.mean((2, 3)), atol=0.01)


def test_generator_and_plane_sweep_give_finite_scores(scene):
    torch.manual_seed(0)
    methods = {"gen": generator_method(ProSplat()), "ps": plane_sweep_method(n_depths=16)}
    for s in summarise(evaluate_scene(scene, methods, views=[2])):
        assert all(math.isfinite(s[k]) for k in ("psnr", "ssim", "lpips", "recon_s", "render_ms"))


def test_cli_runs_baselines_only(scene, tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "prosplat",
        "eval",
        "generator",
        "--data",
        str(scene.folder),
        "--views",
        "2",
        "--no-generator",
        "--baselines",
        "plane_sweep",
        "optimize",
        "--opt-steps",
        "3",
        "--out",
        str(tmp_path / "eval"),
    ]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "| 2 | interpolation | plane sweep |" in res.stdout
    assert "| 2 | interpolation | 3DGS opt 3 |" in res.stdout
    for reference in ("flat colour", "MORI paste", "true depth"):  # the ladder's rows, by default
        assert f"| 2 | interpolation | {reference} |" in res.stdout
    assert (tmp_path / "eval" / "summary.md").exists() and (
        tmp_path / "eval" / "scores.json"
    ).exists()


def test_reference_rows_score_the_same_targets_in_both_evaluations(scene):
    """`eval generator` and `eval improve` add the ladder's flat / paste / true-depth rows; the
    flat row is the inputs' mean colour, scored like any method, with an interval."""
    from prosplat.eval.improve import Row, evaluate_rows
    from prosplat.eval.ladder import flat_image
    from prosplat.metrics import psnr

    refs = ("flat", "paste", "true-depth")
    rows = evaluate_scene(scene, {"exact": exact_method}, views=[2], references=refs)
    names = [r.method for r in rows]
    assert names == ["flat colour"] * 2 + ["MORI paste"] * 2 + ["true depth"] * 2 + ["exact"] * 2
    idx = pick_inputs(scene, 2)
    flat = flat_image(scene.images[idx], 32, 32)
    for r, t in zip(rows[:2], scene.target_indices):
        assert r.psnr == pytest.approx(float(psnr(flat, scene.images[t])), abs=1e-4)
    by = {s["method"]: s for s in summarise(rows)}
    assert by["true depth"]["psnr"] > by["flat colour"]["psnr"] + 3  # exact geometry, 2 views
    assert by["true depth"]["abs_rel"] < 0.1 and math.isnan(by["MORI paste"]["abs_rel"])
    assert by["exact"]["psnr_lo"] <= by["exact"]["psnr"] <= by["exact"]["psnr_hi"]
    torch.manual_seed(0)
    ablation = evaluate_rows(scene, {"gen": Row(ProSplat())}, [2], references=("flat", "paste"))
    assert [r.method for r in ablation] == names[:4] + ["gen"] * 2
    assert [r.psnr for r in ablation[:4]] == [r.psnr for r in rows[:4]]
