"""prosplat.render.hole_fill: covered pixels untouched, holes continued from their
surroundings (against a brute-force nearest-covered-pixel reference), partial coverage
completed by ``over``, any size and batch, and the wiring into render_view and the ladder."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.pipeline.enhance import render_view
from prosplat.render import render
from prosplat.render.hole_fill import fill_colour, fill_holes


def _nearest_covered(rgb: torch.Tensor, covered: torch.Tensor) -> torch.Tensor:
    """Brute force: every pixel takes the colour of its nearest covered pixel."""
    h, w = covered.shape
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    pts = torch.stack([ys[covered], xs[covered]], -1).float()  # [M,2]
    grid = torch.stack([ys, xs], -1).reshape(-1, 1, 2).float()  # [HW,1,2]
    nearest = ((grid - pts[None]) ** 2).sum(-1).argmin(1)  # [HW]
    return rgb[:, covered][:, nearest].reshape(3, h, w)


def test_covered_pixels_are_unchanged_and_a_constant_render_fills_constant():
    rgb = torch.zeros(3, 40, 56)
    alpha = torch.zeros(40, 56)
    alpha[5:30, 10:40] = 1
    colour = torch.tensor([0.2, 0.5, 0.9])
    rgb[:, 5:30, 10:40] = colour[:, None, None]
    out = fill_holes(rgb, alpha)
    assert torch.equal(out[:, 5:30, 10:40], rgb[:, 5:30, 10:40])
    assert torch.allclose(out, colour[:, None, None].expand_as(out), atol=1e-6)


def test_a_hole_blends_from_the_side_it_is_nearest():
    """Left red, right blue, a black gap between: across the gap the fill goes from red to
    blue monotonically, each hole pixel leaning to the side it is nearest (the sign of the
    brute-force nearest-covered fill), symmetric about the middle."""
    h, w = 32, 64
    rgb = torch.zeros(3, h, w)
    rgb[0, :, :24] = 1.0  # red on the left
    rgb[2, :, 40:] = 1.0  # blue on the right
    alpha = torch.ones(h, w)
    alpha[:, 24:40] = 0
    out = fill_holes(rgb, alpha)
    lean = (out[0] - out[2])[:, 24:40]  # [H,16] red minus blue in the gap
    ref = _nearest_covered(rgb, alpha > 0.5)
    assert torch.equal(torch.sign(lean), torch.sign((ref[0] - ref[2])[:, 24:40]))
    profile = lean.mean(0)
    assert (profile.diff() < 0).all()  # red -> blue, no ringing
    assert torch.allclose(profile, -profile.flip(0), atol=1e-5)
    assert out.min() >= 0 and out.max() <= 1  # never outside the render's own colours


def test_partial_coverage_is_completed_over_the_fill():
    h, w = 16, 16
    colour = torch.tensor([0.8, 0.4, 0.1])
    alpha = torch.full((h, w), 0.25)
    rgb = colour[:, None, None] * alpha  # premultiplied over black
    out = fill_holes(rgb, alpha)
    # everything the render saw has the one colour, so the completed pixel is that colour
    assert torch.allclose(out, colour[:, None, None].expand(3, h, w), atol=1e-5)


def test_nothing_covered_stays_black_and_shapes_are_checked():
    out = fill_holes(torch.zeros(3, 8, 8), torch.zeros(8, 8))
    assert torch.equal(out, torch.zeros(3, 8, 8))
    with pytest.raises(ValueError, match="rgb must be"):
        fill_holes(torch.zeros(8, 8), torch.zeros(8, 8))
    with pytest.raises(ValueError, match="does not match"):
        fill_holes(torch.zeros(3, 8, 8), torch.zeros(4, 4))


@settings(max_examples=25, deadline=None)
@given(
    h=st.integers(1, 37),
    w=st.integers(1, 37),
    b=st.integers(1, 3),
    seed=st.integers(0, 2**16),
)
def test_any_size_and_batch_matches_one_at_a_time(h, w, b, seed):
    g = torch.Generator().manual_seed(seed)
    alpha = (torch.rand(b, 1, h, w, generator=g) > 0.6).float() * torch.rand(
        b, 1, h, w, generator=g
    )
    rgb = torch.rand(b, 3, h, w, generator=g) * alpha
    out = fill_holes(rgb, alpha)
    assert out.shape == rgb.shape and torch.isfinite(out).all()
    assert out.min() >= 0 and out.max() <= 1 + 1e-6
    for i in range(b):
        assert torch.allclose(out[i], fill_holes(rgb[i], alpha[i, 0]), atol=1e-6)
    full = alpha >= 1
    assert torch.equal(out.expand_as(rgb)[full.expand_as(rgb)], rgb[full.expand_as(rgb)])


def _half_scene():
    """A wall of Gaussians that covers only the left half of a camera's view."""
    cam = Camera.look_at((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 48, 32)
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, 24), torch.linspace(-1.3, 0.0, 24), indexing="ij")
    means = torch.stack([xs, ys, torch.zeros_like(xs)], -1).reshape(-1, 3)
    n = len(means)
    colour = torch.tensor([0.9, 0.3, 0.2])
    g = Gaussians(
        means,
        torch.tensor([1.0, 0, 0, 0]).expand(n, 4).clone(),
        torch.full((n, 3), 0.06),
        torch.full((n,), 0.99),
        ((colour - 0.5) / 0.28209479177387814)[None, None].expand(n, 1, 3).clone(),
    )
    return g, cam


def test_render_view_fills_only_the_shown_raw_image():
    g, cam = _half_scene()
    raw = render(g, cam)
    view = render_view(g, cam, fill_holes=True)
    assert torch.equal(view.raw, raw.rgb)  # stage 2's input stays the render on black
    hole = raw.alpha < 0.01
    assert hole.any() and (view.image[:, hole] > 0.1).all()  # the hole shows the wall's colour
    assert torch.allclose(view.image[:, ~hole], fill_holes(raw.rgb, raw.alpha)[:, ~hole])
    plain = render_view(g, cam)
    assert torch.equal(plain.image, raw.rgb)  # off by default: the rasterizer's image
    with pytest.raises(ValueError, match="not both"):
        render_view(g, cam, background=torch.ones(3), fill_holes=True)


def test_splat_scale_renders_the_gaussians_smaller_and_a_guarded_view_at_their_own_size(
    monkeypatch,
):
    """``splat_scale`` multiplies every Gaussian's scales for that render (the brute-force
    twin: rendering :meth:`Gaussians.with_scale_factor` directly); a smaller splat leaves more
    holes on black, which the fill then completes; a view the guard refuses on black comes
    back at the Gaussians' own size, not the smaller one it was enhanced at."""
    from types import SimpleNamespace

    from prosplat.pipeline import enhance as enhance_module

    g, cam = _half_scene()
    small = render(g.with_scale_factor(0.5), cam)
    view = render_view(g, cam, fill_holes=True, splat_scale=0.5)
    assert torch.equal(view.raw, small.rgb) and torch.equal(view.alpha, small.alpha)
    assert torch.allclose(view.image, fill_holes(small.rgb, small.alpha))
    assert float(small.alpha.sum()) < float(render(g, cam).alpha.sum())  # smaller footprints
    assert g.with_scale_factor(1.0) is g
    assert torch.equal(g.with_scale_factor(0.25).scales, g.scales * 0.25)
    for bad in (0.0, -1.0, float("nan"), float("inf"), True):
        with pytest.raises(ValueError, match="scale factor"):
            g.with_scale_factor(bad)
    # a model that rewrites every pixel: the departure guard refuses its view
    monkeypatch.setattr(enhance_module, "enhance", lambda improver, raw, *a, **k: 1.0 - raw)
    scribbler = SimpleNamespace(config=SimpleNamespace(warp_input=False))
    images = torch.rand(1, 3, cam.height, cam.width)
    guarded = render_view(g, cam, images, [cam], scribbler, splat_scale=0.5)
    assert guarded.guard is not None
    assert torch.equal(guarded.image, render(g, cam).rgb)  # the Gaussians as given, on black
    filled = render_view(g, cam, images, [cam], scribbler, splat_scale=0.5, fill_holes=True)
    assert filled.guard is not None and torch.allclose(filled.image, view.image)


def test_fill_enhanced_false_keeps_the_fill_to_raw_and_guarded_views(monkeypatch):
    """``fill_enhanced=False``: an enhanced view is stage 2's image as it came (not blended
    with the fill by the render's alpha, as by default); a view the guard refuses still shows
    the filled raw render."""
    from types import SimpleNamespace

    from prosplat.pipeline import enhance as enhance_module

    g, cam = _half_scene()
    raw = render(g, cam)
    images = torch.rand(1, 3, cam.height, cam.width)
    model = SimpleNamespace(config=SimpleNamespace(warp_input=False))
    gentle = lambda improver, raw, *a, **k: (0.9 * raw + 0.08).clamp(0, 1)  # noqa: E731
    monkeypatch.setattr(enhance_module, "enhance", gentle)
    kept = render_view(g, cam, images, [cam], model, fill_holes=True, fill_enhanced=False)
    blended = render_view(g, cam, images, [cam], model, fill_holes=True)
    assert kept.guard is None and blended.guard is None
    assert torch.equal(kept.image, gentle(None, raw.rgb))
    fill = fill_colour(raw.rgb, raw.alpha)
    torch.testing.assert_close(blended.image, raw.alpha * kept.image + (1 - raw.alpha) * fill)
    assert (blended.image - kept.image).abs().amax() > 0.1  # the holes differ
    monkeypatch.setattr(enhance_module, "enhance", lambda improver, raw, *a, **k: 1.0 - raw)
    guarded = render_view(g, cam, images, [cam], model, fill_holes=True, fill_enhanced=False)
    assert guarded.guard is not None
    torch.testing.assert_close(guarded.image, raw.rgb + (1 - raw.alpha) * fill)


def test_oversized_splats_are_the_ones_the_rasterizer_draws_that_wide():
    """:func:`oversized_splats` against the rasterizer's 2D covariance, inverted and
    diagonalised here (its conic is what the rasterizer draws): a Gaussian is flagged exactly
    when its widest standard deviation exceeds the limit; Gaussians behind the camera never
    are."""
    from prosplat.pipeline.enhance import oversized_splats
    from prosplat.render.projection import project_gaussians

    cam = Camera.look_at((0.0, 0.0, -4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 50.0, 64, 48)
    gen = torch.Generator().manual_seed(3)
    n = 400
    depth = torch.empty(n).uniform_(0.3, 6.0, generator=gen)  # along the axis, from the camera
    xy = (torch.rand(n, 2, generator=gen) - 0.5) * 0.4 * depth[:, None]  # near the image centre
    means = torch.cat([xy, (depth - 4.0)[:, None]], 1)
    scales = torch.empty(n, 3).uniform_(0.002, 0.4, generator=gen)
    g = Gaussians(
        means,
        torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
        scales,
        torch.full((n,), 0.9),
        torch.zeros(n, 1, 3),
    )
    limit_frac = 0.1
    flagged = oversized_splats(g, cam, limit_frac)
    p = project_gaussians(g, cam)
    a, b, c = p.conics.to(torch.float64).unbind(-1)
    det = a * c - b * b
    cov = torch.stack([c / det, -b / det, -b / det, a / det], -1).view(n, 2, 2)
    sigma = torch.linalg.eigvalsh(cov)[:, -1].sqrt()  # the widest direction, px
    limit = limit_frac * min(cam.width, cam.height)
    clear = ((sigma / limit - 1).abs() > 1e-6) & p.valid  # rounding decides at the limit
    assert clear.sum() > 300 and flagged[clear].any() and (~flagged[clear]).any()
    assert torch.equal(flagged[clear], (sigma > limit)[clear])
    assert not flagged[~p.valid].any()
    behind = Gaussians(
        torch.tensor([[0.0, 0.0, -4.5]]),  # behind the camera at z = -4
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
        torch.full((1, 3), 5.0),
        torch.ones(1),
        torch.zeros(1, 1, 3),
    )
    assert not oversized_splats(behind, cam, limit_frac).any()
    for bad in (0.0, -0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="max_radius"):
            oversized_splats(g, cam, bad)


def test_render_view_leaves_out_oversized_splats(monkeypatch):
    """``max_splat_radius``: one huge Gaussian just in front of the camera greys out the whole
    view; with the cap (on by default) a filled view is bitwise the render without it, and
    the wall's own splats (about 2 px wide) all stay; None draws everything, and so does a
    raw view on black."""
    from types import SimpleNamespace

    from prosplat.pipeline import enhance as enhance_module

    g, cam = _half_scene()
    blob = Gaussians(
        torch.tensor([[0.0, 0.0, -2.5]]),  # 0.5 in front of the camera, 1 sigma = 0.2
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
        torch.full((1, 3), 0.2),
        torch.full((1,), 0.8),
        torch.zeros(1, 1, 3),
    )
    both = Gaussians.cat([g, blob])
    assert not torch.allclose(render(both, cam).rgb, render(g, cam).rgb, atol=0.05)
    filled = render_view(both, cam, fill_holes=True, max_splat_radius=0.25)
    alone = render(g, cam)
    assert torch.equal(filled.raw, alone.rgb)
    assert torch.equal(filled.image, fill_holes(alone.rgb, alone.alpha))
    assert torch.equal(render_view(both, cam, fill_holes=True).image, filled.image)  # default
    every = render_view(both, cam, fill_holes=True, max_splat_radius=None)
    assert torch.equal(every.raw, render(both, cam).rgb)
    # a raw view on black draws every splat whatever the cap: its holes would stay black
    assert torch.equal(render_view(both, cam, max_splat_radius=0.25).image, render(both, cam).rgb)
    for bad in (0.0, -0.1, float("nan"), "0.1"):  # refused there too, not silently ignored
        with pytest.raises(ValueError, match="max_splat_radius"):
            render_view(both, cam, max_splat_radius=bad)
    # so does a view the guard refuses to enhance, shown on black
    monkeypatch.setattr(enhance_module, "enhance", lambda improver, raw, *a, **k: 1.0 - raw)
    scribbler = SimpleNamespace(config=SimpleNamespace(warp_input=False))
    images = torch.rand(1, 3, cam.height, cam.width)
    guarded = render_view(both, cam, images, [cam], scribbler)
    assert guarded.guard is not None and torch.equal(guarded.raw, alone.rgb)
    assert torch.equal(guarded.image, render(both, cam).rgb)
