"""Warping the reference into the target through depth (prosplat.improve.warp), against an
analytic textured plane seen by two cameras."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera
from prosplat.improve.warp import warp_reference


def texture(points: torch.Tensor) -> torch.Tensor:
    """[...,3] points on the plane z = 0 -> [3,...] smooth colours in [0,1]."""
    x, y = points[..., 0], points[..., 1]
    return torch.stack(
        [
            0.5 + 0.4 * torch.sin(1.3 * x),
            0.5 + 0.4 * torch.cos(1.1 * y),
            0.5 + 0.3 * torch.sin(x + y),
        ]
    )


def plane_view(cam: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """The plane z = 0 seen by ``cam``: image [3,H,W] and z-depth [H,W] (0 where missed)."""
    dirs = cam.ray_directions(torch.float64)  # [H,W,3]
    origin = cam.center.double()
    s = -origin[2] / dirs[..., 2]  # ray parameter where z = 0
    hit = s > 0
    points = origin + s[..., None] * dirs
    depth = torch.where(hit, cam.world_to_camera(points)[..., 2], torch.zeros_like(s))
    return texture(points).float(), depth.float()


def camera(angle_deg: float, size: int = 48) -> Camera:
    a = math.radians(angle_deg)
    eye = (4 * math.sin(a), -4 * math.cos(a), 3.0)
    return Camera.look_at(eye, (0, 0, 0), (0, 0, 1), 0.9 * size, size, size)


def test_warp_to_the_same_camera_returns_the_reference():
    cam = camera(0)
    image, depth = plane_view(cam)
    warped, valid = warp_reference(image, cam, cam, depth, reference_depth=depth)
    assert valid.all()
    torch.testing.assert_close(warped, image, atol=1e-5, rtol=0)


def test_warp_through_true_depth_reproduces_the_other_view():
    """Two cameras 35 degrees apart: the reference warped through the target's true depth is
    the target's own image (up to bilinear resampling), far closer than the reference pasted."""
    ref, tgt = camera(0), camera(35)
    ref_image, ref_depth = plane_view(ref)
    tgt_image, tgt_depth = plane_view(tgt)
    warped, valid = warp_reference(ref_image, ref, tgt, tgt_depth, reference_depth=ref_depth)
    assert valid.float().mean() > 0.6  # most of the target is seen by the reference
    warp_err = (warped - tgt_image).abs()[:, valid].mean()
    paste_err = (ref_image - tgt_image).abs()[:, valid].mean()
    assert warp_err < 0.01
    assert paste_err > 10 * warp_err


def test_occluded_outside_and_uncovered_pixels_are_invalid():
    ref, tgt = camera(0), camera(35)
    ref_image, ref_depth = plane_view(ref)
    _, tgt_depth = plane_view(tgt)
    # something in front of the plane at the reference: nothing the target sees is visible
    _, valid = warp_reference(ref_image, ref, tgt, tgt_depth, reference_depth=0.5 * ref_depth)
    assert not valid.any()
    # a target behind the reference, looking away from the scene: its points lie behind it
    away = Camera.look_at((0, -6, 3.0), (0, -12, 3.0), (0, 0, 1), 40.0, 48, 48)
    _, valid = warp_reference(ref_image, ref, away, torch.full((48, 48), 2.0))
    assert not valid.any()
    # uncovered target pixels (alpha < 0.5) are invalid
    alpha = torch.zeros(48, 48)
    alpha[:, :24] = 1
    _, valid = warp_reference(ref_image, ref, tgt, tgt_depth, alpha, ref_depth)
    assert not valid[:, 24:].any() and valid[:, :24].any()


def test_sizes_must_match_their_cameras():
    cam = camera(0)
    image, depth = plane_view(cam)
    with pytest.raises(ValueError, match="target_depth"):
        warp_reference(image, cam, cam, depth[:-1])
    with pytest.raises(ValueError, match="reference image"):
        warp_reference(image[:, :-1], cam, cam, depth)


def test_render_view_hands_a_warp_model_the_warped_reference():
    """render_view gives a warp-input model the reference warped through the rendered depth
    (reference_warp), the same as calling enhance with it by hand; a model without the
    input ignores it."""
    from prosplat.eval.demo_scene import demo_scene, orbit_cameras
    from prosplat.improve import ImproveConfig, ImproveModel
    from prosplat.improve.warp import reference_warp
    from prosplat.pipeline.enhance import enhance, render_view
    from prosplat.render import render

    torch.manual_seed(0)
    gaussians, cams = demo_scene(size=32, n_inputs=2)
    images = torch.stack([render(gaussians, c).rgb for c in cams])
    target = orbit_cameras(3, 32, 32)[1]
    cfg = ImproveConfig(
        vae_channels=(16, 16), vae_groups=8, unet_channels=(16, 16, 16), unet_groups=8,
        cross_attention_dim=16, alpha_input=True, warp_input=True, working_size=0,
    )  # fmt: skip
    model = ImproveModel(cfg).eval()
    with torch.no_grad():
        torch.nn.init.normal_(model.warp_in.weight, std=0.3)
        torch.nn.init.normal_(model.vae.decoder.conv_out.weight, std=0.1)
    view = render_view(gaussians, target, images, cams, model)
    warp = reference_warp(
        gaussians, target, view.depth, view.alpha, images[view.reference], cams[view.reference]
    )
    assert warp[3].mean() > 0.3  # the reference sees much of the target
    # a caller that already rendered the reference's depth (curation) gets the same warp
    ref_depth = render(gaussians, cams[view.reference]).depth
    given = reference_warp(
        gaussians, target, view.depth, view.alpha, images[view.reference],
        cams[view.reference], ref_depth,
    )  # fmt: skip
    assert torch.equal(given, warp)
    by_hand = enhance(
        model, view.raw, target, images[view.reference], cams[view.reference],
        alpha=view.alpha, warp=warp, working_size=0,
    )  # fmt: skip
    torch.testing.assert_close(view.image, by_hand)
    zero = torch.zeros_like(warp)
    no_warp = enhance(
        model, view.raw, target, images[view.reference], cams[view.reference],
        alpha=view.alpha, warp=zero, working_size=0,
    )  # fmt: skip
    assert (view.image - no_warp).abs().max() > 1e-3
    # forgetting the warp is an error, not a silently wrong picture
    with pytest.raises(ValueError, match="warp"):
        enhance(model, view.raw, target, images[view.reference], cams[view.reference])
    # the working-size path carries the warp down with the render
    small = enhance(
        model, view.raw, target, images[view.reference], cams[view.reference],
        alpha=view.alpha, warp=warp, working_size=16,
    )  # fmt: skip
    assert small.shape == view.image.shape and torch.isfinite(small).all()
