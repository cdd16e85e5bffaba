"""How stage 2 is applied to a view (prosplat.pipeline.enhance): the working size (enhance small, carry
the change up) and the guard (raw render back, with the reason)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from improve_configs import SMALL as TINY_TEST

from prosplat import ProSplat
from prosplat.eval.demo_scene import demo_scene, orbit_cameras
from prosplat.improve.model import ImproveModel
from prosplat.pipeline.enhance import EnhanceOptions, enhance, guard_reason
from prosplat.render.hole_fill import fill_colour

SMALL = TINY_TEST.with_(working_size=32)  # the other stage-2 tests' small model


def _model() -> ImproveModel:
    torch.manual_seed(0)
    model = ImproveModel(SMALL).eval()
    with torch.no_grad():  # make the residual decoder non-zero: an untrained one is identity
        torch.nn.init.normal_(model.vae.decoder.conv_out.weight, std=0.2)
    return model


def test_large_views_are_enhanced_at_the_working_size_and_the_change_carried_up():
    model = _model()
    cams = orbit_cameras(2, 270, 150, arc_deg=40.0)  # neither side a multiple of 16
    g = torch.Generator().manual_seed(0)
    raw, ref = torch.rand(3, 150, 270, generator=g), torch.rand(3, 150, 270, generator=g)
    with torch.no_grad():
        out = enhance(model, raw, cams[0], ref, cams[1])  # no alpha: carried onto the render
        small = F.interpolate(raw[None], size=(18, 32), mode="bilinear", antialias=True)[0]
        change = enhance(model, small, cams[0].resized(32, 18), ref, cams[1]) - small
    assert out.shape == raw.shape and torch.isfinite(out).all()
    expected = (raw + F.interpolate(change[None], size=(150, 270), mode="bilinear")[0]).clamp(0, 1)
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=0)
    # the change is smooth: it has no more detail than a 32-px image
    assert (out - raw).abs().max() > 1e-3
    # working_size=0 runs at the view's own size (a different, unsmoothed result)
    with torch.no_grad():
        native = enhance(model, raw, cams[0], ref, cams[1], working_size=0)
    assert native.shape == raw.shape and not torch.allclose(native, out)


def test_a_dotted_lattice_is_not_carried_up():
    """A 128-px render of one colour with every other pixel a hole (a lattice of splats too
    small for the view), enhanced by an identity model at 32 px: carried onto the render on
    black (``carry="raw"``) the lattice stays as it was; carried onto the render with its
    holes filled at full size (the default) the view is even, and its mean is the model's
    (the identity keeps the darker mean of the antialiased lattice: it does not fill)."""
    model = ImproveModel(SMALL).eval()  # untrained: residual zero, the identity
    cams = orbit_cameras(2, 128, 128, arc_deg=40.0)
    alpha = torch.zeros(128, 128)
    alpha[0::2, 0::2] = alpha[1::2, 1::2] = 1.0  # a checkerboard of covered pixels
    raw = torch.tensor([0.8, 0.5, 0.2])[:, None, None] * alpha  # [3,128,128] on black
    ref = torch.rand(3, 128, 128, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        old = enhance(model, raw, cams[0], ref, cams[1], alpha=alpha, carry="raw")
        new = enhance(model, raw, cams[0], ref, cams[1], alpha=alpha)
    torch.testing.assert_close(old, raw, atol=1e-5, rtol=0)  # the lattice, untouched
    with torch.no_grad():  # a caller's filled render (render_view's) is the one made here
        given = raw + (1 - alpha) * fill_colour(raw, alpha)
        assert torch.equal(
            enhance(model, raw, cams[0], ref, cams[1], alpha=alpha, filled=given), new
        )
    assert float(old.std(dim=(1, 2)).mean()) > 0.2
    assert float(new.std(dim=(1, 2)).mean()) < 0.01  # even
    torch.testing.assert_close(new.mean(dim=(1, 2)), raw.mean(dim=(1, 2)), atol=0.01, rtol=0)
    with pytest.raises(ValueError, match="carry"):
        EnhanceOptions(carry="blend")


def test_a_4k_camera_costs_what_the_working_size_costs():
    model = _model()
    cams = orbit_cameras(2, 3840, 2160, arc_deg=40.0)
    raw, ref = torch.rand(3, 2160, 3840), torch.rand(3, 64, 112)
    with torch.no_grad():
        out = enhance(model, raw, cams[0], ref, cams[1].resized(112, 64))
    assert out.shape == (3, 2160, 3840) and torch.isfinite(out).all()


def test_guard_keeps_the_raw_render_of_an_empty_view_and_says_why():
    torch.manual_seed(0)
    gaussians, inputs = demo_scene(32, n_inputs=2)
    images = torch.rand(2, 3, 32, 32)
    away = orbit_cameras(2, 32, 32, arc_deg=40.0)[0]
    # turn the camera around: it sees none of the Gaussians
    w2c = away.world_to_cam.clone()
    w2c[:3, :3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=w2c.dtype)) @ w2c[:3, :3]
    w2c[:3, 3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=w2c.dtype)) @ w2c[:3, 3]
    empty = type(away)(away.K, w2c, 32, 32)
    model = ProSplat(improver=_model())
    view = model.render(gaussians, empty, images, inputs)
    assert float(view.alpha.mean()) < 0.01
    assert view.guard is not None and "coverage" in view.guard
    assert torch.equal(view.image, view.raw)
    # without the guard the model invents something there
    free = model.render(gaussians, empty, images, inputs, options=EnhanceOptions(guard=False))
    assert free.guard is None and not torch.equal(free.image, free.raw)
    # a covered view: this random model rewrites it wholesale, which the departure rule catches
    seen = model.render(gaussians, inputs[0], images, inputs)
    assert seen.guard is not None and "confident pixels" in seen.guard
    lax = model.render(
        gaussians, inputs[0], images, inputs, options=EnhanceOptions(max_departure=1)
    )
    assert lax.guard is None and not torch.equal(lax.image, lax.raw)


def test_guard_departure_rule():
    raw = torch.full((3, 8, 8), 0.5)
    alpha = torch.ones(8, 8)
    opts = EnhanceOptions(max_departure=0.1)
    assert guard_reason(raw, raw + 0.05, alpha, opts) is None
    assert "confident pixels" in guard_reason(raw, raw + 0.2, alpha, opts)
    # changes where the render is not confident (holes) are what the model is for
    holes = torch.zeros(8, 8)
    holes[0, 0] = 1.0
    filled = raw.clone()
    filled[:, 1:, :] += 0.4
    assert (
        guard_reason(raw, filled, holes, EnhanceOptions(max_departure=0.1, min_coverage=0)) is None
    )
    with pytest.raises(ValueError, match="max_departure"):
        EnhanceOptions(max_departure=0)
