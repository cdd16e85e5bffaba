"""Tests for prosplat.geometry.merge: flat 2x2 blocks of pixel-aligned Gaussians become one."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from prosplat import Camera, Gaussians, render
from prosplat.geometry.merge import MergeOptions, merge_flat, moment_match
from prosplat.geometry.pixel_gaussians import pixel_gaussians
from prosplat.metrics import psnr
from prosplat.render.projection import quat_to_rotmat

S = 32  # image size


def _plane(size: int = S, tilt: float = 0.2):
    """A camera looking at the plane z = 2 + tilt·x (slanted, so depths vary across the
    image) and each pixel's z-depth [H,W] and world point [H,W,3] on it."""
    f = 0.5 * size / math.tan(math.radians(30))
    cam = Camera.look_at((0.3, -0.2, -1.0), (0.0, 0.0, 2.0), (0.0, -1.0, 0.0), f, size, size)
    dirs = cam.ray_directions(torch.float64)  # [H,W,3]
    o = cam.center.to(torch.float64)
    t = (2 - o[2] + tilt * o[0]) / (dirs[..., 2] - tilt * dirs[..., 0])
    pts = o + dirs * t[..., None]
    depth = (pts - o) @ cam.forward.to(torch.float64)
    return cam, depth, pts


def _smooth_texture(pts):
    """[3,H,W] colours that change by < 0.02 between neighbouring pixels."""
    x, y = pts[..., 0], pts[..., 1]
    return torch.stack(
        [0.5 + 0.2 * torch.sin(2 * x), 0.4 + 0.2 * torch.cos(1.5 * y), 0.3 + 0.1 * torch.sin(x + y)]
    ).float()


def _all(n: int) -> torch.Tensor:
    return torch.ones(n, dtype=torch.bool)


def test_moment_match_equals_brute_force_float64():
    """Mean, covariance, SH and opacity of a merged group against the weighted mixture's
    moments computed directly in float64 (rotation matrices, R S² Rᵀ, outer products)."""
    gen = torch.Generator().manual_seed(1)
    n = 8
    g = Gaussians(
        torch.randn(n, 3, generator=gen, dtype=torch.float64),
        torch.randn(n, 4, generator=gen, dtype=torch.float64),
        torch.rand(n, 3, generator=gen, dtype=torch.float64) * 0.5 + 0.05,
        torch.rand(n, generator=gen, dtype=torch.float64) * 0.9 + 0.05,
        torch.randn(n, 4, 3, generator=gen, dtype=torch.float64),
        torch.arange(n),
    )
    groups = torch.tensor([[0, 1, 2, 3], [7, 5, 6, 4]])
    out = moment_match(g, groups)
    for b, grp in enumerate(groups.tolist()):
        w = g.opacities[grp] / g.opacities[grp].sum()
        mu = sum(w[k] * g.means[i] for k, i in enumerate(grp))
        cov = torch.zeros(3, 3, dtype=torch.float64)
        for k, i in enumerate(grp):
            R = quat_to_rotmat(g.quats[i : i + 1])[0]
            d = (g.means[i] - mu)[:, None]
            cov += w[k] * (R @ torch.diag(g.scales[i] ** 2) @ R.T + d @ d.T)
        R = quat_to_rotmat(out.quats[b : b + 1])[0]
        assert torch.det(R) == pytest.approx(1.0, abs=1e-9)  # a proper rotation
        got = R @ torch.diag(out.scales[b] ** 2) @ R.T
        torch.testing.assert_close(out.means[b], mu, rtol=0, atol=1e-12)
        torch.testing.assert_close(got, cov, rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(out.sh[b], sum(w[k] * g.sh[i] for k, i in enumerate(grp)))
        assert float(out.opacities[b]) == pytest.approx(float(g.opacities[grp].mean()))
        assert int(out.views[b]) == grp[0]


@pytest.mark.parametrize("footprint, opacity", [(0.3, 0.5), (0.5, 0.95), (1.0, 0.5)])
def test_flat_plane_renders_the_same_with_a_quarter_of_the_gaussians(footprint, opacity):
    """A smoothly textured, slanted plane: every block merges (4x fewer Gaussians) and the
    render, from the input view and from a novel one, stays within 35 dB of the unmerged
    one. Plain moment matching (``cover=False``) does not: it lets the background through."""
    size = 48
    cam, depth, pts = _plane(size)
    g = pixel_gaussians(_smooth_texture(pts), depth, cam, footprint, opacity).to(
        dtype=torch.float32
    )
    n = size * size
    options = MergeOptions(color_tol=0.05, depth_tol=0.02)
    merged, view_index, stats = merge_flat(g, _all(n), depth[None].float(), [cam], options)
    assert stats == {"before": n, "after": n // 4, "blocks": n // 4, "blocks4": 0}
    assert len(merged) == len(view_index) == n // 4 and not view_index.any()
    plain, _, _ = merge_flat(g, _all(n), depth[None].float(), [cam], MergeOptions(
        color_tol=0.05, depth_tol=0.02, cover=False))  # fmt: skip
    novel = Camera.look_at((0.5, -0.3, -1.1), (0.0, 0.0, 2.0), (0.0, -1.0, 0.0), cam.fx, size, size)
    inner = (slice(None), slice(6, -6), slice(6, -6))  # the image border: half-covered blocks
    for view in (cam, novel):
        ref = render(g, view).rgb[inner]
        assert float(psnr(render(merged, view).rgb[inner], ref)) > 35
        assert float(psnr(render(plain, view).rgb[inner], ref)) < 30


def test_a_colour_edge_or_a_depth_edge_is_left_alone():
    """A block is merged only when its colours and its depths agree: a one-pixel-column
    colour stripe and a depth step each keep their blocks' Gaussians untouched."""
    cam, depth, pts = _plane()
    image = torch.full((3, S, S), 0.5)
    image[:, :, 9] = 0.9  # colour edge inside the blocks of columns 8-9
    depth = depth.clone()
    depth[17:, :] *= 1.1  # depth step inside the blocks of rows 16-17
    g = pixel_gaussians(image, depth, cam, 0.5, 0.9).to(dtype=torch.float32)
    merged, view_index, stats = merge_flat(g, _all(S * S), depth[None].float(), [cam])
    untouched = torch.zeros(S, S, dtype=torch.bool)
    untouched[:, 8:10] = True
    untouched[16:18, :] = True
    n_blocks = (S // 2) ** 2 - (S // 2 + S // 2 - 1)
    assert stats["blocks"] == n_blocks
    assert stats["after"] == S * S - 3 * n_blocks
    # every Gaussian of an edge block is in the result, bitwise unchanged
    originals = g.means[untouched.reshape(-1)]
    hit = (merged.means[None] == originals[:, None]).all(-1).any(1)
    assert hit.all()


def test_a_block_missing_a_survivor_is_not_merged():
    """A pixel the budget dropped (e.g. a duplicate) leaves its block as it is."""
    cam, depth, _ = _plane()
    g = pixel_gaussians(torch.full((3, S, S), 0.5), depth, cam, 0.5, 0.9).to(dtype=torch.float32)
    keep = _all(S * S)
    keep[0] = False  # the top-left block loses one pixel
    keep[5 * S + 7] = False  # and the block at rows 4-5, columns 6-7
    merged, view_index, stats = merge_flat(g[keep], keep, depth[None].float(), [cam])
    assert stats["blocks"] == (S // 2) ** 2 - 2
    assert (
        stats["after"]
        == stats["before"] - 3 * stats["blocks"]
        == (S * S - 2) - 3 * ((S // 2) ** 2 - 2)
    )
    for pixel in (1, S, S + 1, 4 * S + 6, 4 * S + 7, 5 * S + 6):  # the kept three of each
        assert (merged.means == g.means[pixel]).all(-1).any()


def test_two_levels_merge_flat_4x4_groups_and_stay_view_major():
    """With two views and ``levels=2``, flat 4x4 groups become one Gaussian; the result keeps
    each Gaussian's view (sorted, as the budget's survivors are) and the counts add up."""
    cam, depth, pts = _plane()
    image = torch.full((3, S, S), 0.4)
    g1 = pixel_gaussians(image, depth, cam, 0.5, 0.9)
    views = torch.arange(2).repeat_interleave(S * S)
    g = Gaussians.cat([g1, g1]).with_views(views).to(dtype=torch.float32)
    depths = torch.stack([depth, depth]).float()
    loose = MergeOptions(depth_tol=0.05)  # the slanted plane spans ~3% in a 4x4 group
    one, vi1, s1 = merge_flat(g, _all(2 * S * S), depths, [cam, cam], loose)
    two, vi2, s2 = merge_flat(g, _all(2 * S * S), depths, [cam, cam], replace(loose, levels=2))
    assert s1["blocks"] == s2["blocks"] == 2 * (S // 2) ** 2 and s1["blocks4"] == 0
    assert s2["blocks4"] > 0 and s2["after"] == s1["after"] - 3 * s2["blocks4"]
    for vi in (vi1, vi2):
        assert torch.equal(vi, vi.sort().values) and torch.equal(
            vi.bincount(), torch.tensor([len(vi) // 2] * 2)
        )
    assert torch.equal(two.views, vi2)


def test_empty_input_and_bad_arguments():
    cam, depth, _ = _plane(8)
    g = Gaussians.empty()
    merged, view_index, stats = merge_flat(g, torch.zeros(64, dtype=torch.bool), depth[None], [cam])
    assert len(merged) == 0 and view_index.numel() == 0
    assert stats == {"before": 0, "after": 0, "blocks": 0, "blocks4": 0}
    with pytest.raises(ValueError, match="keep"):
        merge_flat(g, torch.zeros(63, dtype=torch.bool), depth[None], [cam])
    with pytest.raises(ValueError, match="levels"):
        MergeOptions(levels=3).check()
    with pytest.raises(ValueError, match="color_tol"):
        MergeOptions(color_tol=-1).check()


def test_odd_sizes_and_holes_in_depth():
    """An odd last row/column is never merged, nor a block with a pixel of no surface."""
    cam, depth, _ = _plane(9)
    depth = depth.clone()
    depth[0, 0] = 0.0
    g = pixel_gaussians(torch.full((3, 9, 9), 0.5), depth.clamp_min(1.0), cam, 0.5, 0.9)
    merged, _, stats = merge_flat(g, _all(81), depth[None], [cam], MergeOptions(depth_tol=0.2))
    assert stats["blocks"] == 16 - 1  # 4x4 blocks fit in 9x9, the top-left has no surface
    assert len(merged) == 81 - 3 * 15
