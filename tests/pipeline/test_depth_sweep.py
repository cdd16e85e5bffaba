"""prosplat.pipeline.depth_sweep: the generator's depth moved to where the input views match."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from prosplat import ProSplat, render
from prosplat.data import load_scene
from prosplat.eval.baselines.plane_sweep import gaussians_from_depths
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians, raycast
from prosplat.generator import GeneratorOutput
from prosplat.metrics import psnr
from prosplat.pipeline.depth_sweep import (
    DepthSweepOptions,
    scale_search,
    slide_along_rays,
    snap_output,
    sweep_depths,
)

SIZE = 32


@pytest.fixture(scope="module")
def views():
    """4 orbit views of the textured analytic scene: exact images and depths."""
    cams = orbit_cameras(4, SIZE, SIZE, arc_deg=40.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    depths = torch.stack([raycast(c)[0] for c in cams]).float()
    return cams, images, depths


@pytest.fixture(scope="module")
def blender_scene(tmp_path_factory):
    """A Blender tabletop at 64 px (Cycles), 4 inputs and 2 targets, with its Z-pass depth:
    real renders with exact depth, where matching across views must find the surface."""
    pytest.importorskip("bpy")
    out = tmp_path_factory.mktemp("sweep")
    cmd = [sys.executable, "-m", "scenes.render", "--name", "tabletop", "--seed", "7",
           "--out", str(out), "--size", "64", "--inputs", "4", "--targets", "2",
           "--samples", "16", "--denoise"]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    scene = load_scene(out / "tabletop_000007")
    idx = scene.input_indices
    return dict(
        cams=[scene.cameras[i] for i in idx],
        images=scene.images[idx],
        depths=scene.depths[idx],
        targets=[
            (scene.cameras[i], scene.images[i], scene.depths[i]) for i in scene.target_indices
        ],
    )


def wrong_depths(depths: torch.Tensor) -> torch.Tensor:
    """The truth off by a smooth factor per view, up to ±15 % (inside the default band)."""
    v, h, w = depths.shape
    ramp = torch.linspace(-1, 1, w)[None, None, :].expand(v, h, w)
    tilt = torch.tensor([0.12, -0.1, 0.08, -0.12])[:, None, None]
    return depths * torch.exp(tilt + 0.03 * ramp)


def abs_rel(pred, gt):
    """Median |pred − gt| / gt over the pixels with a surface."""
    m = (gt > 0) & torch.isfinite(gt)
    return float(((pred[m] - gt[m]).abs() / gt[m]).median())


def output_from_images(cams, images, depths) -> GeneratorOutput:
    """A GeneratorOutput (B = 1) with one Gaussian per pixel at ``depths [V,H,W]``: the
    pixel's colour, about a pixel wide, facing its camera (the plane-sweep baseline's
    layout, :func:`prosplat.eval.baselines.plane_sweep.gaussians_from_depths`)."""
    g = gaussians_from_depths(images, cams, depths, torch.ones_like(depths))
    return GeneratorOutput(
        g.means[None],
        g.quats[None],
        g.scales[None],
        g.opacities[None],
        g.sh[None],
        depths[None],
        torch.ones_like(depths)[None],
    )


@pytest.mark.blender
def test_the_sweep_finds_the_surface_the_views_agree_on(blender_scene):
    cams, images, depths = blender_scene["cams"], blender_scene["images"], blender_scene["depths"]
    start = wrong_depths(depths)
    before = abs_rel(start, depths)
    for options in (
        DepthSweepOptions(),  # the defaults: smoothed, where confident
        DepthSweepOptions(smooth=0.0, min_confidence=0.0),  # every pixel its own winner
    ):
        new, moved = sweep_depths(images, cams, start, options)
        assert new.shape == start.shape and bool(torch.isfinite(new).all())
        assert float(moved.float().mean()) > 0.2, options
        after = abs_rel(new, depths)
        assert after < 0.7 * before, (options, before, after)  # 0.105 -> 0.062-0.069
    # swept at half size (32 px: little to match), the correction upsampled to 64 px
    half, _ = sweep_depths(images, cams, start, DepthSweepOptions(max_height=32))
    assert half.shape == start.shape and abs_rel(half, depths) < 0.9 * before  # 0.090
    # the truth is a fixed point: what the views agree on stays where it is
    kept, _ = sweep_depths(images, cams, depths, DepthSweepOptions(smooth=0.03))
    assert abs_rel(kept, depths) < 0.02


def test_one_view_is_left_alone_and_two_by_default(views):
    cams, images, depths = views
    alone, moved = sweep_depths(images[:1], cams[:1], depths[:1])
    assert torch.equal(alone, depths[:1]) and not bool(moved.any())
    wrong = depths[:2] * 1.1
    two, moved = sweep_depths(images[:2], cams[:2], wrong)  # min_views = 3: not worth it
    assert torch.equal(two, wrong) and not bool(moved.any())
    two, moved = sweep_depths(images[:2], cams[:2], wrong, DepthSweepOptions(min_views=2))
    assert bool(moved.any()) and not torch.equal(two, wrong)


def test_sliding_along_rays_keeps_each_views_own_image(views):
    """A Gaussian scaled about its camera's centre projects to the same footprint: view 0's
    own Gaussians render view 0 as before, while the depths and means move by the ratio (a
    smooth one, as the sweep's: where neighbours swap order their blend changes)."""
    cams, images, depths = views
    out = output_from_images(cams[:1], images[:1], depths[:1])
    factor = torch.exp(0.15 + 0.05 * torch.linspace(-1, 1, SIZE))[None, None, :]
    moved = slide_along_rays(out, cams[:1], depths[:1] * factor)
    assert torch.allclose(moved.depths, depths[:1] * factor)
    before, after = render(out.gaussians(0), cams[0]), render(moved.gaussians(0), cams[0])
    # a few pixels where neighbours' blend order flips; with the footprint not kept (scales
    # left as they were) the mean change is 0.0073
    assert float((after.rgb - before.rgb).abs().mean()) < 4e-3
    ray_before = torch.nn.functional.normalize(out.means[0] - cams[0].center.float(), dim=1)
    ray_after = torch.nn.functional.normalize(moved.means[0] - cams[0].center.float(), dim=1)
    assert torch.allclose(ray_before, ray_after, atol=1e-5)


@pytest.mark.blender
def test_snapping_an_output_moves_its_gaussians_toward_the_truth(blender_scene):
    """Pixel-aligned Gaussians at wrong depths, coloured by the inputs' pixels: once snapped
    the surfaces the targets see lie nearer Blender's depth there, and the targets' colours
    do not get worse."""
    cams, images, depths = blender_scene["cams"], blender_scene["images"], blender_scene["depths"]
    out = output_from_images(cams, images, wrong_depths(depths))
    snapped = snap_output(out, images, cams, DepthSweepOptions(smooth=0.03, min_confidence=0.4))
    depth_err, colour = [], []  # per target: (before, after)
    for cam, gt, gt_depth in blender_scene["targets"]:
        r0, r1 = render(out.gaussians(0), cam), render(snapped.gaussians(0), cam)
        m = (r0.alpha > 0.5) & (r1.alpha > 0.5) & (gt_depth > 0)
        depth_err.append([abs_rel(r.depth[m], gt_depth[m]) for r in (r0, r1)])
        colour.append([float(psnr(r.rgb.clamp(0, 1), gt)) for r in (r0, r1)])
    (d0, d1), (p0, p1) = torch.tensor(depth_err).mean(0), torch.tensor(colour).mean(0)
    assert d1 < 0.85 * d0, depth_err  # 0.132 -> 0.105
    assert p1 > p0, colour


def test_the_pipeline_sweeps_when_asked(views):
    cams, images, _ = views
    model = ProSplat(trained_size=SIZE)
    plain = model.reconstruct(images, cams)
    model.depth_sweep = DepthSweepOptions()
    swept = model.reconstruct(images, cams)
    assert swept.depths.shape == plain.depths.shape
    assert not torch.equal(swept.depths, plain.depths)
    assert len(swept.view_index) == len(swept.gaussians)


def test_the_pipeline_scales_one_pass_views_and_refines_from_them(views, monkeypatch):
    """reconstruct applies the search's factor (here forced to 1.1), depth_scale=False
    leaves it out, and refinement starts from the scaled one-pass Gaussians: 0 steps is the
    one-pass scene."""
    import prosplat.pipeline.model as pipeline_model

    cams, images, _ = views
    model = ProSplat(trained_size=SIZE)
    model.depth_sweep = DepthSweepOptions()
    calls = []

    def forced(out, images, cameras, options=None, keep=None):
        calls.append(len(cameras))
        return 1.1, [(1.1, 0.0)]

    monkeypatch.setattr(pipeline_model, "scale_search", forced)  # the name the model calls
    plain = model.reconstruct(images, cams, depth_scale=False)
    assert calls == []
    scaled = model.reconstruct(images, cams)
    assert calls == [len(cams)]
    torch.testing.assert_close(scaled.depths, plain.depths * 1.1)
    assert len(scaled.gaussians) == len(plain.gaussians)  # the factor comes after the budget
    assert torch.equal(scaled.view_index, plain.view_index)
    refined = model.reconstruct(images, cams, refine_steps=0)
    assert calls == [len(cams)] * 2
    torch.testing.assert_close(refined.gaussians.means, scaled.gaussians.means)
    calls.clear()
    model.depth_sweep = DepthSweepOptions(scale_candidates=0)
    model.reconstruct(images, cams)
    assert calls == []


@pytest.mark.parametrize(
    "options, message",
    [
        (DepthSweepOptions(span=0.0), "span"),
        (DepthSweepOptions(candidates=2), "candidates"),
        (DepthSweepOptions(best_views=0), "best_views"),
        (DepthSweepOptions(min_confidence=1.0), "min_confidence"),
        (DepthSweepOptions(smooth=-0.1), "smooth"),
        (DepthSweepOptions(max_height=16), "max_height"),
        (DepthSweepOptions(min_views=1), "min_views"),
        (DepthSweepOptions(scale_span=0.0), "scale_span"),
        (DepthSweepOptions(scale_candidates=-1), "scale_candidates"),
        (DepthSweepOptions(scale_candidates=2.5), "scale_candidates"),
        (DepthSweepOptions(scale_height=8), "scale_height"),
    ],
)
def test_bad_options_raise_naming_the_field(views, options, message):
    cams, images, depths = views
    with pytest.raises(ValueError, match=message):
        sweep_depths(images, cams, depths, options)


@pytest.fixture(scope="module")
def views64():
    """The 4 orbit views at 64 px: at 32 px a pixel spans as much parallax as a 5 % depth
    change, and the views' renders cannot tell the truth from 5 % nearer."""
    cams = orbit_cameras(4, 64, 64, arc_deg=40.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    depths = torch.stack([raycast(c)[0] for c in cams]).float()
    return cams, images, depths


@pytest.mark.parametrize("error", [0.9, 1.0, 1.12])
def test_scale_search_undoes_a_scene_wide_depth_error(views64, error):
    """Every view's Gaussians at ``error`` x the true depth: the factor that re-renders the
    inputs best is the one that puts them back (within one 5 % step of the grid: a pixel of
    parallax at 64 px is a few per cent of depth), and the truth is left where it is."""
    import math

    cams, images, depths = views64
    out = output_from_images(cams, images, depths * error)
    factor, scored = scale_search(out, images, cams)
    assert len(scored) == DepthSweepOptions().scale_candidates
    assert min(scored, key=lambda fl: fl[1])[0] == factor
    assert abs(math.log(factor * error)) <= 0.05 + 1e-9, (error, factor, scored)
    if error == 1.0:
        assert factor == 1.0
    off, _ = scale_search(out, images, cams, DepthSweepOptions(scale_candidates=0))
    assert off == 1.0


def test_snap_output_applies_the_scene_wide_factor(views):
    """With the local sweep taking nothing (min_confidence just under 1), snap_output moves the
    depth by the search's factor alone; with ``scale_candidates=0`` it leaves it."""
    cams, images, depths = views
    from prosplat.geometry.budget import prune_pixel_aligned

    start = depths * 0.85
    out = output_from_images(cams, images, start)
    local_off = DepthSweepOptions(min_confidence=0.999)
    snapped = snap_output(out, images, cams, local_off)
    # scored as snap_output scores it: on the Gaussians the budget keeps
    _, keep, _ = prune_pixel_aligned(out.gaussians(0), out.depths[0], cams)
    factor, _ = scale_search(out, images, cams, local_off, keep=keep)
    assert factor > 1.05
    assert torch.allclose(snapped.depths[0], start * factor, rtol=1e-5)
    kept = snap_output(out, images, cams, DepthSweepOptions(min_confidence=0.999,
                                                             scale_candidates=0))  # fmt: skip
    assert torch.allclose(kept.depths[0], start, rtol=1e-6)


def test_mismatched_shapes_raise(views):
    cams, images, depths = views
    with pytest.raises(ValueError, match="depths must be"):
        sweep_depths(images, cams, depths[:, :10])
    with pytest.raises(ValueError, match="one camera per image"):
        sweep_depths(images, cams[:2], depths)


def test_on_by_default_for_prosplat_weights_and_switchable():
    import argparse

    from prosplat.cli.reconstruct import add_common_arguments, load_model

    assert ProSplat.from_pretrained(improve=False).depth_sweep == DepthSweepOptions()
    assert ProSplat.from_pretrained(improve=False, depth_sweep=False).depth_sweep is None
    narrow = DepthSweepOptions(span=0.1, candidates=9)
    assert ProSplat.from_pretrained(improve=False, depth_sweep=narrow).depth_sweep is narrow
    with pytest.raises(ValueError, match="depth_sweep must be"):
        ProSplat.from_pretrained(improve=False, depth_sweep="on")
    with pytest.raises(ValueError, match="span"):
        ProSplat.from_pretrained(improve=False, depth_sweep=DepthSweepOptions(span=-1.0))
    parser = argparse.ArgumentParser()
    add_common_arguments(parser)
    for flags, on in (([], True), (["--no-depth-sweep"], False)):
        args = parser.parse_args(["some/scene", "--out", "unused", *flags])
        args.improve = None
        assert (load_model(args).depth_sweep is not None) == on, flags
