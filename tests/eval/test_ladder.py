"""The evaluation ladder: intervals, the trivial rows against hand-computed images, the
true-depth upper bound and the valid regions on analytic geometry, and the command end to
end on a tiny synthetic scene folder (no Blender)."""

from __future__ import annotations

import json
import math

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat.cli import main
from prosplat.core.camera import Camera
from prosplat.data import load_scene, overlap_matrix
from prosplat.data.rigs import pick_inputs
from prosplat.eval.demo_scene import orbit_cameras, raycast, texture
from prosplat.eval.ladder import (
    REGISTRY,
    LadderContext,
    SceneInputs,
    SkipRung,
    bootstrap_ci,
    build_rungs,
    chosen_overlap,
    flat_image,
    overlap_bin,
    paste_image,
    true_depth_gaussians,
    valid_mask,
)
from prosplat.eval.ladder.cli import DEFAULT_ROWS
from prosplat.metrics import psnr
from prosplat.render import render

# ---- intervals ------------------------------------------------------------------------------


def test_bootstrap_interval_contains_the_mean_and_is_seeded():
    x = torch.randn(60, generator=torch.Generator().manual_seed(1)).tolist()
    ci = bootstrap_ci(x, seed=3)
    assert ci.n == 60 and ci.mean == pytest.approx(sum(x) / 60)
    assert ci.lo < ci.mean < ci.hi
    assert bootstrap_ci(x, seed=3) == ci  # same seed, same interval
    assert bootstrap_ci(x, seed=4) != ci  # another seed resamples differently
    # about ±1.96 σ/√n for a normal sample (σ = 1): a wrong percentile or a std instead of a
    # standard error would miss this by far
    assert ci.hi - ci.lo == pytest.approx(2 * 1.96 / math.sqrt(60), rel=0.3)


def test_bootstrap_interval_shrinks_with_n_and_ignores_nan():
    gen = torch.Generator().manual_seed(0)
    small = bootstrap_ci(torch.rand(25, generator=gen).tolist())
    large = bootstrap_ci(torch.rand(400, generator=gen).tolist())
    assert (large.hi - large.lo) < 0.5 * (small.hi - small.lo)  # ~ 1/√16 = 1/4
    ci = bootstrap_ci([1.0, float("nan"), 3.0])
    assert ci.n == 2 and ci.mean == 2.0 and 1.0 <= ci.lo <= ci.hi <= 3.0
    assert bootstrap_ci([float("nan")]).n == 0 and bootstrap_ci([]).fmt() == "–"
    one = bootstrap_ci([5.0])
    assert (one.lo, one.mean, one.hi) == (5.0, 5.0, 5.0)


def test_cluster_bootstrap_resamples_whole_clusters():
    # two clusters of identical values: resampling targets gives a narrow interval, resampling
    # the two clusters can only give the means 0, 0.5 or 1
    values = [0.0] * 50 + [1.0] * 50
    by_target = bootstrap_ci(values)
    by_scene = bootstrap_ci(values, clusters=["a"] * 50 + ["b"] * 50)
    assert by_target.hi - by_target.lo < 0.25
    assert (by_scene.lo, by_scene.hi) == (0.0, 1.0)
    with pytest.raises(ValueError, match="cluster labels"):
        bootstrap_ci(values, clusters=["a"])


def test_overlap_bins():
    assert [overlap_bin(v) for v in (0.0, 0.19, 0.2, 0.45, 0.6, 0.99)] == [
        "<0.2", "<0.2", "0.2-0.4", "0.4-0.6", ">=0.6", ">=0.6",
    ]  # fmt: skip
    assert overlap_bin(float("nan")) == "unknown"


# ---- the trivial rows ----------------------------------------------------------------------


def _rig(n: int = 3, size: int = 32) -> list[Camera]:
    return orbit_cameras(n, size, size)


def test_flat_is_the_mean_input_colour():
    images = torch.zeros(2, 3, 4, 4)
    images[0, 0] = 0.2
    images[1, 0] = 0.6
    images[0, 2, :2] = 1.0  # a quarter of all pixels of the blue channel
    out = flat_image(images, 5, 7)
    assert out.shape == (3, 5, 7)
    torch.testing.assert_close(out[:, 0, 0], torch.tensor([0.4, 0.0, 0.25]))
    assert (out == out[:, :1, :1]).all()
    # the registered rung gives the same image
    rung = build_rungs(["flat"], LadderContext())[0]
    inputs = SceneInputs(images, _rig(2, 4), None, 0.5, 10.0)
    cam = _rig(3, 4)[1].resized(7, 5)
    torch.testing.assert_close(rung.view(rung.reconstruct(inputs), cam, inputs).image, out)


def test_paste_is_the_input_mori_picks():
    cams = _rig(3)
    images = torch.stack([torch.full((3, 32, 32), v) for v in (0.1, 0.5, 0.9)])
    inputs = SceneInputs(images, cams, None, 0.5, 10.0)
    for j, cam in enumerate(cams):  # a target at an input camera: MORI picks that input
        image, picked = paste_image(cam, inputs)
        assert picked == j and torch.equal(image, images[j])
    # a target between inputs 1 and 2 but nearer 2, looking the same way as the rig
    c1, c2 = cams[1].center, cams[2].center
    w2c = cams[2].world_to_cam.clone()
    w2c[:3, 3] = -cams[2].R @ (0.3 * c1 + 0.7 * c2)
    target = Camera(cams[2].K, w2c, 32, 32)
    assert paste_image(target, inputs)[1] == 2
    # another size: the reference is resampled to the target's (a constant image stays so)
    image, _ = paste_image(cams[0].resized(16, 8), inputs)
    assert image.shape == (3, 8, 16) and torch.allclose(image, torch.tensor(0.1))


def test_registry_skips_rows_that_cannot_run(capsys):
    messages = []
    rungs = build_rungs(["flat", "optimize", "depthsplat"], LadderContext(), log=messages.append)
    assert [r.name for r in rungs] == ["flat colour"]
    assert any("--opt-steps" in m for m in messages) and any("--depthsplat" in m for m in messages)
    with pytest.raises(ValueError, match="unknown ladder rows"):
        build_rungs(["flat", "nope"], LadderContext())
    assert list(REGISTRY)[:2] == ["flat", "paste"]  # the table's order: bottom first
    rows = build_rungs(["optimize"], LadderContext({"opt_steps": [3, 7]}))
    assert [r.name for r in rows] == [
        "3DGS opt 3", "3DGS opt 3 filled", "3DGS opt 7", "3DGS opt 7 filled"
    ]  # fmt: skip
    assert [r.shares for r in rows] == ["3DGS opt 3"] * 2 + ["3DGS opt 7"] * 2  # one fit each
    assert SkipRung.__doc__


# ---- true depth and valid regions, on analytic geometry -------------------------------------


def _analytic_views(cams: list[Camera], smooth: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Images [V,3,H,W] and exact z-depths [V,H,W] of the demo scene's spheres, wall and floor.

    The images are the procedural texture at each pixel's surface point (hard checker edges,
    point-sampled), or with ``smooth`` a slowly varying colour of the point, as a
    band-limited render looks (a Gaussian splat cannot reproduce aliased pixel edges)."""
    images, depths = [], []
    for cam in cams:
        z, points, ident = raycast(cam)
        if smooth:
            x, y, zz = points.unbind(-1)
            rgb = torch.stack([0.5 + 0.3 * torch.sin(1.5 * x), 0.5 + 0.3 * torch.cos(2 * y + zz),
                               0.4 + 0.1 * ident.double()], dim=-1)  # fmt: skip
        else:
            rgb = texture(points, ident)
        images.append(rgb.permute(2, 0, 1).float())
        depths.append(z.float())
    return torch.stack(images), torch.stack(depths)


def test_true_depth_gaussians_sit_on_the_surface_and_rerender_an_input():
    cams = orbit_cameras(4, 48, 48)
    images, depths = _analytic_views(cams, smooth=True)
    ins = [0, 2, 3]
    g = true_depth_gaussians(images[ins], depths[ins], [cams[i] for i in ins])
    assert len(g) == 3 * 48 * 48
    surface = raycast(cams[0])[1].reshape(-1, 3).float()  # [HW,3] the first input's points
    torch.testing.assert_close(g.means[: 48 * 48], surface, atol=1e-4, rtol=1e-5)
    # the input itself, from its own pixels: nearly exact (what is left is the splats'
    # half-pixel spill over silhouettes, 30 dB; other inputs' splats spill there too)
    own = true_depth_gaussians(images[:1], depths[:1], cams[:1])
    assert float(psnr(render(own, cams[0]).rgb.clamp(0, 1), images[0])) > 30.0
    assert float(psnr(render(g, cams[0]).rgb.clamp(0, 1), images[0])) > 24.0
    # a held-out view: its colours agree, and its rendered depth is Blender's where the inputs
    # see the surface (median: splats mix depths over silhouettes, and front-to-back blending
    # leans ~1 % towards the nearer of overlapping splats); 10 % wrong input depth
    # shows up as a ~10 % error
    mask = valid_mask(cams[1], depths[1], [cams[i] for i in ins], depths[ins])
    out = render(g, cams[1])
    assert float(psnr(out.rgb.clamp(0, 1), images[1], mask)) > 24.0

    def median_rel(d: torch.Tensor) -> float:
        return float(((d - depths[1]).abs() / depths[1])[mask].median())

    assert median_rel(out.depth) < 0.02
    wrong = true_depth_gaussians(images[ins], 1.1 * depths[ins], [cams[i] for i in ins])
    assert median_rel(render(wrong, cams[1]).depth) > 0.05


def test_warp_paste_puts_the_reference_where_the_depth_says():
    """The warp-paste rung with Gaussians at the true depth: on a held-out view it is close to
    Blender's image where the reference sees, and far better than pasting that reference."""
    from prosplat.eval.ladder.rungs import warp_paste_view

    cams = orbit_cameras(4, 48, 48)
    images, depths = _analytic_views(cams, smooth=True)
    ins = [0, 2, 3]
    inp = SceneInputs(images[ins], [cams[i] for i in ins], depths[ins], 1.0, 20.0)
    g = true_depth_gaussians(inp.images, inp.depths, inp.cameras)
    view = warp_paste_view(g, cams[1], inp)
    assert view.info["warp_valid"] > 0.5
    pasted, j = paste_image(cams[1], inp)
    assert view.info["reference"] == j
    raw = render(g, cams[1]).rgb
    warped = (view.image - raw).abs().amax(0) > 1e-6  # [H,W] where the warp replaced the render
    assert warped.float().mean() > 0.4
    err = (view.image - images[1]).abs()[:, warped].mean()
    # the reference's own pixels, put where they belong (measured 0.011; the rendered depth
    # blurs over silhouettes); the reference pasted is 0.049 off there, the splats 0.018
    assert err < 0.015
    assert (pasted - images[1]).abs()[:, warped].mean() > 3 * err
    assert (raw - images[1]).abs()[:, warped].mean() > 1.3 * err


def test_true_depth_sky_pixels_go_far_behind_or_are_skipped():
    cams = orbit_cameras(2, 16, 16)
    images, depths = _analytic_views(cams)
    depths[:, :4] = 0  # the top rows are sky
    surface = true_depth_gaussians(images, depths, cams, part="surface")
    sky = true_depth_gaussians(images, depths, cams, part="sky")
    everything = true_depth_gaussians(images, depths, cams)
    assert (len(surface), len(sky), len(everything)) == (2 * 12 * 16, 2 * 4 * 16, 2 * 16 * 16)
    z = cams[0].world_to_camera(sky.means[:16].double())[:, 2]  # first row of view 0
    assert torch.allclose(z, torch.tensor(20.0 * float(depths.max()), dtype=z.dtype), rtol=1e-4)
    with pytest.raises(ValueError, match="part must be"):
        true_depth_gaussians(images, depths, cams, part="clouds")
    # the rung renders the sky behind the surfaces but scores the surfaces' depth only
    rung = build_rungs(["true-depth"], LadderContext({"improve": False}))[0]
    inputs = SceneInputs(images, cams, depths, 0.5, 10.0)
    view = rung.view(rung.reconstruct(inputs), cams[0], inputs)
    assert float(psnr(view.image.clamp(0, 1), images[0])) > 15.0  # the sky rows are drawn
    assert float(view.depth[:4].max()) < float(depths.max())  # no 20x-far depth leaks in
    whole = render(everything, cams[0])
    torch.testing.assert_close(view.image, whole.rgb, atol=0.05, rtol=0)


def _wall_camera(x: float, size: int = 32) -> Camera:
    """Looking down +z from (x, 0, 0), 90° field of view; the wall z = 3 fills its view."""
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[0, 3] = -x
    return Camera.from_intrinsics(size / 2, size / 2, size / 2, size / 2, size, size, w2c)


def test_valid_mask_is_all_true_for_a_target_at_an_input():
    cams = orbit_cameras(3, 24, 24)
    _, depths = _analytic_views(cams)
    depths[1, :3, :5] = 0  # some sky too: seen by the same camera
    assert valid_mask(cams[1], depths[1], cams, depths).all()
    assert valid_mask(cams[1], depths[1], [cams[1]], depths[1:2]).all()


def test_valid_mask_excludes_what_no_input_sees():
    size = 32
    inp, tgt = _wall_camera(0.0, size), _wall_camera(2.0, size)
    wall = torch.full((1, size, size), 3.0)
    # the input sees the wall for x in [-3, 3]; the target's column c sees x = 2 + (c + 0.5 - 16)
    # * 3 / 16, beyond 3 from column 21 on (x = 3.03): those columns are unseen
    mask = valid_mask(tgt, wall[0], [inp], wall)
    assert mask[:, :21].all() and not mask[:, 21:].any()
    # an occluder in front of the input (depth 1 in its middle columns) hides the wall behind
    occluded = wall.clone()
    occluded[0, :, 12:20] = 1.0  # input columns 12-19 see the occluder, not the wall
    mask2 = valid_mask(tgt, wall[0], [inp], occluded)
    # target column c lands in input column floor(c + 0.5 + 32 / 3) = c + 11: columns 1-8
    hidden = mask & ~mask2
    assert hidden[:, 1:9].all() and not hidden[:, :1].any() and not hidden[:, 9:].any()
    # a second input that sees the hidden part restores it
    other = _wall_camera(1.0, size)
    assert valid_mask(tgt, wall[0], [inp, other], torch.cat([occluded, wall]))[:, 1:9].all()


def test_chosen_overlap_averages_the_recorded_pairs(tmp_path):
    folder = tmp_path / "s"
    write_synthetic_scene(folder, size=16, n_views=6)
    scene = load_scene(folder)
    ins = scene.input_indices  # 0, 2, 4
    scene.meta["input_overlap"] = [[1, 0.2, 0.4], [0.2, 1, 0.6], [0.4, 0.6, 1]]
    assert chosen_overlap(scene, ins) == pytest.approx(0.4)
    assert chosen_overlap(scene, [0, 4]) == pytest.approx(0.4)
    assert chosen_overlap(scene, [2, 4]) == pytest.approx(0.6)
    del scene.meta["input_overlap"]
    assert math.isnan(chosen_overlap(scene, ins))


# ---- the command ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A dataset of one 64 px scene (4 inputs, 4 targets, one extrapolation) with its
    recorded input overlap, as the renderer writes it."""
    root = tmp_path_factory.mktemp("ladder") / "tiny"
    folder = root / "tabletop_000001"
    cams = write_synthetic_scene(folder, size=64, n_views=8)
    meta = json.loads((folder / "transforms.json").read_text())
    ins = [i for i, f in enumerate(meta["frames"]) if f["split"] == "input"]
    depths = [raycast(cams[i])[0].float() for i in ins]
    matrix = overlap_matrix([cams[i] for i in ins], depths)
    meta["input_overlap"] = matrix.tolist()
    meta["frames"][-1]["target_kind"] = "extrapolation"
    (folder / "transforms.json").write_text(json.dumps(meta))
    return root


def test_eval_ladder_end_to_end(data, tmp_path, capsys):
    out = tmp_path / "ladder"
    argv = ["eval", "ladder", "--data", str(data), "--sizes", "64", "--views", "3", "--out"]
    rows = ["--rows", "flat", "paste", "generator", "true-depth", "depthsplat"]
    with pytest.raises(SystemExit) as done:
        main(argv + [str(out)] + rows)
    assert done.value.code == 0
    printed = capsys.readouterr().out
    assert "skipping ladder row depthsplat" in printed and "| true depth |" in printed
    assert {p.name for p in out.iterdir()} == {
        "ladder.md",
        "ladder.csv",
        "ladder.json",
        "speed.png",
    }
    payload = json.loads((out / "ladder.json").read_text())
    scores = payload["scores"]
    names = ["flat colour", "MORI paste", "generator", "true depth", "true depth enhanced"]
    assert payload["meta"]["rows"] == names
    assert len(scores) == len(names) * 4
    scene = load_scene(data / "tabletop_000001")
    chosen = pick_inputs(scene, 3)
    flat = flat_image(scene.images[chosen], 64, 64)
    for s in scores:
        assert s["views"] == 3 and s["size"] == 64 and s["family"] == "tabletop"
        assert 0 < s["valid_fraction"] <= 1 and math.isfinite(s["psnr_valid"])
        assert (s["kind"] == "extrapolation") == (s["target"] == 7)
        assert math.isnan(s["abs_rel"]) == (s["rung"] in ("flat colour", "MORI paste"))
        if s["rung"] == "flat colour":
            t = s["target"]
            assert s["psnr"] == pytest.approx(float(psnr(flat, scene.images[t])), abs=1e-4)
    # the overlap of the chosen inputs, binned
    want = overlap_bin(chosen_overlap(scene, chosen))
    assert {s["overlap_bin"] for s in scores} == {want}
    # the summary: every grouping, intervals around the means
    summary = payload["summary"]
    assert {e["grouping"] for e in summary} == {
        "all",
        "kind",
        "family",
        "scene_type",
        "overlap_bin",
    }
    for e in summary:
        assert e["psnr_lo"] <= e["psnr"] <= e["psnr_hi"]
    # paired differences against the paste and the upper bound, on the same targets
    deltas = {(d["rung"], d["anchor"]): d for d in payload["deltas"]}
    by = {(s["rung"], s["target"]): s for s in scores}
    d = deltas["generator", "MORI paste"]
    diffs = [by["generator", t]["psnr"] - by["MORI paste", t]["psnr"] for t in (1, 3, 5, 7)]
    assert d["n"] == 4 and d["d_psnr"] == pytest.approx(sum(diffs) / 4)
    assert d["d_psnr_lo"] <= d["d_psnr"] <= d["d_psnr_hi"]
    assert ("flat colour", "true depth") in deltas and ("MORI paste", "MORI paste") not in deltas
    md = (out / "ladder.md").read_text()
    assert "#### paired differences" in md
    assert "prosplat eval ladder --data" in md and "#### by input overlap" in md
    assert (out / "ladder.csv").read_text().count("\n") == len(summary) + 1
    # a second run never replaces the first; --overwrite does
    before = (out / "ladder.json").stat().st_mtime_ns
    with pytest.raises(SystemExit):
        main(argv + [str(out), "--rows", "flat"])
    assert (tmp_path / "ladder-2" / "ladder.md").is_file()
    assert (out / "ladder.json").stat().st_mtime_ns == before
    with pytest.raises(SystemExit):
        main(argv + [str(out), "--rows", "flat", "--overwrite", "--resample", "scenes"])
    again = json.loads((out / "ladder.json").read_text())
    assert again["meta"]["rows"] == ["flat colour"]
    # one scene: resampling whole scenes can only redraw it, so every interval is a point
    assert all(e["psnr_lo"] == e["psnr_hi"] == pytest.approx(e["psnr"]) for e in again["summary"])
    assert "--resample scenes" in again["meta"]["command"]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--sizes", "16"], "below 32 px"),
        (["--sizes", "48", "--generator-size", "0"], "not multiples of 32"),
        (["--views", "7"], "outside 2-6"),
        (["--rows", "nope"], "unknown ladder rows"),
        (["--sizes", "128"], "cannot evaluate at 128 px"),
        (["--views", "5"], "has 4 input views, cannot evaluate 5"),
        (["--refine-steps", "0"], "--refine-steps: [0] must be >= 1"),
        (["--refine-seconds", "0"], "--refine-seconds: [0.0] must be > 0"),
        (["--distill-steps", "0"], "--distill-steps: [0] must be >= 1"),
        (["--splat-scales", "0"], "--splat-scales: [0.0] must be finite and > 0"),
        (["--max-splat-radius", "0"], "--max-splat-radius: [0.0] must be finite and > 0"),
        (["--generator-size", "48"], "--generator-size 48 is not a multiple of 32"),
    ],
)
def test_eval_ladder_bad_options_exit_2(data, tmp_path, capsys, extra, message):
    argv = ["eval", "ladder", "--data", str(data), "--out", str(tmp_path / "o"), "--views", "3"]
    with pytest.raises(SystemExit) as done:
        main(argv + ["--rows", "flat"] + extra)
    assert done.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_refine_rows_fit_the_inputs_from_a_smaller_generator_run(data):
    """``--generator-size 32`` on 64-px views: the generator matches on 32-px inputs (with
    ``--low-res-gaussians``, a quarter of the Gaussians, at 32 px; else one per 64-px pixel),
    its Gaussians render at 64 px, and the refine rows fit them to the 64-px inputs, keeping
    their count and getting closer to the inputs."""
    full = LadderContext({"generator_size": 32, "improve": False})
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    assert full.model.full_res_gaussians
    assert len(build_rungs(["generator"], full)[0].reconstruct(inp)) > 3 * 32 * 32
    ctx = LadderContext(
        {"generator_size": 32, "refine_steps": [30], "improve": False, "low_res_gaussians": True}
    )
    rungs = {r.name: r for r in build_rungs(["generator", "refine"], ctx)}
    assert list(rungs) == ["generator", "refine 30"]  # no improvement model: no enhanced row
    torch.manual_seed(0)
    g = rungs["generator"].reconstruct(inp)
    fitted = rungs["refine 30"].reconstruct(inp)
    assert 0 < len(fitted) == len(g) <= 3 * 32 * 32
    before = [float(psnr(render(g, c).rgb, im)) for c, im in zip(inp.cameras, inp.images)]
    after = [float(psnr(render(fitted, c).rgb, im)) for c, im in zip(inp.cameras, inp.images)]
    assert render(g, inp.cameras[0]).rgb.shape[-2:] == (64, 64)
    assert sum(after) / 3 > sum(before) / 3 + 0.5
    messages = []
    assert build_rungs(["refine"], LadderContext(), log=messages.append) == []
    assert "--refine-steps" in messages[0]


def test_consistent_rows_drop_only_from_the_generator_rows_gaussians(data):
    """The opt-in ``consistent`` rows draw the generator row's Gaussians less those the
    cross-view check drops: a subset of them, never more, and all of them with a margin no
    point can exceed; the row is not among the defaults."""
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    ctx = LadderContext({"generator_size": 32, "improve": False})
    rungs = {r.name: r for r in build_rungs(["generator", "consistent"], ctx)}
    assert list(rungs) == ["generator", "generator consistent", "generator filled consistent"]
    g = rungs["generator"].reconstruct(inp)
    kept = rungs["generator consistent"].reconstruct(inp)
    assert 0 < len(kept) <= len(g)
    assert torch.isin(kept.means[:, 0], g.means[:, 0]).all()
    lenient = LadderContext({"generator_size": 32, "improve": False, "consistency_tau": 0.999})
    assert len(build_rungs(["consistent"], lenient)[0].reconstruct(inp)) == len(g)
    assert "consistent" not in DEFAULT_ROWS


def test_distill_rows_fit_the_enhanced_targets_of_the_scene(data):
    """The distill rows see every target camera of the scene at once (run_rungs hands them
    over, never their images): one fit to the inputs and the enhanced targets, timed once
    as the reconstruction, whose renders move toward the enhanced views."""
    from prosplat.eval.ladder.run import run_rungs
    from prosplat.pipeline.enhance import render_view

    ctx = LadderContext({"generator_size": 32, "distill_steps": [40]})
    rungs = build_rungs(["generator", "distill"], ctx)
    assert [r.name for r in rungs] == ["generator", "distill 40"] and not rungs[1].warmup
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    cams = [scene.cameras[t] for t in scene.target_indices[:2]]
    out = list(run_rungs(rungs, inp, cams))
    assert [(r.name, k) for r, k, *_ in out] == [
        ("generator", 0), ("generator", 1), ("distill 40", 0), ("distill 40", 1)
    ]  # fmt: skip
    assert out[2][3] == out[3][3] > 0  # one reconstruction, timed once
    g = rungs[0].reconstruct(inp)
    for k, cam in enumerate(cams):
        enhanced = render_view(g, cam, inp.images, inp.cameras, ctx.model.improver).image
        raw, distilled = out[k][2].image, out[2 + k][2].image
        assert (distilled - enhanced).abs().mean() < (raw - enhanced).abs().mean()
    with pytest.raises(ValueError, match="no view cameras"):
        rungs[1].reconstruct(inp)  # outside run_rungs nobody named the cameras
    messages = []
    assert build_rungs(["distill"], LadderContext(), log=messages.append) == []
    assert "--distill-steps" in messages[0]


def test_refine_distill_rows_start_from_the_refined_gaussians(data, monkeypatch):
    """With --refine-steps too, ``refine R distill N`` distills the Gaussians refined R steps
    (the add-on's path when Refine Seconds and Distill Steps are both set), after the rows
    that start from the generator."""
    from prosplat.eval.ladder.run import run_rungs

    ctx = LadderContext({"generator_size": 32, "distill_steps": [5], "refine_steps": [3]})
    rungs = build_rungs(["distill"], ctx)
    assert [r.name for r in rungs] == ["distill 5", "refine 3 distill 5"]
    asked = []
    real = type(ctx.model).reconstruct

    def spy(self, *args, **kwargs):
        asked.append(kwargs.get("refine_steps"))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(type(ctx.model), "reconstruct", spy)
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    cams = [scene.cameras[scene.target_indices[0]]]
    out = list(run_rungs(rungs, inp, cams))
    assert [s for s in asked if s is not None] == [3]  # the plain row never refines
    plain, refined = out[0][2].image, out[1][2].image
    assert not torch.equal(plain, refined)


def test_demo_report_scores_the_same_ladder(data):
    """The demo's report table comes from the ladder code, with the demo's loaded model."""
    from types import SimpleNamespace

    from prosplat import ProSplat
    from prosplat.cli.demo import demo_ladder
    from prosplat.cli.demo_report import ladder_markdown

    scene = load_scene(data / "tabletop_000001")
    entries = demo_ladder(ProSplat.from_pretrained(), scene, 64, None)
    names = ["flat colour", "MORI paste", "generator", "enhanced", "generator filled"]
    filled = ["enhanced filled", "true depth filled", "true depth", "true depth enhanced"]
    assert [e["rung"] for e in entries] == names + filled
    assert all(e["n"] == 4 and e["psnr_lo"] <= e["psnr"] <= e["psnr_hi"] for e in entries)
    flat = flat_image(scene.images[scene.input_indices], 64, 64)
    want = sum(float(psnr(flat, scene.images[t])) for t in scene.target_indices) / 4
    assert entries[0]["psnr"] == pytest.approx(want, abs=1e-4)
    table = ladder_markdown(SimpleNamespace(ladder=entries))
    assert table.count("\n") == 2 + 9 and "| true depth filled |" in table


def test_find_scenes_skips_half_rendered_folders(tmp_path):
    from prosplat.data import find_scenes

    partial = tmp_path / ".open_000002.partial-123"
    partial.mkdir()
    (partial / "transforms.json").write_text("{}")
    (tmp_path / "room_000003").mkdir()
    (tmp_path / "room_000003" / "transforms.json").write_text("{}")
    assert [p.name for p in find_scenes(tmp_path)] == ["room_000003"]


def test_compare_improve_scores_several_stage2_models_on_one_reconstruction(data):
    """``--compare-improve LABEL=PATH`` adds an enhanced row per model beside each enhanced
    row, sharing the reconstruction: the shipped file again gives the same images."""
    from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS

    spec = f"again={DEFAULT_IMPROVE_WEIGHTS}"
    ctx = LadderContext({"compare_improve": [spec], "refine_steps": [2], "generator_size": 32})
    rungs = {r.name: r for r in build_rungs(["generator", "enhanced", "refine"], ctx)}
    assert list(rungs) == ["generator", "enhanced", "enhanced (again)", "refine 2",
                           "refine 2 enhanced", "refine 2 enhanced (again)"]  # fmt: skip
    assert rungs["enhanced (again)"].shares == rungs["generator"].shares == "generator"
    inp, g, cam = _generator_on_tabletop(data, rungs["generator"])
    a = rungs["enhanced"].view(g, cam, inp).image
    b = rungs["enhanced (again)"].view(g, cam, inp).image
    assert torch.allclose(a, b) and not torch.allclose(
        a, rungs["generator"].view(g, cam, inp).image
    )
    with pytest.raises(ValueError, match="LABEL=PATH"):
        build_rungs(["enhanced"], LadderContext({"compare_improve": ["nolabel"]}))


def test_fill_rows_complete_the_generator_render_and_the_enhanced_view(data):
    """``--rows fill``: ``generator filled`` is the generator's render composited over the
    pull-push fill of its holes, ``enhanced filled`` stage 2's view blended with that fill by
    the render's alpha; both share the generator's reconstruction and are scored closer to
    the target than black holes where the render leaves any."""
    from types import SimpleNamespace

    from prosplat.improve.mori import select_reference
    from prosplat.pipeline.enhance import (
        MAX_SPLAT_RADIUS,
        OTHER_VIEWS_OPACITY,
        oversized_splats,
        render_favouring,
        view_weights,
    )
    from prosplat.render.hole_fill import fill_colour, fill_holes

    rungs = {r.name: r for r in build_rungs(["generator", "enhanced", "fill"], LadderContext({}))}
    assert list(rungs) == [
        "generator", "enhanced", "generator filled", "enhanced filled", "true depth filled",
    ]  # fmt: skip
    assert rungs["generator filled"].shares == rungs["enhanced filled"].shares == "generator"
    assert rungs["true depth filled"].shares == "true depth"
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    g = rungs["generator"].reconstruct(inp)
    t = scene.target_indices[0]
    target = scene.cameras[t]
    wide = Camera(target.K * torch.tensor([[0.3], [0.3], [1.0]]), target.world_to_cam,
                  target.width, target.height)  # sees past what the inputs saw: holes  # fmt: skip
    for cam in (target, wide):
        # filled and enhanced views leave out the oversized splats (prosplat.pipeline.enhance)
        # and their colour favours the input MORI picks (prosplat.pipeline.enhance.render_favouring)
        kept = g[~oversized_splats(g, cam, MAX_SPLAT_RADIUS)]
        assert kept.views is not None
        j = select_reference(cam, inp.cameras)
        raw = render_favouring(kept, cam, view_weights(cam, inp.cameras, j, OTHER_VIEWS_OPACITY))
        raw = SimpleNamespace(image=raw.rgb, alpha=raw.alpha)
        enh = rungs["enhanced"].view(g, cam, inp).image
        filled = rungs["generator filled"].view(g, cam, inp).image
        both = rungs["enhanced filled"].view(g, cam, inp).image
        assert torch.allclose(filled, fill_holes(raw.image, raw.alpha), atol=1e-6)
        fill = fill_colour(raw.image, raw.alpha)
        assert torch.allclose(both, raw.alpha * enh + (1 - raw.alpha) * fill, atol=1e-5)
    hole = raw.alpha < 0.01  # the wide view's
    assert 0.05 < float(hole.float().mean()) < 0.95
    assert (raw.image[:, hole] <= 0.01).all()  # (nearly) black on its own
    drawn = raw.alpha > 0  # the fill is an alpha-weighted mean of these pixels' own colours
    seen = raw.image[:, drawn] / raw.alpha[drawn]
    inside = (filled[:, hole] >= seen.min(1, keepdim=True).values - 1e-5) & (
        filled[:, hole] <= seen.max(1, keepdim=True).values + 1e-5
    )
    assert inside.all() and filled[:, hole].sum(0).gt(0.05).float().mean() > 0.9
    # the upper bound with the same fill: the true-depth render, only lighter where it is open
    truth = {r.name: r for r in build_rungs(["true-depth"], LadderContext({"improve": False}))}
    inp = SceneInputs(inp.images, inp.cameras, scene.depths[idx], inp.near, inp.far)
    state = truth["true depth"].reconstruct(inp)
    bare = truth["true depth"].view(state, wide, inp)
    full = rungs["true depth filled"].view(state, wide, inp).image
    assert (full >= bare.image - 1e-6).all() and not torch.allclose(full, bare.image)
    covered = bare.alpha > 0.999
    assert torch.allclose(full[:, covered], bare.image[:, covered], atol=2e-3)
    # without an improvement model the raw rows alone
    only = build_rungs(["fill"], LadderContext({"improve": False}))
    assert [r.name for r in only] == ["generator filled", "true depth filled"]


def _generator_on_tabletop(data, generator_rung):
    """The tabletop fixture's 3 inputs, the ``generator`` row's Gaussians of them, and the
    scene's first target camera."""
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    return inp, generator_rung.reconstruct(inp), scene.cameras[scene.target_indices[0]]


def test_splat_rows_draw_the_generator_gaussians_smaller_in_filled_and_enhanced_views(data):
    """``--rows splat --splat-scales S``: the same reconstruction as the ``generator`` row,
    its Gaussians' scales multiplied by S before the filled and the enhanced views are made
    (what ``render_view(..., splat_scale=S)`` returns); without a scale the rows skip."""
    from prosplat.pipeline.enhance import render_view

    messages = []
    assert build_rungs(["splat"], LadderContext({}), log=messages.append) == []
    assert any("--splat-scales" in m for m in messages)
    ctx = LadderContext({"splat_scales": [0.5]})
    rungs = {r.name: r for r in build_rungs(["generator", "splat"], ctx)}
    assert list(rungs) == [
        "generator", "generator filled ×0.5", "enhanced ×0.5", "enhanced filled ×0.5",
    ]  # fmt: skip
    assert {r.shares for r in rungs.values()} == {"generator"}
    inp, g, cam = _generator_on_tabletop(data, rungs["generator"])
    small = render(g.with_scale_factor(0.5), cam)
    filled = rungs["generator filled ×0.5"].view(g, cam, inp)
    assert torch.equal(filled.alpha, small.alpha) and torch.equal(filled.depth, small.depth)
    expected = render_view(g, cam, inp.images, inp.cameras, fill_holes=True, splat_scale=0.5)
    assert torch.equal(filled.image, expected.image)
    enh = rungs["enhanced ×0.5"].view(g, cam, inp).image
    again = render_view(g, cam, inp.images, inp.cameras, ctx.improver("splat"), splat_scale=0.5)
    assert torch.allclose(enh, again.image)
    assert not torch.allclose(enh, rungs["generator"].view(g, cam, inp).image)


def test_cull_rows_leave_out_the_splats_a_target_sees_too_wide(data):
    """``--rows cull --max-splat-radius R``: the same reconstruction as the ``generator`` row,
    drawn without the splats the target sees wider than R of its shorter side (what
    ``render_view(..., max_splat_radius=R)`` returns, filled and enhanced); without a radius
    the rows skip."""
    from prosplat.pipeline.enhance import oversized_splats, render_view

    messages = []
    assert build_rungs(["cull"], LadderContext({}), log=messages.append) == []
    assert any("--max-splat-radius" in m for m in messages)
    ctx = LadderContext({"max_splat_radius": [0.02]})
    rungs = {r.name: r for r in build_rungs(["generator", "cull"], ctx)}
    assert list(rungs) == ["generator", "generator filled ≤0.02", "enhanced ≤0.02"]
    assert {r.shares for r in rungs.values()} == {"generator"}
    inp, g, cam = _generator_on_tabletop(data, rungs["generator"])
    wide = oversized_splats(g, cam, 0.02)
    assert 0 < int(wide.sum()) < len(g)  # a small radius: some are left out, not all
    kept = render(g[~wide], cam)
    filled = rungs["generator filled ≤0.02"].view(g, cam, inp)
    assert torch.equal(filled.alpha, kept.alpha) and torch.equal(filled.depth, kept.depth)
    expected = render_view(g, cam, inp.images, inp.cameras, fill_holes=True, max_splat_radius=0.02)
    assert torch.equal(filled.image, expected.image)
    enh = rungs["enhanced ≤0.02"].view(g, cam, inp).image
    again = render_view(
        g, cam, inp.images, inp.cameras, ctx.improver("cull"), max_splat_radius=0.02
    )
    assert torch.allclose(enh, again.image)


def test_no_depth_sweep_reaches_the_model_and_the_command_line():
    import argparse

    from prosplat.eval.ladder.cli import add_arguments, command

    assert LadderContext({"improve": False}).model.depth_sweep is not None  # the default
    assert LadderContext({"improve": False, "no_depth_sweep": True}).model.depth_sweep is None
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--data", "d", "--no-depth-sweep"])
    assert "--no-depth-sweep" in command(args).split()
    assert "--no-depth-sweep" not in command(parser.parse_args(["--data", "d"])).split()


def test_carry_rows_are_the_enhanced_rows_at_the_working_size_and_differ_above(data):
    """The opt-in ``carry`` rows (stage 2's change carried onto the render on black, the
    way before) pair with the enhanced rows: the same image at the model's working size or
    below, another one above it; not among the defaults."""
    scene = load_scene(data / "tabletop_000001")
    idx = pick_inputs(scene, 3)
    inp = SceneInputs(scene.images[idx], [scene.cameras[i] for i in idx], None, 0.5, 20.0)
    ctx = LadderContext({"generator_size": 32})
    rungs = {r.name: r for r in build_rungs(["enhanced", "fill", "carry"], ctx)}
    assert {"enhanced ⇡raw", "enhanced filled ⇡raw"} <= set(rungs)
    g = rungs["enhanced"].reconstruct(inp)
    cam = scene.cameras[scene.target_indices[0]]
    for ours, old in (("enhanced", "enhanced ⇡raw"), ("enhanced filled", "enhanced filled ⇡raw")):
        small = [rungs[n].view(g, cam, inp).image for n in (ours, old)]
        assert torch.equal(*small), ours
        working = ctx.model.improver.config.working_size
        big_cam = cam.resized(2 * working, 2 * working)
        big = [rungs[n].view(g, big_cam, inp).image for n in (ours, old)]
        assert not torch.equal(*big), ours
    assert "carry" not in DEFAULT_ROWS


def test_ladder_evaluates_at_a_height_the_generator_cannot_run_at(data, tmp_path):
    """``--sizes 48`` (as 540 for 960x540 scenes): the rows score 48-px views while the
    generator runs at the multiple of 32 below (its stride), its Gaussians drawn at 48; its
    depth is as right as at 64 px."""
    out = tmp_path / "o"
    argv = ["eval", "ladder", "--data", str(data), "--out", str(out), "--views", "3"]
    with pytest.raises(SystemExit) as done:
        main(argv + ["--sizes", "48", "64", "--rows", "generator"])
    assert done.value.code == 0
    scores = json.loads((out / "ladder.json").read_text())["scores"]
    by_size = {n: [s for s in scores if s["size"] == n] for n in (48, 64)}
    assert len(by_size[48]) == len(by_size[64]) == 4
    rel = {n: sum(s["abs_rel"] for s in v) / 4 for n, v in by_size.items()}
    assert rel[48] < 0.2 and abs(rel[48] - rel[64]) < 0.05
