"""``prosplat bench points`` on a tiny synthetic scene (no Blender): the Pareto front, the rows'
arithmetic, enhancement-off rows against an independent render, and the CLI's files/errors."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat
from prosplat.data import load_scene
from prosplat.data.rigs import pick_inputs
from prosplat.data.scene import resize_views
from prosplat.eval.bench import pareto, points
from prosplat.geometry.budget import prune_gaussians
from prosplat.metrics import psnr


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A dataset folder with one 32 px scene: 4 input views, 4 targets (one extrapolation)."""
    root = tmp_path_factory.mktemp("bench") / "tiny"
    folder = root / "scene_a"
    write_synthetic_scene(folder, size=32, n_views=8)
    meta = json.loads((folder / "transforms.json").read_text())
    targets = [f for f in meta["frames"] if f["split"] == "target"]
    targets[-1]["target_kind"] = "extrapolation"
    (folder / "transforms.json").write_text(json.dumps(meta))
    return root


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return ProSplat.from_pretrained()


def parse(*argv: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    points.add_arguments(ap)
    return ap.parse_args(list(argv))


def test_pareto_front_excludes_dominated_keeps_ties_and_skips_nan():
    pts = [
        (10.0, 20.0),  # 0: front
        (5.0, 15.0),  # 1: front (fastest)
        (20.0, 19.0),  # 2: slower and worse than 0
        (5.0, 15.0),  # 3: tie with 1: kept
        (10.0, 18.0),  # 4: as fast as 0 but worse
        (1.0, float("nan")),  # 5: no quality: never on the front
        (30.0, 25.0),  # 6: front (best)
        (5.0, 14.0),  # 7: as fast as 1 but worse
    ]
    assert pareto.pareto_front(pts) == [1, 3, 0, 6]
    assert pareto.pareto_front([]) == []


def test_points_vary_one_axis_at_a_time():
    axes = points.parse_axes(parse("--data", "x", "--opt-steps", "300,1000"))
    pts = points.build_points(axes, plane_sweep=True)
    base = pts[0]
    config = (base.size, base.views, base.budget, base.enhance, base.dtype)
    assert config == (64, 4, None, True, "fp32")
    labels = [p.label for p in pts]
    assert len(set(labels)) == len(labels)
    assert len({(p.method, p.size, p.views, p.budget, p.enhance, p.dtype) for p in pts}) == len(pts)
    wanted = "32 px|2 views|6 views|enh off|2 views, enh off|6 views, enh off|budget 0.5"
    wanted += "|budget 0.2|bf16|plane sweep|opt-300|opt-1000"
    wanted += "|refine 50|refine 100|refine 300|refine 1000"  # the default refinement axis
    assert set(wanted.split("|")) <= set(labels)
    refined = [p for p in pts if p.family == "refine"]
    assert [p.method for p in refined] == ["refine-50", "refine-100", "refine-300", "refine-1000"]
    for p in refined:  # refinement varies only the method: the base point otherwise
        assert replace(p, family="", label="", method="") == replace(
            base, family="", label="", method=""
        )
    zero = points.build_points(points.parse_axes(parse("--data", "x", "--refine-steps", "0,5")))
    assert [p.label for p in zero if p.family == "refine"] == ["refine 5"]  # 0 is the base
    for p in pts[1:]:
        if p.family in ("resolution", "views", "budget", "dtype"):  # exactly one axis differs
            diff = [
                f
                for f in ("size", "views", "budget", "enhance", "dtype")
                if getattr(p, f) != getattr(base, f)
            ]
            assert len(diff) == 1, (p, diff)
    opt = [p for p in pts if p.family == "optimise"]
    assert all(not p.enhance and p.views == 4 for p in opt)
    # no improver wanted: no bf16 point (it changes stage 2 only)
    off = points.build_points(points.parse_axes(parse("--data", "x", "--enhance", "off")))
    assert not any(p.family == "dtype" for p in off) and not off[0].enhance


@pytest.mark.parametrize(
    "flag, value, message",
    [
        ("--sizes", "48", "multiples of 32"),
        ("--views", "2,7", "outside 2-6"),
        ("--budgets", "auto,1.5", "fraction in (0, 1]"),
        ("--budgets", "lots", "is not auto"),
        ("--budgets", "0", "is not auto"),
        ("--dtypes", "fp16", "not among"),
        ("--enhance", "maybe", "not on or off"),
        ("--repeats", "0", ">= 1"),
        ("--refine-steps", "-5", "must be >= 0"),
        ("--refine-steps", "many", "comma-separated integers"),
    ],
)
def test_bad_axis_values_exit_2_before_any_work(data, capsys, flag, value, message):
    assert points.run(parse("--data", str(data), flag, value, "--out", "unused")) == 2
    err = capsys.readouterr().err
    assert err.startswith("prosplat bench points:") and message in err


def test_missing_data_and_too_many_views_exit_2(data, tmp_path, capsys):
    assert points.run(parse("--data", str(tmp_path / "nope"), "--out", str(tmp_path))) == 2
    assert "prosplat scenes render" in capsys.readouterr().err
    assert points.run(parse("--data", str(data), "--views", "6", "--sizes", "32")) == 2
    assert "has 4 input views, cannot measure 6" in capsys.readouterr().err
    assert points.run(parse("--data", str(data), "--views", "2", "--sizes", "64")) == 2
    assert "cannot measure at 64 px" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_rows_are_finite_amortised_exactly_and_enhance_off_matches_raw_render(data, model):
    scene = load_scene(data / "scene_a")
    argv = "--data x --sizes 32 --views 2,4 --budgets auto,0.5 --dtypes fp32 --opt-steps 5"
    argv += " --refine-steps 0,4"
    axes = points.parse_axes(parse(*argv.split()))
    pts = points.build_points(axes)
    rows = points.measure_scene(model, scene, pts, repeats=2, split="tiny")
    assert len(rows) == len(pts) * len(scene.target_indices)
    assert {r["kind"] for r in rows} == {"interpolation", "extrapolation"}
    for r in rows:
        for k in ("recon_s", "view_ms", "amortised_ms", "psnr", "psnr_raw", "ssim", "lpips"):
            assert math.isfinite(r[k]), (r["point"], k)
        assert r["recon_s"] > 0 and r["view_ms"] > 0 and r["gaussians"] > 0
        assert r["amortised_ms"] == r["recon_s"] * 1e3 / r["n_targets"] + r["view_ms"]
        assert r["n_targets"] == 4
        once = r["method"].startswith(("opt-", "refine-"))
        assert r["recon_repeats"] == (1 if once else 2) and r["recon_timed_once"] == once
    # enhancement off: the score is the raw render's, reproduced here independently (its
    # colour favouring the input MORI picks, prosplat.pipeline.enhance.render_favouring)
    from prosplat.improve.mori import select_reference
    from prosplat.pipeline.enhance import OTHER_VIEWS_OPACITY, render_favouring, view_weights

    for label, views, budget in (("enh off", 4, None), ("2 views, enh off", 2, None)):
        idx = pick_inputs(scene, views)
        cams = [scene.cameras[i] for i in idx]
        near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
        out = model.reconstruct(
            scene.images[idx], cams, near, far, budget="all", generator_height=0
        )
        depths = out.depths  # [V,H,W]
        view_index = torch.arange(views).repeat_interleave(depths[0].numel())
        g = prune_gaussians(out.gaussians, view_index, depths, cams, budget=budget)[0]
        for r in (r for r in rows if r["point"] == label):
            cam = scene.cameras[r["target"]]
            j = select_reference(cam, cams)
            w = view_weights(cam, cams, j, OTHER_VIEWS_OPACITY)
            rgb = render_favouring(g, cam, w).rgb.clamp(0, 1)  # [3,H,W]
            expected = float(psnr(rgb, scene.images[r["target"]]))
            assert r["psnr"] == pytest.approx(expected, abs=1e-4) and r["gaussians"] == len(g)
            assert r["psnr_raw"] == r["psnr"] and r["dtype"] == "-"
    # refinement starts from the pipeline's pruned Gaussians (reconstruct: its budget
    # keeps the same ones with the scene-wide depth factor and without) and keeps their count
    p = next(p for p in pts if p.label == "refine 4")
    idx = pick_inputs(scene, p.views)
    near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
    imgs, cams = resize_views(scene.images[idx], [scene.cameras[i] for i in idx], p.size)
    start = model.reconstruct(imgs, cams, near, far, budget=p.budget).gaussians
    assert {r["gaussians"] for r in rows if r["point"] == "refine 4"} == {len(start)}
    enhanced = [r for r in rows if r["point"] == "base"]
    assert any(r["psnr"] != r["psnr_raw"] for r in enhanced)  # the improver changed something
    summary = pareto.summarise(rows)
    assert len(summary) == 2 * len(pts) and any(s["front"] for s in summary)
    assert all(s["x_base"] == 1.0 for s in summary if s["point"] == "base")


def test_run_writes_table_json_plot_and_never_clobbers(data, model, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(ProSplat, "from_pretrained", classmethod(lambda cls, *a, **k: model))
    out = tmp_path / "points"
    argv = ["--data", str(data), "--out", str(out)]
    argv += "--sizes 32 --views 2,4 --budgets auto --dtypes fp32 --repeats 2 --opt-steps 5".split()
    argv += ["--refine-steps", ""]
    assert points.run(parse(*argv)) == 0
    printed = capsys.readouterr().out
    assert "### interpolation targets" in printed and "### extrapolation targets" in printed
    saved = json.loads((out / "points.json").read_text())
    assert saved["meta"]["repeats"] == 2 and len(saved["rows"]) == 4 * len(saved["meta"]["points"])
    md = (out / "points.md").read_text()
    assert "| tiny | base | 32 | 4 | auto | on | fp32 |" in md and "| tiny | opt-5 |" in md
    # the ladder's reference rows at the base point, scored by the ladder's own code
    for label in ("flat colour", "MORI paste", "true depth"):
        assert f"| tiny | {label} | 32 | 4 | - | off |" in md
    scene = load_scene(data / "scene_a")
    ref = {
        (r["point"], r["target"]): r["psnr"] for r in saved["rows"] if r["family"] == "reference"
    }
    from prosplat.eval.generator import reference_scores

    mine = reference_scores(scene, pick_inputs(scene, 4), ["flat", "paste", "true-depth"])
    for s, t in zip(mine, scene.target_indices * 3):
        assert ref[s.method, t] == pytest.approx(s.psnr, abs=1e-6)
    assert points.run(parse(*argv, "--references", "flat,nope")) == 2
    assert "not among" in capsys.readouterr().err
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = (out / "points.json").read_bytes()
    assert points.run(parse(*argv)) == 0
    assert (out / "points.json").read_bytes() == before
    assert {p.name for p in (tmp_path / "points-2").iterdir()} == {
        "points.json",
        "points.md",
        "pareto.png",
    }
