"""Tests for prosplat.geometry.budget.prune_gaussians on the analytic demo scene (exact depth)."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera, Gaussians, render
from prosplat.data.overlap import covisibility
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians, raycast
from prosplat.geometry.budget import (
    DEDUP_ANGLE,
    _budget_count,
    _dither_rank,
    bilinear_depth,
    budget_arg,
    importance,
    prune_gaussians,
    prune_pixel_aligned,
)
from prosplat.metrics import psnr

S = 64  # image size of the demo views
HW = S * S


@pytest.fixture(scope="module")
def scene():
    """Two wide-baseline views, their N = 2·64·64 pixel-aligned Gaussians and exact depths."""
    cams = orbit_cameras(2, S, S)
    g = pixel_aligned_gaussians(cams)
    depths = torch.stack([raycast(c)[0] for c in cams])  # [2,H,W] float64
    view_index = torch.arange(2).repeat_interleave(HW)
    return g, view_index, depths, cams


def _visible_in(src, src_depth, dst, dst_depth, rel_tol=0.02):
    """[H*W] bool per pixel of ``src``: its surface point is seen by ``dst`` (covisibility's rule)."""
    pts = src.unproject(src.pixel_centers(torch.float64), src_depth)
    uv, z = dst.project(pts)
    col, row = uv[..., 0].floor().long(), uv[..., 1].floor().long()
    inside = (z > 0) & (col >= 0) & (col < dst.width) & (row >= 0) & (row < dst.height)
    d = dst_depth[row.clamp(0, dst.height - 1), col.clamp(0, dst.width - 1)]
    return (inside & ((d - z).abs() <= rel_tol * z)).reshape(-1)


def test_duplicates_keep_the_copy_of_the_closer_view(scene):
    """Of a surface both views see, the copy of the view nearer to it (more pixels per unit
    length, same focal length here) is kept and the other dropped; what only one view sees
    is kept. (The views see their shared points 16-74 degrees apart: the angle limit is
    opened here, and tested on its own below.)"""
    g, vi, depths, cams = scene
    _, keep, stats = prune_gaussians(g, vi, depths, cams, dedup_angle=180)
    assert stats["input"] == 2 * HW
    assert stats["kept"] == int(keep.sum()) == 2 * HW - stats["duplicate"]
    assert stats["transparent"] == stats["out_of_bounds"] == stats["over_budget"] == 0
    assert torch.equal(cams[0].K, cams[1].K)  # resolution differs by distance alone
    means = g.means.double()
    for j, i in [(0, 1), (1, 0)]:
        own = slice(j * HW, (j + 1) * HW)
        dropped = ~keep[own]
        _, z_own = cams[j].project(means[own])
        _, z_other = cams[i].project(means[own])
        seen = _visible_in(cams[j], depths[j], cams[i], depths[i])
        other_closer = seen & (z_other < z_own / 1.05)
        own_closer = seen & (z_other > z_own * 1.05)
        assert other_closer.sum() > 500 and own_closer.sum() > 500  # both cases occur
        assert dropped[other_closer].all(), "a copy the closer view also holds must go"
        assert not dropped[own_closer].any(), "the closer view's copy must stay"
        _, _, _, inside = cams[i].nearest_pixels(means[own])
        assert not dropped[~inside].any()  # outside the other image: nobody else has it
        seen_loosely = _visible_in(cams[j], depths[j], cams[i], depths[i], rel_tol=0.05)
        assert float(seen_loosely[dropped].float().mean()) > 0.9  # drops are shared surface
    # Each shared surface point is kept once: about 1 - covisibility of the pixels go.
    cov = covisibility(cams[1], depths[1], cams[0], depths[0])
    assert 0.55 < cov < 0.65 and stats["duplicate"] > 0.75 * cov * HW


def _ray_cos(means: torch.Tensor, a: Camera, b: Camera) -> torch.Tensor:
    """[N] cosine of the angle between the rays from cameras a and b to each point."""
    ra, rb = means - a.center.double(), means - b.center.double()
    return (ra * rb).sum(1) / (ra.norm(dim=1) * rb.norm(dim=1))


@pytest.mark.parametrize("limit", [30.0, 45.0])
def test_duplicates_only_between_views_that_see_the_point_alike(scene, limit):
    """Two views' copies count as one surface only where their rays to it lie within
    ``dedup_angle``: between views far apart the depth test's slack along one view's ray is a
    sideways shift in the other's, and the kept copy leaves cracks. The drops are exactly the
    open test's drops within the limit (two views: each point is asked of one other view)."""
    g, vi, depths, cams = scene
    cos = _ray_cos(g.means.double(), cams[0], cams[1])  # [N]
    near = cos >= math.cos(math.radians(limit))
    assert 200 < int(near.sum()) < len(g) - 200  # both kinds of point occur
    _, keep_open, _ = prune_gaussians(g, vi, depths, cams, dedup_angle=180)
    _, keep, stats = prune_gaussians(g, vi, depths, cams, dedup_angle=limit)
    assert torch.equal(~keep, ~keep_open & near)
    assert 0 < stats["duplicate"] < int((~keep_open).sum())
    _, keep_none, stats = prune_gaussians(g, vi, depths, cams, dedup_angle=0)
    assert stats["duplicate"] == 0 and bool(keep_none.all())
    _, keep_default, _ = prune_gaussians(g, vi, depths, cams)
    near_default = cos >= math.cos(math.radians(DEDUP_ANGLE))
    assert torch.equal(~keep_default, ~keep_open & near_default)


def test_the_nearer_camera_keeps_a_plane_whatever_the_view_order():
    """Two cameras facing a plane, 2 and 4 units away: the far view's Gaussians inside the
    near view's image are the duplicates (the near view sees them at twice the resolution),
    and listing the views the other way round keeps the same Gaussians."""
    size, f = 32, 32.0
    cams, gs, depths = [], [], []
    for dist in (2.0, 4.0):
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[2, 3] = dist  # plane z = 0, camera at z = -dist looking down +z
        cam = Camera.from_intrinsics(f, f, size / 2, size / 2, size, size, w2c)
        depth = torch.full((size, size), dist, dtype=torch.float64)
        pts = cam.unproject(cam.pixel_centers(torch.float64), depth).reshape(-1, 3).float()
        n = pts.shape[0]
        scales = torch.full((n, 3), dist / f / 2)
        quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
        gs.append(Gaussians(pts, quats, scales, torch.full((n,), 0.9), torch.zeros(n, 1, 3)))
        cams.append(cam)
        depths.append(depth)
    n = size * size
    vi = torch.arange(2).repeat_interleave(n)
    _, keep, stats = prune_gaussians(Gaussians.cat(gs), vi, torch.stack(depths), cams)
    far_pts = gs[1].means.double()
    _, _, _, in_near = cams[0].nearest_pixels(far_pts)
    assert keep[:n].all()  # the near view loses nothing
    assert torch.equal(~keep[n:], in_near)  # the far view loses exactly the shared quarter
    assert stats["duplicate"] == int(in_near.sum()) == n // 4

    swapped = Gaussians.cat([gs[1], gs[0]])
    _, keep_sw, _ = prune_gaussians(swapped, vi, torch.stack(depths[::-1]), cams[::-1])
    assert torch.equal(keep_sw, torch.cat([keep[n:], keep[:n]]))


def test_bilinear_depth_read_is_exact_on_linear_maps_and_replicates_borders():
    h, w = 5, 7
    rows, cols = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    dmap = (2.0 + 0.5 * cols + 0.25 * rows).double()  # depth at pixel centre (c+.5, r+.5)
    uv = torch.tensor([[0.5, 0.5], [3.2, 1.7], [6.5, 4.5], [1.0, 2.0]], dtype=torch.float64)
    value, corners = bilinear_depth(dmap, uv)
    expect = 2.0 + 0.5 * (uv[:, 0] - 0.5) + 0.25 * (uv[:, 1] - 0.5)
    torch.testing.assert_close(value, expect)
    # the 2x2 pixels around the point (their spread is the slope term of the duplicate test)
    assert corners.shape == (4, 4) and torch.equal(corners[1], dmap[1:3, 2:4].reshape(-1))
    edge, _ = bilinear_depth(dmap, torch.tensor([[0.1, 0.2], [6.9, 4.9]], dtype=torch.float64))
    torch.testing.assert_close(edge, torch.stack([dmap[0, 0], dmap[-1, -1]]))


def test_pruned_render_barely_changes(scene):
    g, vi, depths, cams = scene
    pruned, _, _ = prune_gaussians(g, vi, depths, cams)
    novel = orbit_cameras(3, S, S)[1]  # halfway between the two inputs
    full = render(g, novel).rgb
    value = float(psnr(render(pruned, novel).rgb, full))
    print(f"\nPSNR of the pruned vs unpruned render from a third camera: {value:.2f} dB")
    assert value > 30


def test_transparent_and_out_of_bounds_removed(scene):
    g, vi, depths, cams = scene
    v0 = g[:HW]
    gen = torch.Generator().manual_seed(0)
    pick = torch.randperm(HW, generator=gen)[:300]
    faint = v0[pick[:100]]
    faint = Gaussians(faint.means, faint.quats, faint.scales, faint.opacities * 0 + 1e-3, faint.sh)
    # Floaters on view 0's rays at depth 0.3 (before near) and 50 (beyond far).
    uv = cams[0].pixel_centers(torch.float64).reshape(-1, 2)[pick[100:300]]
    z = torch.cat([torch.full((100,), 0.3), torch.full((100,), 50.0)]).double()
    floaters = v0[pick[100:300]]
    floaters = Gaussians(
        cams[0].unproject(uv, z).float(),
        floaters.quats,
        floaters.scales,
        floaters.opacities,
        floaters.sh,
    )
    mixed = Gaussians.cat([g, faint, floaters])
    vi_mixed = torch.cat([vi, torch.zeros(300, dtype=torch.long)])
    _, keep, stats = prune_gaussians(mixed, vi_mixed, depths, cams, near=0.5, far=10.0)
    assert stats["transparent"] == 100 and stats["out_of_bounds"] == 200
    assert not keep[2 * HW :].any()
    _, keep_ref, _ = prune_gaussians(g, vi, depths, cams, near=0.5, far=10.0)
    assert torch.equal(keep[: 2 * HW], keep_ref)  # the scene itself lies within [near, far]

    # An AABB that cuts off the back wall (z = 3) removes exactly the Gaussians beyond it.
    lo, hi = (-10.0, -10.0, -10.0), (10.0, 10.0, 2.9)
    _, keep_box, stats_box = prune_gaussians(g, vi, depths, cams, bounds=(lo, hi))
    assert stats_box["out_of_bounds"] == int((g.means[:, 2] > 2.9).sum()) > 0
    assert not keep_box[g.means[:, 2] > 2.9].any()


def test_default_opacity_threshold_is_lossless(scene):
    g, vi, depths, cams = scene
    faint = g[:500]
    faint = Gaussians(
        faint.means + 0.01, faint.quats, faint.scales * 3, faint.opacities * 0 + 0.003, faint.sh
    )
    mixed = Gaussians.cat([g, faint])
    vi_mixed = torch.cat([vi, torch.zeros(500, dtype=torch.long)])
    pruned, _, stats = prune_gaussians(mixed, vi_mixed, depths, cams, dedup_tol=None)
    assert stats["transparent"] == 500
    cam = orbit_cameras(3, S, S)[1]
    torch.testing.assert_close(render(pruned, cam).rgb, render(mixed, cam).rgb, atol=1e-6, rtol=0)


@pytest.mark.parametrize("budget", [1000, 0.25, 0, 10**6])
def test_budget_keeps_that_many_in_dither_order_and_enlarges_them(scene, budget):
    g, vi, depths, cams = scene
    _, keep_auto, auto = prune_gaussians(g, vi, depths, cams)
    pruned, keep, stats = prune_gaussians(g, vi, depths, cams, budget=budget)
    want = budget if isinstance(budget, int) else math.floor(budget * 2 * HW)
    assert stats["kept"] == int(keep.sum()) == len(pruned) == min(want, auto["kept"])
    assert stats["over_budget"] == auto["kept"] - stats["kept"]
    assert not (keep & ~keep_auto).any()  # the budget only removes more
    if 0 < stats["kept"] < auto["kept"]:
        rank = _dither_rank(S, S, "cpu").reshape(-1).repeat(2)
        assert rank[keep].max() <= rank[keep_auto & ~keep].min()  # the even lattice first
        for v in range(2):
            grow = math.sqrt(int((keep_auto & (vi == v)).sum()) / int((keep & (vi == v)).sum()))
            mine = (vi == v)[keep]
            torch.testing.assert_close(pruned.scales[mine], g.scales[keep][mine] * grow)
    elif stats["kept"] == auto["kept"]:
        torch.testing.assert_close(pruned.scales, g.scales[keep])


def test_dither_rank_is_an_even_lattice_at_every_level():
    rank = _dither_rank(8, 8, "cpu")
    assert sorted(rank.reshape(-1).tolist()) == list(range(64))
    assert torch.equal(rank[:2, :2], torch.tensor([[0, 32], [48, 16]]))  # Bayer 8x8 corner
    quarter = rank < 16  # 1/4: one pixel of every 2x2 block
    assert (quarter.reshape(4, 2, 4, 2).sum(dim=(1, 3)) == 1).all()


def test_a_thinned_budget_renders_closer_than_dropping_by_importance(scene):
    """Holes cost more than a coarser even sampling: the budget's render at 1/4 of the
    Gaussians is closer to the unpruned render than keeping the most important quarter."""
    g, vi, depths, cams = scene
    cam = orbit_cameras(3, S, S)[1]
    full = render(g, cam).rgb
    pruned, keep, _ = prune_gaussians(g, vi, depths, cams, budget=0.25)
    by_importance = torch.argsort(importance(g, vi, cams), descending=True)[: len(pruned)]
    even = float(psnr(render(pruned, cam).rgb, full))
    holes = float(psnr(render(g[by_importance], cam).rgb, full))
    assert even > holes + 3.0, (even, holes)


def test_empty_input(scene):
    _, _, depths, cams = scene
    pruned, keep, stats = prune_gaussians(
        Gaussians.empty(),
        torch.zeros(0, dtype=torch.long),
        depths,
        cams,
        near=0.5,
        far=10,
        budget=10,
    )
    assert len(pruned) == 0 and keep.shape == (0,) and keep.dtype == torch.bool
    assert stats == {
        "input": 0,
        "transparent": 0,
        "out_of_bounds": 0,
        "duplicate": 0,
        "over_budget": 0,
        "kept": 0,
    }


@pytest.mark.parametrize(
    ("change", "name"),
    [
        (lambda a: {**a, "view_index": a["view_index"][:-1]}, "view_index"),
        (lambda a: {**a, "view_index": a["view_index"].float()}, "view_index"),
        (lambda a: {**a, "view_index": a["view_index"] + 1}, "view_index"),
        (lambda a: {**a, "depths": a["depths"][:1]}, "depths"),
        (lambda a: {**a, "depths": a["depths"][:, :-1]}, "depths"),
        (lambda a: {**a, "budget": 1.5}, "budget"),
        (lambda a: {**a, "budget": True}, "budget"),
        (lambda a: {**a, "near": 5.0, "far": 1.0}, "near"),
        (lambda a: {**a, "bounds": ((1, 1, 1), (0, 0, 0))}, "bounds"),
        (lambda a: {**a, "dedup_tol": -0.1}, "dedup_tol"),
        (lambda a: {**a, "dedup_px": float("nan")}, "dedup_px"),
        (lambda a: {**a, "dedup_angle": 181.0}, "dedup_angle"),
        (lambda a: {**a, "dedup_angle": float("nan")}, "dedup_angle"),
    ],
)
def test_invalid_arguments_name_themselves(scene, change, name):
    g, vi, depths, cams = scene
    args = change({"gaussians": g, "view_index": vi, "depths": depths, "cameras": cams})
    with pytest.raises(ValueError, match=name):
        prune_gaussians(**args)


def test_prune_pixel_aligned_derives_the_view_index_from_the_depth_maps(scene):
    g, vi, depths, cams = scene
    _, keep, stats = prune_gaussians(g, vi, depths, cams, budget=0.3)
    pruned, keep2, stats2 = prune_pixel_aligned(g, depths, cams, budget=0.3)
    assert torch.equal(keep, keep2) and stats == stats2 and len(pruned) == stats["kept"]


def test_budget_arg_reads_a_count_or_a_fraction_as_the_pruning_does():
    """``--budget 300`` keeps 300 Gaussians, ``--budget 0.25`` a quarter, none: automatic."""
    assert budget_arg(None) is None
    count, fraction, whole = budget_arg(300.0), budget_arg(0.25), budget_arg(1.0)
    assert isinstance(count, int) and count == 300
    assert isinstance(fraction, float) and isinstance(whole, float)
    assert [_budget_count(b, 1000) for b in (count, fraction, whole)] == [300, 250, 1000]
