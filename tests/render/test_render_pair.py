"""prosplat.render.render_pair: one projection, two composites, the same images as two
renders (the reference: :func:`prosplat.render.render` called twice)."""

from __future__ import annotations

import pytest
import torch

from prosplat import Gaussians
from prosplat.eval.demo_scene import demo_scene, orbit_cameras
from prosplat.render import render, render_pair


@pytest.mark.parametrize("backend", ["cpu", "cpu-fused"])
def test_the_pair_is_two_renders(backend):
    g, _ = demo_scene(48, n_inputs=2)
    cam = orbit_cameras(3, 64, 48, arc_deg=30.0)[1]
    w = torch.rand(len(g), generator=torch.Generator().manual_seed(0)).to(g.opacities)
    lower = g.opacities * w
    plain, colour = render_pair(g, cam, lower, torch.tensor([0.2, 0.3, 0.4]), backend)
    weighted = Gaussians.trusted(g.means, g.quats, g.scales, lower, g.sh, g.views)
    bg = torch.tensor([0.2, 0.3, 0.4])
    for got, want in (
        (plain, render(g, cam, bg, backend)),
        (colour, render(weighted, cam, bg, backend)),
    ):
        for name in ("rgb", "alpha", "depth"):
            torch.testing.assert_close(getattr(got, name), getattr(want, name), atol=1e-6, rtol=0)
        assert torch.equal(got.visible, plain.visible)
    # opacities above the Gaussians' own: two plain renders, still right
    higher = (g.opacities * 1.5).clamp(max=1.0)
    _, up = render_pair(g, cam, higher, None, backend)
    brighter = Gaussians.trusted(g.means, g.quats, g.scales, higher, g.sh, g.views)
    torch.testing.assert_close(up.rgb, render(brighter, cam, None, backend).rgb, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="colour_opacities"):
        render_pair(g, cam, lower[:-1])


@pytest.mark.parametrize("backend", ["cpu", "cpu-fused"])
def test_max_radius_leaves_out_what_oversized_splats_flags(backend):
    """``max_radius`` in the render's own projection draws what the subset without the
    flagged Gaussians draws (:func:`oversized_splats`, a projection of its own), in
    ``render`` and in both images of ``render_pair``; ``visible`` turns False for them."""
    from prosplat.pipeline.enhance import oversized_splats

    g, _ = demo_scene(48, n_inputs=2)
    cam = orbit_cameras(3, 64, 48, arc_deg=30.0)[1]
    cap = 0.03  # 1.4 px at 48 px: some of the scene's splats are wider, most are not
    wide = oversized_splats(g, cam, cap)  # [N]
    assert 0 < int(wide.sum()) < len(g) // 2
    kept = g[~wide]
    lower = g.opacities * 0.5
    bg = torch.tensor([0.2, 0.3, 0.4])
    plain, colour = render_pair(g, cam, lower, bg, backend, max_radius=cap)
    half = Gaussians.trusted(kept.means, kept.quats, kept.scales, lower[~wide], kept.sh, kept.views)
    drawn = render(kept, cam, bg, backend).visible  # both of the pair report the plain one's
    for got, want in (
        (render(g, cam, bg, backend, max_radius=cap), render(kept, cam, bg, backend)),
        (plain, render(kept, cam, bg, backend)),
        (colour, render(half, cam, bg, backend)),
    ):
        for name in ("rgb", "alpha", "depth"):
            torch.testing.assert_close(getattr(got, name), getattr(want, name), atol=1e-6, rtol=0)
        assert not got.visible[wide].any()
        assert torch.equal(got.visible[~wide], drawn)
    assert not torch.allclose(plain.rgb, render(g, cam, bg, backend).rgb, atol=1e-3)
    for bad in (0.0, -1.0, float("inf"), True):
        with pytest.raises(ValueError, match="max_radius"):
            render(g, cam, max_radius=bad, backend=backend)
