"""prosplat.pipeline.distill: views fitted back into the Gaussians, and the consistency that buys."""

from __future__ import annotations

import pytest
import torch
from synthetic_scenes import orbit_scene_with_wrong_colours

from prosplat import render
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
from prosplat.eval.flicker import flicker
from prosplat.geometry.hole_gaussians import hole_gaussians
from prosplat.improve.config import ImproveConfig
from prosplat.improve.model import ImproveModel
from prosplat.metrics import psnr
from prosplat.pipeline.distill import distill, distill_enhanced, enhance_views, fits_inputs
from prosplat.pipeline.refine import refine

SIZE = 32
INPUTS = [0, 6]
VIEWS = [1, 2, 3, 4, 5]


@pytest.fixture(scope="module")
def scene():
    """7 orbit views of the analytic demo scene with exact images and depths; the start is
    the inputs' pixel-aligned Gaussians with their colours disturbed (right geometry, wrong
    colours), so only what a fit adds can make the in-between views right."""
    return orbit_scene_with_wrong_colours(7, SIZE, INPUTS, 0.2, arc_deg=60.0)


def _views_psnr(g, scene) -> float:
    with torch.no_grad():
        scores = [float(psnr(render(g, scene["cams"][i]).rgb, scene["images"][i])) for i in VIEWS]
    return sum(scores) / len(scores)


def test_distilling_right_views_makes_them_right(scene):
    """Given the true images at the view cameras, the distilled Gaussians show them better
    than the start and better than refining against the inputs alone for the same steps."""
    images, cams = scene["images"][INPUTS], [scene["cams"][i] for i in INPUTS]
    views, view_cams = scene["images"][VIEWS], [scene["cams"][i] for i in VIEWS]
    fitted = distill(scene["start"], images, cams, views, view_cams, steps=120).gaussians
    inputs_only = refine(scene["start"], images, cams, steps=120).gaussians
    start, ours, base = (
        _views_psnr(scene["start"], scene),
        _views_psnr(fitted, scene),
        _views_psnr(inputs_only, scene),
    )
    assert ours > start + 4.0 and ours > base + 2.0, (start, ours, base)
    seeded = hole_gaussians(scene["start"], torch.cat([images, views]), cams + view_cams)
    assert len(fitted) == len(seeded) > len(scene["start"])  # the views' holes were seeded


def test_seeded_holes_are_fitted_and_shown(scene):
    """The pixels the start leaves uncovered in a view get Gaussians, so the distilled views
    show what the views show there; without seeding (``seed_holes=False``) the count is the
    start's, the holes stay black and the views score lower."""
    images, cams = scene["images"][INPUTS], [scene["cams"][i] for i in INPUTS]
    views, view_cams = scene["images"][VIEWS], [scene["cams"][i] for i in VIEWS]
    runs = {
        seeded: distill(
            scene["start"], images, cams, views, view_cams, steps=60, seed_holes=seeded
        ).gaussians
        for seeded in (True, False)
    }
    assert len(runs[False]) == len(scene["start"]) < len(runs[True])
    with torch.no_grad():
        alpha = {
            k: min(float(render(g, c).alpha.min()) for c in view_cams) for k, g in runs.items()
        }
    assert alpha[False] < 0.2 and alpha[True] > 0.5, alpha
    assert _views_psnr(runs[True], scene) > _views_psnr(runs[False], scene) + 0.5


def test_distilled_frames_are_as_consistent_as_raw_renders(scene):
    """Views that disagree frame to frame (the truth plus independent noise per frame, as a
    per-view enhancement does) flicker; the Gaussians distilled from them cannot."""
    images, cams = scene["images"][INPUTS], [scene["cams"][i] for i in INPUTS]
    view_cams = [scene["cams"][i] for i in VIEWS]
    gen = torch.Generator().manual_seed(3)
    noisy = (scene["images"][VIEWS] + 0.15 * torch.randn(5, 3, SIZE, SIZE, generator=gen)).clamp(
        0, 1
    )
    depths = scene["depths"][VIEWS]
    fitted = distill(scene["start"], images, cams, noisy, view_cams, steps=120).gaussians
    with torch.no_grad():
        frames = torch.stack([render(fitted, c).rgb for c in view_cams])
        truth = torch.stack(
            [render(pixel_aligned_gaussians(scene["cams"]), c).rgb for c in view_cams]
        )
    noisy_f, ours_f, truth_f = (flicker(x, depths, view_cams) for x in (noisy, frames, truth))
    assert ours_f < 0.5 * noisy_f, (ours_f, noisy_f)
    assert ours_f < 1.2 * truth_f, (ours_f, truth_f)  # the stage-2 issue's bar, met


def test_fits_inputs_is_the_aspect_ratio_within_one_percent(scene):
    cam = scene["cams"][0]  # 32 x 32
    assert fits_inputs(cam, SIZE, SIZE) and fits_inputs(cam.resized(96, 96), SIZE, SIZE)
    assert fits_inputs(cam.resized(101, 100), SIZE, SIZE)  # 1 % off
    assert not fits_inputs(cam.resized(103, 100), SIZE, SIZE)
    assert not fits_inputs(cam.resized(64, 32), SIZE, SIZE)


def test_views_of_another_size_are_fitted_at_the_inputs_size(scene):
    images, cams = scene["images"][INPUTS], [scene["cams"][i] for i in INPUTS]
    big = [scene["cams"][i].resized(2 * SIZE, 2 * SIZE) for i in VIEWS[:2]]
    views = torch.nn.functional.interpolate(scene["images"][VIEWS[:2]], scale_factor=2.0)
    out = distill(scene["start"], images, cams, views, big, steps=4)
    assert out.stats.steps == 4
    wide = [scene["cams"][VIEWS[0]].resized(2 * SIZE, SIZE)]
    with pytest.raises(ValueError, match="aspect ratio"):
        distill(scene["start"], images, cams, torch.rand(1, 3, SIZE, 2 * SIZE), wide, steps=1)
    with pytest.raises(ValueError, match="one image per view camera"):
        distill(scene["start"], images, cams, views, big[:1], steps=1)
    with pytest.raises(ValueError, match="no view cameras"):
        distill(scene["start"], images, cams, views[:0], [], steps=1)


def test_distill_enhanced_runs_stage2_on_every_view(scene):
    """End to end with a (tiny, untrained: identity) improvement model: one enhanced view per
    camera, at the inputs' size, then the fit; no model is a clear error."""
    torch.manual_seed(0)
    improver = ImproveModel(
        ImproveConfig(
            vae_channels=(16, 16),
            vae_groups=8,
            unet_channels=(16, 16, 16),
            unet_groups=8,
            cross_attention_dim=16,
            working_size=0,
        )  # fmt: skip
    ).eval()
    images, cams = scene["images"][INPUTS], [scene["cams"][i] for i in INPUTS]
    view_cams = [scene["cams"][i] for i in VIEWS]
    result = distill_enhanced(scene["start"], images, cams, view_cams, improver, steps=5)
    assert result.enhanced.shape == (5, 3, SIZE, SIZE) and result.stats.steps == 5
    with torch.no_grad():  # the identity model: each enhanced view is the start's render
        raw = render(scene["start"], view_cams[0]).rgb.clamp(0, 1)
    torch.testing.assert_close(result.enhanced[0], raw, atol=1e-5, rtol=0)
    assert result.enhance_s > 0
    with pytest.raises(ValueError, match="improvement model"):
        enhance_views(scene["start"], images, cams, view_cams, None)


def test_prosplat_distill_uses_the_loaded_improvement_model():
    """``ProSplat.distill`` on the shipped models: one enhanced view per camera, fitted; a
    ProSplat without stage 2 says so."""
    from prosplat import ProSplat

    cams = orbit_cameras(5, 64, 64, arc_deg=60.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    model = ProSplat.from_pretrained()
    inputs, views = [0, 4], [1, 2, 3]
    g = model.reconstruct(images[inputs], [cams[i] for i in inputs], 1.0, 8.0).gaussians
    out = model.distill(g, [cams[i] for i in views], images[inputs], [cams[i] for i in inputs],
                        steps=3)  # fmt: skip
    assert out.enhanced.shape == (3, 3, 64, 64) and out.stats.steps == 3
    bare = ProSplat.from_pretrained(improve=False)
    with pytest.raises(ValueError, match="improvement model"):
        bare.distill(g, [cams[1]], images[inputs], [cams[i] for i in inputs], steps=1)
