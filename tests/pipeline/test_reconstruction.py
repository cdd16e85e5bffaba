"""``ProSplat.reconstruct``: one call, one :class:`prosplat.Reconstruction`, whatever the
options, holding the same Gaussians as the steps it is made of run one by one (the generator
and its depth sweep, the budget, refinement)."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from prosplat import Reconstruction, render
from prosplat.data.scene import resize_views
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
from prosplat.geometry.budget import prune_pixel_aligned
from prosplat.geometry.merge import MergeOptions, merge_flat
from prosplat.pipeline.refine import refine

NEAR, FAR = 1.0, 8.0


@pytest.fixture(scope="module")
def model(shipped_generator):
    return shipped_generator


@pytest.fixture(scope="module")
def scene():
    """Three 32-px input views of the analytic demo scene and one target camera between them."""
    cams = orbit_cameras(5, 32, 32, arc_deg=60.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)  # [5,3,32,32]
    inputs = [0, 2, 4]
    return images[inputs], [cams[i] for i in inputs], cams[1]


def assert_same_gaussians(a, b) -> None:
    ta, tb = a.tensors(), b.tensors()
    assert ta.keys() == tb.keys()
    for name, t in ta.items():
        assert torch.equal(t, tb[name]), name


def test_budget_all_is_every_gaussian_of_the_generator_in_view_major_order(model, scene):
    images, cams, _ = scene
    rec = model.reconstruct(images, cams, NEAR, FAR, budget="all", generator_height=0)
    assert isinstance(rec, Reconstruction)
    out = model.run_generator(images, cams, NEAR, FAR, sweep=True)  # the network + its sweep
    assert_same_gaussians(rec.gaussians, out.gaussians(0))
    assert torch.equal(rec.depths, out.depths[0])
    v, h, w = rec.depths.shape
    assert len(rec.gaussians) == v * h * w == 3 * 32 * 32
    assert torch.equal(rec.view_index, torch.arange(v).repeat_interleave(h * w))
    assert torch.equal(rec.gaussians.views, rec.view_index)
    assert rec.cameras == cams  # inputs at or below the trained size run as they are
    assert rec.prune_stats["input"] == rec.prune_stats["kept"] == len(rec.gaussians)
    assert rec.refine_stats is None
    assert set(rec.timings) == {"generator", "prune", "refine"}
    assert rec.timings["generator"] > 0 and rec.timings["prune"] == rec.timings["refine"] == 0


@pytest.fixture(scope="module")
def close_scene():
    """Three 32-px views 12 degrees apart: close enough for the budget's duplicate test
    (``DEDUP_ANGLE``), which ``scene``'s 30-degree steps are not."""
    cams = orbit_cameras(5, 32, 32, arc_deg=24.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)  # [5,3,32,32]
    return images[[0, 2, 4]], [cams[i] for i in (0, 2, 4)]


def test_the_default_budget_prunes_the_generators_gaussians(model, close_scene):
    images, cams = close_scene
    # the scene-wide depth factor is left out so the budget's input is the unpruned set
    full = model.reconstruct(images, cams, NEAR, FAR, budget="all", depth_scale=False)
    rec = model.reconstruct(images, cams, NEAR, FAR, depth_scale=False)
    g, keep, stats = prune_pixel_aligned(full.gaussians, full.depths, full.cameras)
    assert rec.prune_stats == stats and 0 < stats["kept"] < stats["input"]
    assert_same_gaussians(rec.gaussians, g)
    assert torch.equal(rec.view_index, full.view_index[keep])
    assert torch.equal(rec.gaussians.views, rec.view_index)
    assert torch.equal(rec.depths, full.depths) and rec.cameras == full.cameras
    v, h, w = rec.depths.shape
    assert v == len(rec.cameras) == 3 and (h, w) == (rec.cameras[0].height, rec.cameras[0].width)
    assert rec.depths_for(images) is rec.depths
    assert len(model.reconstruct(images, cams, NEAR, FAR, budget=500).gaussians) == 500
    assert len(model.reconstruct(images, cams, NEAR, FAR, budget=0.25).gaussians) == 768


def test_refinement_starts_from_the_budget_and_fills_stats_and_timings(model, scene):
    images, cams, _ = scene
    start = model.reconstruct(images, cams, NEAR, FAR)
    rec = model.reconstruct(images, cams, NEAR, FAR, refine_steps=3, seed=1)
    want = refine(
        start.gaussians, images, cams, steps=3, seed=1, depths=start.depths_for(images),
        view_index=start.view_index,
    )  # fmt: skip
    assert_same_gaussians(rec.gaussians, want.gaussians)
    assert rec.refine_stats.steps == 3 and rec.refine_stats.n_gaussians == len(start.gaussians)
    assert rec.prune_stats == start.prune_stats and torch.equal(rec.depths, start.depths)
    assert torch.equal(rec.view_index, start.view_index)
    assert rec.timings["refine"] >= rec.refine_stats.seconds > 0
    assert rec.timings["generator"] > 0 and rec.timings["prune"] > 0


def test_grad_and_budget_refusals(model, scene):
    images, cams, _ = scene
    rec = model.reconstruct(images, cams, NEAR, FAR, budget="all", grad=True, generator_height=0)
    assert rec.gaussians.means.requires_grad
    assert not model.reconstruct(
        images, cams, NEAR, FAR, budget="all"
    ).gaussians.means.requires_grad
    with pytest.raises(ValueError, match="budget='all'"):
        model.reconstruct(images, cams, NEAR, FAR, grad=True)
    with pytest.raises(ValueError, match="budget='all'"):
        model.reconstruct(images, cams, NEAR, FAR, budget="all", grad=True, refine_steps=2)
    with pytest.raises(ValueError, match="'all'"):
        model.reconstruct(images, cams, NEAR, FAR, budget="half")
    with pytest.raises(ValueError, match="seconds must be a finite number > 0"):
        model.reconstruct(images, cams, NEAR, FAR, refine_seconds=0)


def test_render_takes_a_reconstruction_and_knows_its_cameras(model, scene):
    images, cams, target = scene
    rec = model.reconstruct(images, cams, NEAR, FAR)
    given = model.render(rec.gaussians, target, images, cams, enhance=False, fill_holes=True)
    known = model.render(rec, target, images, enhance=False, fill_holes=True)
    assert torch.equal(known.image, given.image)
    # cameras at the generator's smaller size are brought to the images' size
    half = replace(rec, cameras=[c.resized(16, 16) for c in rec.cameras])
    again = model.render(half, target, images, enhance=False, fill_holes=True)
    assert torch.equal(again.image, given.image)
    with pytest.raises(TypeError, match="fill_hole"):
        model.render(rec, target, images, enhance=False, fill_hole=True)


def test_inputs_off_the_networks_stride_run_at_the_multiple_of_32_below(model):
    """72 x 100 inputs (neither side a multiple of 32) reconstruct, the generator at 64 x 96
    with cameras to match, as the evaluation at 540 px of a 960 x 540 scene needs; the
    depth is that of the same views resized by hand."""
    truth = pixel_aligned_gaussians(orbit_cameras(6, 100, 72, arc_deg=50.0))
    cams = orbit_cameras(4, 100, 72, arc_deg=40.0)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)  # [4,3,72,100]
    rec = model.reconstruct(images, cams, generator_height=0)
    assert rec.depths.shape == (4, 64, 96)
    assert (rec.cameras[0].width, rec.cameras[0].height) == (96, 64)
    small, small_cams = resize_views(images, cams, 64)
    by_hand = model.reconstruct(small, small_cams, generator_height=0)
    torch.testing.assert_close(rec.depths, by_hand.depths)


def test_merge_flat_runs_after_the_budget_and_keeps_the_reconstruction_consistent(model, scene):
    """With :attr:`ProSplat.merge_flat` the budget's survivors are merged in flat 2x2 blocks
    (:func:`prosplat.geometry.merge.merge_flat` on its mask); the view index follows, the
    stats count the merged-away Gaussians, refinement runs on the result; the options'
    default ``above_scale`` (1) leaves it off where the Gaussians come at the matching size
    (32-px inputs), so ``above_scale=0`` merges here."""
    images, cams, _ = scene
    options = MergeOptions(color_tol=0.1, depth_tol=0.05, above_scale=0)
    full = model.reconstruct(images, cams, NEAR, FAR, budget="all", depth_scale=False)
    plain = model.reconstruct(images, cams, NEAR, FAR, depth_scale=False)
    g, keep, stats = prune_pixel_aligned(full.gaussians, full.depths, full.cameras)
    assert plain.prune_stats == stats  # off by default
    want, want_index, counts = merge_flat(g, keep, full.depths, full.cameras, options)
    assert counts["blocks"] > 0
    default = model.merge_flat
    assert default is None  # opt-in
    try:
        model.merge_flat = options
        rec = model.reconstruct(images, cams, NEAR, FAR, depth_scale=False)
        assert_same_gaussians(rec.gaussians, want)
        assert torch.equal(rec.view_index, want_index)
        assert torch.equal(rec.gaussians.views, rec.view_index)
        assert rec.prune_stats == {**stats, "merged": counts["before"] - counts["after"],
                                   "kept": len(want)}  # fmt: skip
        assert torch.equal(rec.depths, plain.depths) and rec.cameras == plain.cameras
        refined = model.reconstruct(images, cams, NEAR, FAR, refine_steps=2)
        assert refined.refine_stats.n_gaussians == len(refined.gaussians) < stats["kept"]
        model.merge_flat = replace(options, above_scale=1.0)
        off = model.reconstruct(images, cams, NEAR, FAR, depth_scale=False)
        assert_same_gaussians(off.gaussians, plain.gaussians)
        assert off.prune_stats == plain.prune_stats
    finally:
        model.merge_flat = default


@pytest.mark.parametrize("budget", [None, "all"])
def test_cross_view_fades_what_other_inputs_saw_through(model, scene, budget):
    """With :attr:`ProSplat.cross_view` the Gaussians are checked against the other inputs'
    depth (:func:`prosplat.geometry.consistency.cross_view_check` on the reconstruction's own
    maps): those seen through fade by ``fade`` per view, the rest are untouched; ``fade=0``
    drops them and the view index follows; the stats count them. Off by default."""
    from prosplat.geometry.consistency import CrossViewOptions, cross_view_check

    images, cams, _ = scene
    plain = model.reconstruct(images, cams, NEAR, FAR, budget=budget, depth_scale=False)
    full = model.reconstruct(images, cams, NEAR, FAR, budget="all", depth_scale=False)
    assert model.cross_view is None  # opt-in
    check = cross_view_check(plain.depths, plain.cameras, 0.1, means=plain.gaussians.means,
                             view_index=plain.view_index)  # fmt: skip
    seen_through = check.contradictions > 0
    assert 0 < int(seen_through.sum()) < len(plain.gaussians)  # the check has work to do
    try:
        model.cross_view = CrossViewOptions(tau=0.1, fade=0.5)
        rec = model.reconstruct(images, cams, NEAR, FAR, budget=budget, depth_scale=False)
        assert len(rec.gaussians) == len(plain.gaussians)
        factor = 0.5 ** check.contradictions.to(plain.gaussians.opacities)
        torch.testing.assert_close(rec.gaussians.opacities, plain.gaussians.opacities * factor)
        assert torch.equal(rec.gaussians.means, plain.gaussians.means)
        assert rec.prune_stats["faded"] == int(seen_through.sum())
        model.cross_view = CrossViewOptions(tau=0.1, fade=0.0)
        dropped = model.reconstruct(images, cams, NEAR, FAR, budget=budget, depth_scale=False)
        assert torch.equal(dropped.gaussians.means, plain.gaussians.means[~seen_through])
        assert torch.equal(dropped.view_index, plain.view_index[~seen_through])
        assert torch.equal(dropped.gaussians.views, dropped.view_index)
        assert dropped.prune_stats["kept"] == len(dropped.gaussians)
        if budget is None:  # the merge after it works on the survivors' pixel mask
            g, keep, _ = prune_pixel_aligned(full.gaussians, full.depths, full.cameras)
            assert_same_gaussians(g, plain.gaussians)
            keep[torch.nonzero(keep).squeeze(1)[seen_through]] = False
            options = MergeOptions(color_tol=0.1, depth_tol=0.05, above_scale=0)
            want, want_index, _ = merge_flat(
                g[~seen_through], keep, plain.depths, plain.cameras, options
            )
            model.merge_flat = options
            both = model.reconstruct(images, cams, NEAR, FAR, depth_scale=False)
            assert_same_gaussians(both.gaussians, want)
            assert torch.equal(both.view_index, want_index)
    finally:
        model.cross_view = None
        model.merge_flat = None
