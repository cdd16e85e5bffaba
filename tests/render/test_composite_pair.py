"""prosplat.render.cpu.composite_pair: two opacity streams of the same Gaussians in one C++
pass, bitwise what two one-stream composites give (its twin, composite_pair_reference), with
each stream stopping on its own transmittance; and render_pair, which uses it, bitwise two
renders (with a background, and on a view where nothing is drawn)."""

from __future__ import annotations

import pytest
import torch

from prosplat import Gaussians
from prosplat.eval.demo_scene import demo_scene, orbit_cameras
from prosplat.render import render, render_pair
from prosplat.render.cpu import composite, composite_pair, composite_pair_reference
from prosplat.render.fused import depth_order
from prosplat.render.projection import MIN_ALPHA, MIN_TRANSMITTANCE

W, H = 37, 29  # not a multiple of the 16 px tile


def screen_gaussians(n: int, seed: int, dtype: torch.dtype, n_feat: int = 4):
    """Screen-space Gaussians over a W x H view, a third of them stacked opaque at its centre
    (so the transmittance threshold is reached there), with loose boxes and a front-to-back
    order; and lower opacities: the same scaled by [0, 1], some 0, some just under 1/255."""
    gen = torch.Generator().manual_seed(seed)
    means2d = torch.rand(n, 2, generator=gen, dtype=dtype) * torch.tensor([W + 8.0, H + 8.0]) - 4
    stacked = torch.arange(n) % 3 == 0
    means2d[stacked] = torch.tensor([W / 2, H / 2], dtype=dtype)
    sx = torch.empty(n, dtype=dtype).uniform_(0.5, 6.0, generator=gen)
    sy = torch.empty(n, dtype=dtype).uniform_(0.5, 6.0, generator=gen)
    rho = torch.empty(n, dtype=dtype).uniform_(-0.8, 0.8, generator=gen)
    det = (sx * sy) ** 2 * (1 - rho**2)
    conics = torch.stack([sy**2 / det, -rho * sx * sy / det, sx**2 / det], dim=-1)  # [N,3]
    opacities = torch.rand(n, generator=gen, dtype=dtype)
    opacities[stacked] = 1.0  # alpha clamps to 0.99: three samples take T below 1e-4
    lower = opacities * torch.rand(n, generator=gen, dtype=dtype)
    lower[torch.arange(n) % 7 == 0] = 0.0
    lower[torch.arange(n) % 7 == 1] = MIN_ALPHA * 0.999
    feats = torch.randn(n, n_feat, generator=gen, dtype=dtype)
    r = (3 * torch.maximum(sx, sy)).ceil().to(torch.int32) + 1
    u, v = means2d[:, 0].floor().to(torch.int32), means2d[:, 1].floor().to(torch.int32)
    boxes = torch.stack(
        [
            (u - r).clamp(0, W),
            (u + r).clamp(-1, W - 1),
            (v - r).clamp(0, H),
            (v + r).clamp(-1, H - 1),
        ],
        dim=-1,
    ).to(torch.int32)  # [N,4]: 3 sd, wider than where alpha reaches 1/255
    depths = torch.rand(n, generator=gen, dtype=dtype) + 0.5
    order = depth_order(depths, torch.rand(n, generator=gen) < 0.9)  # [M]
    return means2d, conics, opacities, lower, feats, boxes, order


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("n_feat", [4, 11])  # 11: the per-tile accumulators on the heap
def test_the_pair_is_two_composites_bitwise(dtype, n_feat):
    means2d, conics, high, low, feats, boxes, order = screen_gaussians(600, 0, dtype, n_feat)
    got = composite_pair(means2d, conics, high, low, feats, boxes, order, W, H)
    want = composite_pair_reference(means2d, conics, high, low, feats, boxes, order, W, H)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == dtype and torch.equal(a, b)
    t_high, t_low = got[1], got[3]
    # both streams reached the threshold at the centre (T would drop below 1e-4 with one
    # more sample), at different samples: the opaque stream after two 0.99 alphas, the
    # lower one later, past where the opaque one stopped
    centre = (H // 2, W // 2)
    assert t_high[centre] < 1e-2 and t_low[centre] < 1e-2 and t_low[centre] != t_high[centre]
    assert min(t_high.min(), t_low.min()) >= MIN_TRANSMITTANCE
    assert not torch.equal(got[0], got[2])
    # swapping the streams swaps the results (neither stream leans on the other's order)
    swapped = composite_pair(means2d, conics, low, high, feats, boxes, order, W, H)
    for a, b in zip(swapped, (*got[2:], *got[:2]), strict=True):
        assert torch.equal(a, b)


def test_one_stream_stopping_first_either_way():
    """Where the lower stream is opaque too (equal opacities at the centre) both stop; the
    pair still equals the two composites and the equal streams give equal images."""
    means2d, conics, high, _, feats, boxes, order = screen_gaussians(300, 1, torch.float32)
    got = composite_pair(means2d, conics, high, high.clone(), feats, boxes, order, W, H)
    assert torch.equal(got[0], got[2]) and torch.equal(got[1], got[3])
    assert torch.equal(got[0], composite(means2d, conics, high, feats, boxes, order, W, H)[0])


def test_an_empty_order_and_all_faint_gaussians_leave_the_view_empty():
    means2d, conics, high, low, feats, boxes, order = screen_gaussians(50, 2, torch.float32)
    out_a, t_a, out_b, t_b = composite_pair(
        means2d, conics, high, low, feats, boxes, order[:0], W, H
    )
    assert torch.equal(t_a, torch.ones(H, W)) and torch.equal(t_b, t_a)
    assert not out_a.any() and not out_b.any()
    faint = torch.full_like(high, MIN_ALPHA * 0.5)
    got = composite_pair(means2d, conics, high, faint, feats, boxes, order, W, H)
    assert torch.equal(got[3], torch.ones(H, W)) and not got[2].any()
    want = composite_pair_reference(means2d, conics, high, faint, feats, boxes, order, W, H)
    assert all(torch.equal(a, b) for a, b in zip(got, want, strict=True))


def test_the_pair_backward_is_the_two_composites_backward():
    inputs = screen_gaussians(200, 3, torch.float64)
    means2d, conics, high, low, feats, boxes, order = inputs
    gen = torch.Generator().manual_seed(4)
    weights = [torch.randn(s, generator=gen, dtype=torch.float64) for s in ((4, H, W), (H, W)) * 2]

    def grads(fn):
        leaves = [x.clone().requires_grad_(True) for x in (means2d, conics, high, low, feats)]
        outs = fn(*leaves[:4], leaves[4], boxes, order, W, H)
        sum((o * w).sum() for o, w in zip(outs, weights, strict=True)).backward()
        return [x.grad for x in leaves]

    for a, b in zip(grads(composite_pair), grads(composite_pair_reference), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("backend", ["cpu", "cpu-fused"])
def test_render_pair_is_two_renders_bitwise(backend):
    g, _ = demo_scene(48, n_inputs=2)
    g = g.to(dtype=torch.float32)
    cam = orbit_cameras(3, 64, 48, arc_deg=30.0)[1]
    w = torch.rand(len(g), generator=torch.Generator().manual_seed(0))
    lower = g.opacities * w * (torch.arange(len(g)) % 5 != 0)  # some Gaussians left out
    bg = torch.tensor([0.2, 0.3, 0.4])
    weighted = Gaussians.trusted(g.means, g.quats, g.scales, lower, g.sh, g.views)
    for cap in (None, 0.03):
        plain, colour = render_pair(g, cam, lower, bg, backend, max_radius=cap)
        for got, want in (
            (plain, render(g, cam, bg, backend, max_radius=cap)),
            (colour, render(weighted, cam, bg, backend, max_radius=cap)),
        ):
            for name in ("rgb", "alpha", "depth"):
                assert torch.equal(getattr(got, name), getattr(want, name)), name
            assert torch.equal(got.visible, plain.visible)  # both report the plain render's
    # a view that draws nothing (every Gaussian behind it): the background, twice
    away = Gaussians.trusted(-g.means * 50, g.quats, g.scales, g.opacities, g.sh, g.views)
    plain, colour = render_pair(away, cam, lower, bg, backend)
    for out in (plain, colour):
        assert not out.visible.any() and not out.alpha.any()
        assert torch.equal(out.rgb, bg[:, None, None].expand(3, 48, 64))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_finish_is_its_torch_twin_bitwise(dtype):
    """The one-pass finish (colour over the background, alpha, depth) against the torch
    operations it replaces, with pixels never drawn (T = 1), barely drawn (alpha under the
    1e-6 clamp) and opaque, and a background that is not black."""
    from prosplat.render.cpu import finish, finish_reference

    gen = torch.Generator().manual_seed(5)
    trans = torch.rand(23, 41, generator=gen, dtype=dtype)
    trans[0] = 1.0
    trans[1] = 1.0 - torch.rand(41, generator=gen, dtype=dtype) * 1e-6
    trans[2] = MIN_TRANSMITTANCE
    out = torch.rand(4, 23, 41, generator=gen, dtype=dtype) * (1 - trans)
    out[3] *= 7.0
    bg = torch.tensor([0.2, 0.0, 1.0], dtype=dtype)
    got, want = finish(out, trans, bg), finish_reference(out, trans, bg)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == dtype and torch.equal(a, b)
    assert not got[2][0].any() and (got[1][1] < 1e-6).any()
