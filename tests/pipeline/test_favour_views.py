"""Views favour the input nearest them: ``Gaussians.views`` (each Gaussian's input view), where
it comes from and where it survives, ``prosplat.pipeline.enhance.view_weights`` (how much each view
counts) and ``render_favouring`` against the brute-force renderer
(``prosplat/render/reference.py``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prosplat import Camera, Gaussians
from prosplat.convert.pointcloud import from_attributes, to_attributes, transform_gaussians
from prosplat.core.ply import VIEW_PROPERTY, PlyWarning, read_ply, write_ply
from prosplat.improve.mori import select_reference
from prosplat.pipeline.enhance import (
    OTHER_VIEWS_OPACITY,
    render_favouring,
    render_view,
    view_weights,
)
from prosplat.render import render
from prosplat.render.reference import render_reference

SIZE = 24


def _camera(eye) -> Camera:
    return Camera.look_at(eye, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 30.0, SIZE, SIZE)


def _two_walls() -> tuple[Gaussians, list[Camera]]:
    """Two input views' surfaces that disagree: view 0 saw a red wall at x = 0.1, view 1 a
    blue one at x = -0.1 (a depth error), both facing the +x cameras; view 1's also reaches
    further up, so part of the image only it covers."""
    g = torch.Generator().manual_seed(0)
    parts = []
    for view, (x, colour, top) in enumerate(
        ((0.1, (0.9, 0.1, 0.1), 0.3), (-0.1, (0.1, 0.2, 0.9), 0.6))
    ):
        yz = torch.stack(torch.meshgrid(torch.linspace(-0.6, 0.6, 25),
                                        torch.linspace(-0.6, top, 20), indexing="ij"), -1)  # fmt: skip
        yz = yz.reshape(-1, 2) + 0.005 * torch.randn(yz.numel() // 2, 2, generator=g)
        n = len(yz)
        means = torch.cat([torch.full((n, 1), x), yz], 1)
        colours = torch.tensor(colour).expand(n, 3)
        scales = torch.full((n, 3), 0.03)
        parts.append(Gaussians.from_colors(means, colours, scales, torch.full((n,), 0.8))
                     .with_views(torch.full((n,), view)))  # fmt: skip
    cams = [_camera((3.0, -1.0, 0.2)), _camera((3.0, 1.0, 0.2))]
    return Gaussians.cat(parts), cams


def test_views_survive_subsets_copies_and_files(tmp_path) -> None:
    gs, _ = _two_walls()
    assert gs.views is not None and gs.views.dtype == torch.int64
    assert torch.equal(gs[gs.views == 1].views, gs.views[gs.views == 1])
    assert torch.equal(gs[3:9].views, gs.views[3:9])
    for other in (gs.detach(), gs.to(dtype=torch.float64), gs.with_sh_degree(1),
                  gs.with_scale_factor(0.5)):  # fmt: skip
        assert torch.equal(other.views, gs.views)
    assert Gaussians.cat([gs, gs.with_views(None)]).views is None  # unknown for part: unknown
    # a PLY keeps them as one extra property; attributes (the add-on's mesh) likewise
    write_ply(gs, tmp_path / "a.ply")
    assert torch.equal(read_ply(tmp_path / "a.ply").views, gs.views)
    back = from_attributes(to_attributes(gs))
    assert torch.equal(back.views, gs.views)
    assert torch.equal(transform_gaussians(back, torch.eye(4, dtype=torch.float64)).views, gs.views)
    # edited into something else (a float, a negative), the views are unknown, not wrong
    arrays = to_attributes(gs)
    arrays[VIEW_PROPERTY] = arrays[VIEW_PROPERTY] + np.float32(0.5)
    assert from_attributes(arrays).views is None
    # a PLY from another tool has none; a bad column is read past with a warning
    write_ply(gs.with_views(None), tmp_path / "b.ply")
    assert read_ply(tmp_path / "b.ply").views is None
    from plyfile import PlyData, PlyElement

    data = PlyData.read(str(tmp_path / "a.ply"))["vertex"].data.copy()
    data[VIEW_PROPERTY][0] = -1
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "c.ply"))
    with pytest.warns(PlyWarning, match=VIEW_PROPERTY):
        assert read_ply(tmp_path / "c.ply").views is None


@pytest.mark.parametrize(
    "views, message",
    [(torch.zeros(3), "integer"), (torch.zeros(2, dtype=torch.long), r"\[N=3\]"),
     (torch.tensor([0, -1, 0]), ">= 0")],
)  # fmt: skip
def test_bad_views_are_refused(views, message) -> None:
    g = Gaussians.from_colors(torch.zeros(3, 3), torch.zeros(3, 3), torch.ones(3, 3),
                              torch.ones(3) * 0.5)  # fmt: skip
    with pytest.raises(ValueError, match=message):
        g.with_views(views)


def test_the_generator_tags_each_gaussian_with_its_view() -> None:
    from prosplat.generator.output import GeneratorOutput

    b, v, h, w = 1, 3, 2, 4
    n = v * h * w
    out = GeneratorOutput(torch.zeros(b, n, 3), torch.tensor([1.0, 0, 0, 0]).expand(b, n, 4),
                          torch.ones(b, n, 3), torch.full((b, n), 0.5), torch.zeros(b, n, 1, 3),
                          torch.ones(b, v, h, w), torch.ones(b, v, h, w))  # fmt: skip
    assert out.gaussians(0).views.tolist() == [k // (h * w) for k in range(n)]


def test_view_weights_fall_with_the_distance_from_the_target() -> None:
    """1 for the favoured input; W · min(1, d_fav / d_j) for the others, d the distance
    between camera centres: ~0 at the favoured input's own camera, W for one as near (or
    within rounding of it)."""
    cams = [_camera((3.0, 0.0, 0.0)), _camera((0.0, 3.0, 0.0)), _camera((-3.0, 0.0, 0.0))]
    target = _camera((3.0, 1.0, 0.0))  # 1 from input 0, sqrt(13) from 1, sqrt(37) from 2
    w = view_weights(target, cams, 0, 0.5)
    assert w.dtype == torch.float64
    assert torch.allclose(w, torch.tensor([1.0, 0.5 / 13**0.5, 0.5 / 37**0.5], dtype=w.dtype))
    # favouring a view farther than another: the nearer one counts W, not more
    assert torch.allclose(view_weights(target, cams, 1, 0.5)[[0, 2]],
                          torch.tensor([0.5, 0.5 * 13**0.5 / 37**0.5], dtype=w.dtype))  # fmt: skip
    # at an input camera the others count nothing; every centre the same: all count W
    at_input = view_weights(cams[2], cams, 2, 0.5)
    assert torch.allclose(at_input, torch.tensor([0.0, 0.0, 1.0], dtype=w.dtype), atol=1e-6)
    same = [_camera((3.0, 0.0, 0.0)), Camera.look_at((3.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                                     (0.0, 0.0, 1.0), 30.0, SIZE, SIZE)]  # fmt: skip
    assert view_weights(same[0], same, 0, 0.25).tolist() == pytest.approx([1.0, 0.25])
    assert view_weights(target, cams, 0, 0.0).tolist() == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="favoured view 3"):
        view_weights(target, cams, 3, 0.5)
    with pytest.raises(ValueError, match="other_views_opacity"):
        view_weights(target, cams, 0, 1.5)


def test_favouring_keeps_the_coverage_and_moves_the_colour_towards_the_favoured_view() -> None:
    """Alpha and depth are the plain render's; the colour is the render with each view's
    opacities scaled by its weight, un-premultiplied and laid over the plain alpha (the
    brute-force renderer gives both renders); where the weighted render draws nothing the
    plain colour stays; with every weight 1 it is the plain render."""
    gs, cams = _two_walls()
    target = _camera((3.0, 1.2, 0.0))  # nearest input: view 1, whose blue wall lies behind
    j = select_reference(target, cams)
    assert j == 1
    plain = render(gs, target)
    weights = torch.tensor([0.25, 1.0])
    fav = render_favouring(gs, target, weights)
    assert torch.equal(fav.alpha, plain.alpha) and torch.equal(fav.depth, plain.depth)
    rgb, alpha, _ = render_reference(gs, target)
    w = weights[gs.views]
    rgb_w, alpha_w, _ = render_reference(
        Gaussians(gs.means, gs.quats, gs.scales, gs.opacities * w, gs.sh), target
    )
    drawn = alpha_w > 1e-3
    want = torch.where(drawn, rgb_w / alpha_w.clamp_min(1e-6) * alpha, rgb)
    assert torch.allclose(fav.rgb, want, atol=2e-4)
    both = (alpha > 0.9) & (alpha_w > 0.5) & (plain.rgb[0] > 0.6)  # red in front, blue behind
    assert both.sum() > 20
    bluer = fav.rgb[2][both] - plain.rgb[2][both]  # towards view 1's colour
    assert (bluer > 0).all() and float(bluer.mean()) > 0.1
    assert torch.allclose(render_favouring(gs, target, torch.ones(2)).rgb, plain.rgb, atol=1e-5)
    # a background stays behind both renders: the same premultiplied colour over it
    bg = torch.tensor([0.2, 0.7, 0.3])
    on_bg = render_favouring(gs, target, weights, background=bg)
    assert torch.allclose(on_bg.rgb, fav.rgb + (1 - fav.alpha) * bg[:, None, None], atol=1e-5)
    for bad in (torch.tensor([0.25]), torch.tensor([1.0, 1.5]), torch.ones(2, 1)):
        with pytest.raises(ValueError, match="weights"):
            render_favouring(gs, target, bad)


def test_an_input_camera_sees_its_own_views_colour_where_that_view_draws() -> None:
    """At an input's own camera the other views count nothing (view_weights): the colour is
    that view's Gaussians alone (brute force) over the plain alpha wherever they draw, the
    other view's plain colour where only it draws."""
    gs, cams = _two_walls()
    images = torch.rand(2, 3, SIZE, SIZE)
    for j, cam in enumerate(cams):
        shown = render_view(gs, cam, images, cams, max_splat_radius=None)
        rgb, alpha, _ = render_reference(gs, cam)
        own_rgb, own_alpha, _ = render_reference(gs[gs.views == j], cam)
        want = torch.where(own_alpha > 1e-3, own_rgb / own_alpha.clamp_min(1e-6) * alpha, rgb)
        sure = (own_alpha > 1e-3) | (own_alpha < 1e-5)  # away from the 1e-4 switch
        assert torch.allclose(shown.raw[:, sure], want[:, sure], atol=2e-4)
        assert torch.allclose(shown.alpha, alpha, atol=1e-4)
        if j == 0:  # view 1's wall reaches higher: there only the other view draws
            assert ((own_alpha < 1e-5) & (alpha > 0.5)).sum() > 5


def test_render_view_favours_only_with_views_and_the_inputs_they_index() -> None:
    gs, cams = _two_walls()
    images = torch.rand(2, 3, SIZE, SIZE)
    target = _camera((3.0, 1.2, 0.0))
    j = select_reference(target, cams)
    fav = render_favouring(gs, target, view_weights(target, cams, j, OTHER_VIEWS_OPACITY))
    plain = render(gs, target).rgb
    assert torch.allclose(render_view(gs, target, images, cams).raw, fav.rgb, atol=1e-6)
    for unfavoured in (
        render_view(gs, target).raw,  # no inputs: nothing to favour
        render_view(gs.with_views(None), target, images, cams).raw,  # views unknown
        render_view(gs, target, images[:1], cams[:1]).raw,  # views index another input set
        render_view(gs, target, images, cams, other_views_opacity=1).raw,
    ):
        assert torch.allclose(unfavoured, plain, atol=1e-6)
    with pytest.raises(ValueError, match="other_views_opacity"):
        render_view(gs, target, images, cams, other_views_opacity=1.5)


def test_refinement_keeps_the_views() -> None:
    from prosplat.pipeline.refine import refine

    gs, cams = _two_walls()
    images = torch.stack([render(gs, c).rgb.clamp(0, 1).detach() for c in cams])
    out = refine(gs, images, cams, steps=2).gaussians
    assert torch.equal(out.views, gs.views)
