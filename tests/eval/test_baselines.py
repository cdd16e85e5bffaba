"""Tests for prosplat.eval.baselines: plane-sweep stereo and per-scene 3DGS optimisation."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from prosplat import Camera, Gaussians
from prosplat.eval.baselines import optimize_gaussians, plane_sweep_depths, plane_sweep_gaussians
from prosplat.eval.baselines.plane_sweep import LATERAL_SCALE, RAY_SCALE
from prosplat.eval.demo_scene import orbit_cameras, raycast, texture
from prosplat.render.projection import quat_to_rotmat

NEAR, FAR = 1.5, 6.0  # brackets every depth of the demo scene from its orbit cameras


def noise_texture(points: torch.Tensor, cell: float = 0.08, seed: int = 0) -> torch.Tensor:
    """[3, ...] colour: trilinear value noise in 3D (non-repetitive, unlike the demo's checks)."""
    gen = torch.Generator().manual_seed(seed)
    n = int(7 / cell) + 2  # lattice over [-3, 4]³, which holds the demo scene
    grid = torch.rand(1, 3, n, n, n, generator=gen, dtype=torch.float64)
    q = (points + 3) / ((n - 1) * cell) * 2 - 1
    out = F.grid_sample(grid, q.reshape(1, -1, 1, 1, 3), align_corners=True)
    return out.reshape(3, *points.shape[:-1])


def demo_views(n_views: int, size: int, tex: str):
    """Exact images of the demo geometry (colour sampled at each pixel centre's surface point)."""
    cams = orbit_cameras(n_views, size, size)
    hits = [raycast(c) for c in cams]
    if tex == "noise":
        images = torch.stack([noise_texture(p) for _, p, _ in hits])
    else:
        images = torch.stack([texture(p, i).permute(2, 0, 1) for _, p, i in hits])
    return images.float(), cams, torch.stack([h[0] for h in hits])


def evaluation_mask(images, cams, gt):
    """[V,H,W]: textured pixels (5x5 std > 0.03) whose surface another view sees (2% depth)."""
    mu = F.avg_pool2d(images, 5, 1, 2, count_include_pad=False)
    var = (F.avg_pool2d(images * images, 5, 1, 2, count_include_pad=False) - mu * mu).sum(1)
    masks = []
    for r, cam in enumerate(cams):
        pts = cam.unproject(cam.pixel_centers(torch.float64), gt[r])
        seen = torch.zeros(gt.shape[1:], dtype=torch.bool)
        for s, other in enumerate(cams):
            if s != r:
                uv, z = other.project(pts)
                col, row = uv[..., 0].floor().long(), uv[..., 1].floor().long()
                inside = (
                    (z > 0) & (col >= 0) & (col < other.width) & (row >= 0) & (row < other.height)
                )
                d = gt[s][row.clamp(0, other.height - 1), col.clamp(0, other.width - 1)]
                seen |= inside & ((d - z).abs() < 0.02 * z)
        masks.append(seen)
    return torch.stack(masks) & (var.clamp_min(0).sqrt() > 0.03)


@pytest.mark.parametrize(("n_views", "tex", "limit"), [(2, "noise", 0.03), (3, "demo", 0.05)])
def test_plane_sweep_recovers_depth(n_views, tex, limit):
    images, cams, gt = demo_views(n_views, 64, tex)
    g, depth, conf = plane_sweep_gaussians(images, cams, NEAR, FAR, n_depths=64)
    rel = (depth.double() - gt).abs() / gt
    mask = evaluation_mask(images, cams, gt)
    med = float(rel[mask].median())
    med_conf = float(rel[mask & (conf > 0.5)].median())
    print(
        f"\n{n_views} views, {tex} texture: median rel. depth error {med:.4f} on {float(mask.float().mean()):.0%}"
        f" of pixels; {med_conf:.4f} where confidence > 0.5"
    )
    assert med < limit
    assert med_conf <= med  # confidence ranks reliability
    assert ((conf >= 0) & (conf <= 1)).all()

    # Layout: view-major, row-major; every mean lies on its pixel's ray at its depth.
    assert len(g) == n_views * 64 * 64
    for v, cam in enumerate(cams):
        sl = slice(v * 64 * 64, (v + 1) * 64 * 64)
        uv, z = cam.project(g.means[sl].double())
        torch.testing.assert_close(
            uv, cam.pixel_centers(torch.float64).reshape(-1, 2), atol=2e-3, rtol=0
        )
        torch.testing.assert_close(z, depth[v].reshape(-1).double(), atol=1e-5, rtol=1e-5)
        # Thin axis along the ray: 0.1 footprint there, 0.7 across.
        foot = z / cam.fx
        torch.testing.assert_close(
            g.scales[sl].double(),
            foot[:, None]
            * torch.tensor([LATERAL_SCALE, LATERAL_SCALE, RAY_SCALE], dtype=torch.float64),
            rtol=1e-5,
            atol=1e-7,
        )
        axis = quat_to_rotmat(g.quats[sl].double())[:, :, 2]
        ray = F.normalize(g.means[sl].double() - cam.center, dim=1)
        assert ((axis * ray).sum(1) > 1 - 1e-5).all()


@pytest.mark.parametrize("case", ["identical_views", "constant_images", "single_view"])
def test_plane_sweep_degenerate_inputs_are_finite(case):
    cams = orbit_cameras(2, 24, 24)
    images, _, _ = demo_views(2, 24, "demo")
    if case == "identical_views":
        cams, images = [cams[0], cams[0]], images[[0, 0]]
    elif case == "constant_images":
        images = torch.full_like(images, 0.4)
    else:
        cams, images = cams[:1], images[:1]
    g, depth, conf = plane_sweep_gaussians(images, cams, NEAR, FAR, n_depths=16)
    assert all(torch.isfinite(t).all() for t in g.tensors().values())
    assert (
        torch.isfinite(depth).all()
        and (depth >= NEAR * 0.999).all()
        and (depth <= FAR * 1.001).all()
    )
    assert (conf < 1e-3).all(), "nothing to match: no confidence"


def test_plane_sweep_rejects_bad_input():
    images, cams, _ = demo_views(2, 16, "demo")
    with pytest.raises(ValueError, match="cameras"):
        plane_sweep_depths(images, cams[:1], NEAR, FAR)
    with pytest.raises(ValueError, match="near"):
        plane_sweep_depths(images, cams, FAR, NEAR)
    with pytest.raises(ValueError, match="images"):
        plane_sweep_depths(images[:, :2], cams, NEAR, FAR)
    with pytest.raises(ValueError, match="cameras"):
        plane_sweep_depths(images, [c.resized(8, 8) for c in cams], NEAR, FAR)


@pytest.mark.parametrize("init", ["plane_sweep", "random"])
def test_optimize_lowers_loss(init):
    images, cams, _ = demo_views(2, 32, "demo")
    g, stats = optimize_gaussians(images, cams, NEAR, FAR, steps=50, init=init, seed=0)
    assert isinstance(g, Gaussians) and len(g) == 2 * 32 * 32
    g.validate()
    assert not g.means.requires_grad
    assert stats["steps"] == 50 and len(stats["loss_history"]) == 50
    assert stats["final_loss"] < stats["initial_loss"]
    print(
        f"\n{init}: loss {stats['initial_loss']:.4f} -> {stats['final_loss']:.4f}, "
        f"{stats['s_per_step'] * 1e3:.1f} ms/step at 2x32²"
    )


def test_optimize_is_deterministic_for_a_seed():
    images, cams, _ = demo_views(2, 24, "demo")
    threads = torch.get_num_threads()

    def run(seed):
        return optimize_gaussians(
            images, cams, NEAR, FAR, steps=10, init="random", seed=seed, deterministic=True
        )

    (a, sa), (b, sb), (c, _) = run(3), run(3), run(4)
    assert torch.get_num_threads() == threads  # restored
    for name, value in a.tensors().items():
        assert torch.equal(value, b.tensors()[name]), name
    assert sa["final_loss"] == sb["final_loss"]
    assert not torch.allclose(a.means, c.means)


def test_optimize_rejects_bad_input():
    images, cams, _ = demo_views(2, 16, "demo")
    with pytest.raises(ValueError, match="init"):
        optimize_gaussians(images, cams, NEAR, FAR, steps=1, init="sfm")
    with pytest.raises(ValueError, match="11x11"):
        optimize_gaussians(images[..., :8, :8], [c.resized(8, 8) for c in cams], NEAR, FAR, steps=1)
    with pytest.raises(ValueError, match="cameras"):
        optimize_gaussians(
            images, [Camera.from_intrinsics(10, 10, 8, 8, 16, 16)], NEAR, FAR, steps=1
        )


def test_box_mean_is_the_pooling_it_replaces():
    """matching.box_mean (running sums) against avg_pool2d with shrinking border windows, on
    odd sizes, batches and a non-contiguous view (how the sweep calls it)."""
    import torch.nn.functional as F

    from prosplat.geometry.matching import WINDOW, box_mean

    g = torch.Generator().manual_seed(0)
    for shape in ((1, 3, 7, 5), (4, 1, 33, 64), (2, 3, 3, 3)):
        x = torch.rand(shape, generator=g)
        ref = F.avg_pool2d(x, WINDOW, stride=1, padding=WINDOW // 2, count_include_pad=False)
        assert torch.allclose(box_mean(x), ref, atol=2e-6), shape
    for window in (1, 3, 7):  # the generator's image cost volume picks its own window
        x = torch.rand(2, 3, 9, 11, generator=g)
        ref = F.avg_pool2d(x, window, stride=1, padding=window // 2, count_include_pad=False)
        assert torch.allclose(box_mean(x, window), ref, atol=2e-6), window
    # sides where every window is cut (7 < 2·3 + 2), where just one is not (8), and a
    # [N,C,D,H,W] stack of planes as the ZNCC sweep filters it
    for shape in ((1, 1, 7, 7), (1, 2, 8, 7), (2, 2, 3, 8, 9)):
        x = torch.rand(shape, generator=g)
        flat = x.reshape(-1, *shape[-2:])
        ref = F.avg_pool2d(flat, 7, stride=1, padding=3, count_include_pad=False)
        assert torch.allclose(box_mean(x, 7), ref.view(shape), atol=2e-6), shape
    with pytest.raises(ValueError, match="odd"):
        box_mean(x, 4)
    x = torch.rand(3, 5, 16, 16, generator=g).transpose(0, 1)
    ref = F.avg_pool2d(x, WINDOW, stride=1, padding=WINDOW // 2, count_include_pad=False)
    assert torch.allclose(box_mean(x), ref, atol=2e-6)


@pytest.mark.parametrize("best_views", [None, 1])
def test_zncc_cost_in_chunks_of_planes_is_the_whole_cost(best_views, monkeypatch):
    """The sweep warps a chunk of candidates at a time (_CHUNK_PIXELS, small for speed):
    chunks of 2 of 5 planes (a short last one), summed or kept per view for the best-view
    selection, give the cost of all planes at once, bit for bit."""
    from prosplat.geometry import matching as plane_sweep

    images, cams, _ = demo_views(3, 24, "noise")
    depths = torch.linspace(2.5, 6.0, 5)
    whole = plane_sweep.zncc_cost(images, cams, 0, depths, best_views=best_views)  # [5,24,24]
    monkeypatch.setattr(plane_sweep, "_CHUNK_PIXELS", 2 * 24 * 24)
    chunked = plane_sweep.zncc_cost(images, cams, 0, depths, best_views=best_views)
    assert torch.equal(chunked, whole)
    assert whole.amin() < 0.5  # some candidate matched
