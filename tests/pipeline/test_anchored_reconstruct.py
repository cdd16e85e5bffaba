"""``ProSplat.reconstruct(anchors=...)``: each view's depth scaled to the points it observes.

The reference is the same reconstruction without anchors: points placed on each view's rays
at exactly 1.25 times its depth must give depth maps (and Gaussians) 1.25 times as far, with
the depth sweep off so that nothing else moves them."""

from __future__ import annotations

import pytest
import torch

from prosplat import ProSplat, render
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
from prosplat.geometry.anchors import DepthAnchors
from prosplat.pipeline.trust import leave_one_out

SIZE = 64
FACTOR = 1.25


@pytest.fixture(scope="module")
def scene():
    cams = orbit_cameras(4, SIZE, SIZE, arc_deg=40.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    model = ProSplat.from_pretrained(improve=False, depth_sweep=False)
    return model, images, cams


def points_at(rec, factor: float, per_view: int = 40) -> DepthAnchors:
    """``per_view`` points per view on the rays of spread pixels at ``factor`` x its depth."""
    pts, observed = [], []
    g = torch.Generator().manual_seed(0)
    for v, cam in enumerate(rec.cameras):
        depth = rec.depths[v].double()  # [h,w]
        flat = torch.randperm(depth.numel(), generator=g)[:per_view]
        r, c = flat // depth.shape[1], flat % depth.shape[1]
        uv = torch.stack([c.double() + 0.5, r.double() + 0.5], dim=-1)  # [n,2]
        start = sum(len(p) for p in pts)
        pts.append(cam.to(dtype=torch.float64).unproject(uv, factor * depth[r, c]))
        observed.append(torch.arange(start, start + per_view))
    return DepthAnchors(torch.cat(pts), observed)


def test_anchors_scale_each_view_to_its_points(scene):
    model, images, cams = scene
    near, far = 1.0, 20.0
    plain = model.reconstruct(images, cams, near, far, budget="all")
    assert plain.anchor_fits == []
    anchors = points_at(plain, FACTOR)
    rec = model.reconstruct(images, cams, near, far, budget="all", anchors=anchors)
    assert [f.used for f in rec.anchor_fits] == [True] * 4
    assert all(abs(f.scale - FACTOR) < 1e-4 and f.after < 1e-4 for f in rec.anchor_fits)
    torch.testing.assert_close(rec.depths, FACTOR * plain.depths, rtol=1e-4, atol=1e-5)
    # the Gaussians moved along their rays with their depth: same pixel, 1.25x as far
    c = rec.cameras[0].center.to(rec.gaussians.means)
    d0 = (plain.gaussians.means[:100] - c).norm(dim=-1)
    d1 = (rec.gaussians.means[:100] - c).norm(dim=-1)
    torch.testing.assert_close(d1, FACTOR * d0, rtol=1e-4, atol=1e-5)
    # the budget's path takes them too
    pruned = model.reconstruct(images, cams, near, far, anchors=anchors)
    assert [f.used for f in pruned.anchor_fits] == [True] * 4


def test_anchors_must_match_the_views(scene):
    model, images, cams = scene
    plain = model.reconstruct(images, cams, 1.0, 20.0, budget="all")
    anchors = points_at(plain, FACTOR)
    with pytest.raises(ValueError, match=r"anchors.views\(indices\)"):
        model.reconstruct(images[:3], cams[:3], 1.0, 20.0, anchors=anchors)
    # leave-one-out takes each subset's own anchors
    trust = leave_one_out(model, images, cams, 1.0, 20.0, anchors=anchors)
    assert len(trust.model_psnr) == 4
