"""The stage-1 generator: shapes, geometry conventions, gradients, degenerate inputs, checkpoints."""

from __future__ import annotations

import math
import os

import pytest
import torch

import prosplat.pipeline.model as pipeline
from prosplat import Camera, render
from prosplat.core.gaussians import rgb_to_sh0
from prosplat.core.rotations import rotmat_to_quat
from prosplat.generator import BASE, TINY, Generator, GeneratorConfig
from prosplat.generator.adapter import GaussianAdapter
from prosplat.generator.cost_volume import (
    inverse_depth_candidates,
    nearest_views,
    plane_sweep_cost_volume,
    scale_intrinsics,
    warp_grid,
)
from prosplat.geometry.rig import near_far_from_cameras
from prosplat.pipeline.model import ProSplat
from prosplat.render.projection import quat_to_rotmat

# Smaller than TINY so every test runs in well under a second on 2 cores; SH degree 1 and k=2
# neighbours so that the higher-SH head and the k-nearest selection are exercised.
SMALL = GeneratorConfig(
    feature_channels=16,
    num_depth_candidates=8,
    attention_layers=2,
    attention_heads=2,
    attention_splits=2,
    attention_mlp_ratio=2,
    cost_volume_views=2,
    mono_channels=8,
    mono_blocks=1,
    unet_channels=(8, 8, 16),
    refine_channels=8,
    sh_degree=1,
)
NEAR, FAR = 1.0, 10.0


def rig(v: int, w: int, h: int, radius: float = 4.0, arc: float = 40.0) -> list[Camera]:
    """``v`` cameras on an arc round the origin, looking at it."""
    cams = []
    for i in range(v):
        a = math.radians(-arc / 2 + arc * i / max(v - 1, 1))
        eye = (radius * math.sin(a), 0.3 * (i % 2), -radius * math.cos(a))
        cams.append(Camera.look_at(eye, (0, 0, 0), (0, -1, 0), 0.9 * w, w, h))
    return cams


def batch(cams: list[Camera], seed: int = 0, b: int = 1):
    g = torch.Generator().manual_seed(seed)
    w, h = cams[0].width, cams[0].height
    images = torch.rand(b, len(cams), 3, h, w, generator=g)
    K = torch.stack([c.K.float() for c in cams])[None].expand(b, -1, -1, -1)
    w2c = torch.stack([c.world_to_cam.float() for c in cams])[None].expand(b, -1, -1, -1)
    return images, K, w2c


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one thread is faster


@pytest.fixture(scope="module")
def model(one_thread) -> Generator:
    torch.manual_seed(0)
    return Generator(SMALL).eval()


# ---- shapes and determinism ----------------------------------------------------------------
@pytest.mark.parametrize("v,w,h,b", [(2, 32, 32, 2), (3, 64, 32, 1), (4, 32, 64, 1)])
def test_output_shapes_and_ranges(model, v, w, h, b):
    images, K, w2c = batch(rig(v, w, h), b=b)
    with torch.no_grad():
        out = model(images, K, w2c, torch.full((b,), NEAR), torch.full((b,), FAR))
    n = v * h * w
    k = SMALL.sh_coefficients
    assert out.means.shape == (b, n, 3) and out.quats.shape == (b, n, 4)
    assert out.scales.shape == (b, n, 3) and out.opacities.shape == (b, n)
    assert out.sh.shape == (b, n, k, 3)
    assert out.depths.shape == (b, v, h, w) and out.confidence.shape == (b, v, h, w)
    for t in (out.means, out.quats, out.scales, out.opacities, out.sh, out.depths):
        assert torch.isfinite(t).all()
    assert (out.depths >= NEAR * (1 - 1e-5)).all() and (out.depths <= FAR * (1 + 1e-5)).all()
    assert (out.confidence >= 1 / SMALL.num_depth_candidates - 1e-6).all()
    assert (out.confidence <= 1 + 1e-6).all()
    assert (out.scales > 0).all() and ((out.opacities > 0) & (out.opacities < 1)).all()
    assert torch.allclose(out.quats.norm(dim=-1), torch.ones(b, n), atol=1e-5)
    assert len(out.gaussians(b - 1)) == n


def test_deterministic_in_eval_mode(model):
    images, K, w2c = batch(rig(3, 32, 32))
    with torch.no_grad():
        a = model(images, K, w2c, NEAR, FAR)
        b = model(images, K, w2c, NEAR, FAR)
    for name in ("means", "quats", "scales", "opacities", "sh", "depths", "confidence"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


def test_means_lie_on_their_pixel_rays_view_major(model):
    """Gaussian v*H*W + r*W + c projects into camera v within the ±0.5 px offset of pixel
    (c, r)'s centre, at that view's predicted depth."""
    v, w, h = 2, 64, 32
    cams = rig(v, w, h)
    images, K, w2c = batch(cams)
    with torch.no_grad():
        out = model(images, K, w2c, NEAR, FAR)
    means = out.means[0].view(v, h, w, 3)
    for i, cam in enumerate(cams):
        uv, z = cam.project(means[i].double())
        centres = cam.pixel_centers(torch.float64)
        assert (uv - centres).abs().max() <= SMALL.max_offset_px + 1e-3
        assert torch.allclose(z.float(), out.depths[0, i], rtol=1e-4)


def test_match_size_matches_small_and_places_gaussians_at_full_size(model):
    """``match_size``: the network up to the refiner runs on the images resized to it, so its
    inverse depth is the small run's, bilinearly upsampled (inverse depth is affine in the
    refiner's output); every full-size pixel gets its Gaussian on its own ray, coloured from
    its own pixel. The full size itself as ``match_size`` changes nothing."""
    v, w, h = 2, 64, 64
    cams = rig(v, w, h)
    images, K, w2c = batch(cams)
    small = torch.nn.functional.interpolate(
        images[0], size=(32, 32), mode="bilinear", antialias=True, align_corners=False
    ).clamp(0, 1)[None]
    K_small = scale_intrinsics(K, 0.5, 0.5)
    with torch.no_grad():
        lo = model(small, K_small, w2c, NEAR, FAR)
        hi = model(images, K, w2c, NEAR, FAR, match_size=(32, 32))
        same = model(images, K, w2c, NEAR, FAR, match_size=(h, w))
        full = model(images, K, w2c, NEAR, FAR)
    assert hi.means.shape == (1, v * h * w, 3) and hi.depths.shape == (1, v, h, w)
    up = torch.nn.functional.interpolate(
        1 / lo.depths[0][:, None], size=(h, w), mode="bilinear", align_corners=False
    )[:, 0]
    assert torch.allclose(1 / hi.depths[0], up, rtol=1e-4, atol=1e-6)
    assert not torch.allclose(hi.depths, full.depths, rtol=1e-2)  # it did not run at 64 px
    for name in ("means", "sh", "depths"):
        assert torch.equal(getattr(same, name), getattr(full, name)), name
    means = hi.means[0].view(v, h, w, 3)
    for i, cam in enumerate(cams):
        uv, z = cam.project(means[i].double())
        assert (uv - cam.pixel_centers(torch.float64)).abs().max() <= SMALL.max_offset_px + 1e-3
        assert torch.allclose(z.float(), hi.depths[0, i], rtol=1e-4)
    # colour: the full-size pixel plus a residual; a pixel made brighter gets a brighter Gaussian
    brighter = images.clone()
    brighter[0, 0, :, 10, 10] = (brighter[0, 0, :, 10, 10] + 0.5).clamp(max=1)
    with torch.no_grad():
        hi2 = model(brighter, K, w2c, NEAR, FAR, match_size=(32, 32))
    k = 10 * w + 10
    assert (hi2.sh[0, k, 0] - hi.sh[0, k, 0]).sum() > 0.5 * (
        rgb_to_sh0(brighter[0, 0, :, 10, 10]) - rgb_to_sh0(images[0, 0, :, 10, 10])
    ).sum()
    for bad in ((48, 32), (32, 128), (0, 32)):
        with pytest.raises(ValueError, match="match_size"):
            model(images, K, w2c, NEAR, FAR, match_size=bad)


# ---- gradients and one optimisation step ---------------------------------------------------
def render_loss(model: Generator, images, K, w2c, target_cam, target_rgb):
    out = model(images, K, w2c, NEAR, FAR)
    rgb = render(out.gaussians(0), target_cam, torch.tensor([0.5, 0.5, 0.5])).rgb
    return torch.nn.functional.mse_loss(rgb, target_rgb)


def test_gradients_reach_every_parameter():
    torch.manual_seed(1)
    model = Generator(SMALL).train()
    cams = rig(3, 32, 32)
    images, K, w2c = batch(cams[::2])  # inputs: the two outer cameras; target: the middle one
    target = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(5))
    render_loss(model, images, K, w2c, cams[1], target).backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None]
    assert not missing, f"no gradient reaches {missing}"
    bad = [n for n, p in model.named_parameters() if not torch.isfinite(p.grad).all()]
    assert not bad, f"non-finite gradients in {bad}"
    # No exceptions are needed: the only zero-initialised layer (adapter.sh_rest, the higher SH
    # bands) still gets a gradient on its own weights because degree-1 SH are rendered.
    zero = [n for n, p in model.named_parameters() if p.grad.abs().max() == 0]
    assert not zero, f"zero gradient for {zero}"


def test_one_adam_step_lowers_the_render_loss():
    torch.manual_seed(2)
    model = Generator(SMALL).train()
    cams = rig(3, 32, 32)
    images, K, w2c = batch(cams[::2], seed=3)
    target = images[0, 0] * 0.5 + 0.25  # a learnable kind of target: a dimmed input view
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    loss0 = render_loss(model, images, K, w2c, cams[1], target)
    loss0.backward()
    opt.step()
    with torch.no_grad():
        loss1 = render_loss(model, images, K, w2c, cams[1], target)
    assert loss1 < loss0 * 0.999, (loss0.item(), loss1.item())


# ---- cost volume geometry ------------------------------------------------------------------
def plane_features(cam: Camera, z0: float, channels: int = 16) -> torch.Tensor:
    """[C,H,W] 'image-like' features of the world plane z = z0 as seen by ``cam``: pairs of
    cos/sin of plane waves of different frequencies and directions, so every feature vector has
    the same norm and the dot product is largest exactly where the two views see the same point.
    """
    g = torch.Generator().manual_seed(7)
    o = cam.center.double()
    d = cam.ray_directions(torch.float64)  # [H,W,3] through pixel centres
    s = (z0 - o[2]) / d[..., 2]
    xy = (o + s[..., None] * d)[..., :2]  # [H,W,2] on the plane
    ang = torch.rand(channels // 2, generator=g, dtype=torch.float64) * math.pi
    freq = 2 + 6 * torch.rand(channels // 2, generator=g, dtype=torch.float64)  # cycles / unit
    dirs = torch.stack([ang.cos(), ang.sin()], -1)  # [C/2,2]
    phase = 2 * math.pi * freq * (xy @ dirs.T)  # [H,W,C/2]
    return torch.cat([phase.cos(), phase.sin()], -1).permute(2, 0, 1).float()


def test_fine_matching_adds_a_half_resolution_volume_that_gets_gradients():
    """fine_matching_channels > 0: the 1/2-resolution cost volume is built from its own
    features and feeds the depth head; every new parameter learns, and the default (0) keeps
    the v1 parameter layout (the shipped weights, v1's network, load strictly)."""
    torch.manual_seed(2)
    cfg = GeneratorConfig(**{**SMALL.to_dict(), "fine_matching_channels": 4})
    model = Generator(cfg).train()
    cams = rig(3, 32, 32)
    images, K, w2c = batch(cams[::2])
    target = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(5))
    render_loss(model, images, K, w2c, cams[1], target).backward()
    for name in ("encoder.fine.weight", "depth_head.fine_pool.0.weight", "depth_head.fine_gain"):
        grad = dict(model.named_parameters())[name].grad
        assert grad is not None and grad.abs().max() > 0, name
    plain = set(Generator(SMALL).state_dict())
    assert plain < set(model.state_dict())
    assert not any(k.startswith(("encoder.fine", "depth_head.fine")) for k in plain)
    with pytest.raises(ValueError, match="fine_matching_channels"):
        GeneratorConfig(fine_matching_channels=-1)


def grown_then_trained(base: GeneratorConfig, grow, arg):
    """Trained-looking weights of ``base`` (every tensor perturbed from its init) grown by
    ``grow(base, state, arg)``: checks the grown network gives the same depths and Gaussians,
    then takes one render-loss backward pass through it. -> (old state, grown config, grown
    state, grown network with gradients)."""
    torch.manual_seed(3)
    old = Generator(base).eval()
    with torch.no_grad():
        for p in old.parameters():
            p.add_(0.05 * torch.randn_like(p))
    cfg, state = grow(base, old.state_dict(), arg)
    new = Generator(cfg).eval()
    new.load_state_dict(state)
    cams = rig(3, 32, 32)
    images, K, w2c = batch(cams)
    near, far = torch.tensor([NEAR]), torch.tensor([FAR])
    with torch.no_grad():
        a, b = old(images, K, w2c, near, far), new(images, K, w2c, near, far)
    torch.testing.assert_close(b.depths, a.depths, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(b.means, a.means, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(b.sh, a.sh, atol=1e-5, rtol=1e-5)
    new.train()
    target = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(5))
    render_loss(new, images[:, ::2], K[:, ::2], w2c[:, ::2], cams[1], target).backward()
    return old.state_dict(), cfg, state, new


def test_grow_fine_matching_reproduces_the_trained_network_then_learns():
    """Growing weights by a fine cost volume gives the same Gaussians as the original network
    (the new inputs enter through zero weights), and a gradient step opens the new paths."""
    from prosplat.generator.grow import grow_fine_matching

    old, cfg, state, new = grown_then_trained(SMALL, grow_fine_matching, 4)
    assert (
        cfg.fine_matching_channels == 4 and cfg.num_depth_candidates == SMALL.num_depth_candidates
    )
    grads = {n: p.grad for n, p in new.named_parameters()}
    assert grads["depth_head.fine_gain"].abs() > 0
    fine_slot = grads["depth_head.unet.inc.0.0.weight"][:, 8:16]  # the fine volume's channels
    assert fine_slot.abs().max() > 0
    with pytest.raises(ValueError, match="already"):
        grow_fine_matching(cfg, state, 4)
    with pytest.raises(ValueError, match="channels"):
        grow_fine_matching(SMALL, old, 0)


def test_grow_alexnet_reproduces_the_trained_network_then_learns(tmp_path):
    """Growing weights by frozen AlexNet features gives the same Gaussians as the original
    network (the projection's last layer is zero); the backbone is LPIPS's own AlexNet (its
    relu1 matches LPIPS's at 1/4 resolution), survives a save and load, and never gets a
    gradient (buffers), while a gradient step opens the projection."""
    import torch.nn.functional as F

    from prosplat.generator.alexnet import FrozenAlexNet
    from prosplat.generator.grow import grow_alexnet
    from prosplat.metrics import LPIPS

    torch.manual_seed(4)
    old = Generator(TINY).eval()
    with torch.no_grad():
        for p in old.parameters():
            p.add_(0.05 * torch.randn_like(p))
    cfg, state = grow_alexnet(TINY, old.state_dict(), 3)
    assert cfg.alexnet_layers == 3
    new = Generator(cfg).eval()
    new.load_state_dict(state)
    assert not any("alexnet.conv" in n for n, _ in new.named_parameters())  # frozen: buffers
    cams = rig(3, 64, 64)
    images, K, w2c = batch(cams)
    with torch.no_grad():
        a, b = old(images, K, w2c, NEAR, FAR), new(images, K, w2c, NEAR, FAR)
    torch.testing.assert_close(b.depths, a.depths, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(b.means, a.means, atol=1e-5, rtol=1e-5)

    x = images[0] * 2 - 1  # [V,3,64,64] as the branch sees them
    lp = LPIPS()
    relu1 = lp.features((x - lp.shift) / lp.scale)[0]  # [V,64,15,15]
    relu1 = relu1 / (relu1.square().sum(1, keepdim=True).sqrt() + 1e-10)
    expect = F.interpolate(relu1, size=(16, 16), mode="bilinear", align_corners=False)
    feats = new.monocular.alexnet(x)  # [V,640,16,16]
    assert feats.shape == (3, 640, 16, 16)
    torch.testing.assert_close(feats[:, :64], expect, atol=1e-5, rtol=1e-5)
    assert FrozenAlexNet(2).out_channels == 256

    pipe = ProSplat(cfg)  # the backbone travels in the weights file
    pipe.generator.load_state_dict(state)
    loaded = ProSplat.from_pretrained(pipe.save(tmp_path / "g2.safetensors"), improve=False)
    torch.testing.assert_close(
        loaded.generator.monocular.alexnet.conv2_weight, lp.features.conv2.weight
    )

    new.train()
    target = torch.rand(3, 64, 64, generator=torch.Generator().manual_seed(5))
    render_loss(new, images[:, ::2], K[:, ::2], w2c[:, ::2], cams[1], target).backward()
    assert new.monocular.alexnet_proj[2].weight.grad.abs().max() > 0
    with pytest.raises(ValueError, match="already"):
        grow_alexnet(cfg, state, 3)
    with pytest.raises(ValueError, match="alexnet_layers"):
        grow_alexnet(TINY, old.state_dict(), 4)
    with pytest.raises(FileNotFoundError, match="lpips_weights"):
        grow_alexnet(TINY, old.state_dict(), 3, lpips_weights=tmp_path / "none.safetensors")


def test_warp_grid_matches_camera_projection():
    """The grid for a candidate depth samples the neighbour exactly where Camera.project puts
    the reference pixel centre lifted to that depth (pixel centres at +0.5, align_corners=False)."""
    w, h = 24, 16
    ref = Camera.from_intrinsics(20.0, 22.0, 11.0, 8.5, w, h)
    nb = Camera.look_at((0.7, -0.2, 0.1), (0.1, 0.0, 4.0), (0, -1, 0), 19.0, w, h)
    K = torch.stack([ref.K, nb.K]).float()[None]
    w2c = torch.stack([ref.world_to_cam, nb.world_to_cam]).float()[None]
    depths = torch.tensor([[2.0, 3.5]])
    grid = warp_grid(K, w2c, torch.tensor([[1, 0]]), depths, h, w)  # [1,2,2,h,w,2]
    for m, z in enumerate(depths[0].tolist()):
        pts = ref.unproject(
            ref.pixel_centers(torch.float64), torch.full((h, w), z, dtype=torch.float64)
        )
        uv, _ = nb.project(pts)
        expect = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1).clamp(-2, 2)
        assert torch.allclose(grid[0, 0, m].double(), expect, atol=1e-4)


def test_warp_grid_sends_points_behind_the_neighbour_outside():
    """A neighbour facing the reference camera: a candidate between the two lands where
    Camera.project puts it, one beyond the neighbour lies behind it and gets (-2, -2)."""
    w, h = 12, 10
    ref = Camera.from_intrinsics(10.0, 10.0, 6.0, 5.0, w, h)  # at the origin, looking +z
    nb = Camera.look_at((0.2, 0.1, 3.0), (0.0, 0.0, 0.0), (0, -1, 0), 10.0, w, h)
    K = torch.stack([ref.K, nb.K]).float()[None]
    w2c = torch.stack([ref.world_to_cam, nb.world_to_cam]).float()[None]
    grid = warp_grid(K, w2c, torch.tensor([[1, 0]]), torch.tensor([[1.5, 6.0]]), h, w)
    assert (grid[0, 0, 1] == -2).all()  # 6 units out: behind the neighbour at z = 3
    pts = ref.unproject(ref.pixel_centers(torch.float64), torch.full((h, w), 1.5).double())
    uv, _ = nb.project(pts)
    expect = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1).clamp(-2, 2)
    assert torch.allclose(grid[0, 0, 0].double(), expect, atol=1e-4)


def test_per_pixel_depths_warp_exactly_as_the_planes_they_pick():
    """warp_grid with [B,V,D,h,w] depths (each pixel its own candidates, as a band search
    around a first estimate needs) lands where the same depth's plane sends that pixel."""
    w, h, d = 12, 8, 5
    ref = Camera.from_intrinsics(11.0, 11.0, 6.0, 4.0, w, h)
    nb = Camera.look_at((0.5, 0.1, 0.0), (0.0, 0.0, 4.0), (0, -1, 0), 11.0, w, h)
    K = torch.stack([ref.K, nb.K]).float()[None]
    w2c = torch.stack([ref.world_to_cam, nb.world_to_cam]).float()[None]
    planes = inverse_depth_candidates(torch.tensor([NEAR]), torch.tensor([FAR]), d)  # [1,D]
    nbr = torch.tensor([[1, 0]])
    by_plane = warp_grid(K, w2c, nbr, planes, h, w)  # [1,2,D,h,w,2]
    rows = torch.arange(h)[:, None].expand(h, w)
    pick = (torch.arange(d)[:, None, None] + rows) % d  # [D,h,w]: pixel row r shifts by r
    per_pixel = planes[0][pick][None, None].expand(1, 2, d, h, w)  # [1,2,D,h,w]
    grid = warp_grid(K, w2c, nbr, per_pixel, h, w)
    expect = torch.gather(by_plane, 2, pick[None, None, ..., None].expand(1, 2, d, h, w, 2))
    torch.testing.assert_close(grid, expect, atol=1e-6, rtol=0)
    cost = plane_sweep_cost_volume(torch.randn(1, 2, 4, h, w), K, w2c, per_pixel, nbr[..., None])
    assert cost.shape == (1, 2, d, h, w)
    with pytest.raises(ValueError, match="per pixel"):
        warp_grid(K, w2c, nbr, per_pixel[:, :1], h, w)


def test_cost_volume_argmax_is_the_candidate_nearest_the_plane():
    """Through Generator.cost_volume: cameras at full resolution (4x), features at 1/4, so the
    intrinsics scaling to the feature resolution is part of what is checked."""
    w, h, near, far, d = 64, 48, 1.0, 20.0, 24
    cfg = GeneratorConfig(num_depth_candidates=d, cost_volume_views=3)
    cands = inverse_depth_candidates(torch.tensor([near]), torch.tensor([far]), d)[0]
    true_z = float(cands[9]) * 1.01  # off-grid, but candidate 9 is the nearest in disparity
    ref = Camera.from_intrinsics(200.0, 200.0, 2 * w, 2 * h, 4 * w, 4 * h)  # origin, looking +z
    nb = Camera.look_at((0.6, 0.1, 0.0), (0.0, 0.0, true_z), (0, -1, 0), 200.0, 4 * w, 4 * h)
    feats = torch.stack([plane_features(c.resized(w, h), true_z) for c in (ref, nb)])[None]
    K = torch.stack([ref.K, nb.K]).float()[None]
    w2c = torch.stack([ref.world_to_cam, nb.world_to_cam]).float()[None]
    cost = Generator.cost_volume(
        Generator(cfg), feats, K, w2c, torch.tensor([near]), torch.tensor([far]), (4 * h, 4 * w)
    )
    assert cost.shape == (1, 2, d, h, w)
    best = cost[0].argmax(1)  # [2,h,w]
    nearest = int((1 / cands - 1 / true_z).abs().argmin())
    assert nearest == 9
    # the reference view's centre region maps inside the neighbour at the true depth
    crop = best[0, h // 4 : 3 * h // 4, w // 4 : 3 * w // 4]
    assert (crop == nearest).float().mean() > 0.95, crop
    # the neighbour sees a tilted plane, so its depth varies; it still matches near the centre
    assert (best[1, h // 2 - 2 : h // 2 + 2, w // 2 - 2 : w // 2 + 2] - nearest).abs().max() <= 1


def test_zero_baseline_cost_volume_is_flat_and_finite():
    cam = Camera.from_intrinsics(40.0, 40.0, 16, 16, 32, 32)
    feats = torch.randn(1, 2, 8, 32, 32)
    K = torch.stack([cam.K, cam.K]).float()[None]
    w2c = torch.stack([cam.world_to_cam, cam.world_to_cam]).float()[None]
    cands = inverse_depth_candidates(torch.tensor([0.5]), torch.tensor([50.0]), 6)
    cost = plane_sweep_cost_volume(feats, K, w2c, cands, nearest_views(w2c, 3))
    assert torch.isfinite(cost).all()
    # every candidate samples the other view exactly at the same pixel centre: <f_i, f_j> / sqrt(C)
    # (a half-pixel slip, e.g. align_corners=True, would blend neighbours of random features)
    same_pixel = (feats * feats.flip(1)).sum(2, keepdim=True) / math.sqrt(8)  # [1,2,1,32,32]
    assert torch.allclose(cost, same_pixel.expand_as(cost), atol=1e-4)


@pytest.mark.parametrize(
    ("all_pairs", "planes_per_chunk"), [(True, 5), (False, 5), (False, 2)],
    ids=["all-pairs", "warped", "warped-in-chunks"],
)  # fmt: skip
def test_cost_volume_matches_a_candidate_by_candidate_reference(
    all_pairs, planes_per_chunk, monkeypatch
):
    """The vectorised correlation, both ways (candidates warped a chunk of planes at a time,
    multiplied and summed over channels; or every pixel pair correlated first, then
    sampled), against one grid_sample and one dot product per view, neighbour and candidate:
    the same volume and the same feature gradients. Chunks of 2 of the 5 planes leave a
    short last chunk. The third camera faces the others, so some of its candidates lie
    behind them and some points fall outside."""
    import torch.nn.functional as F

    from prosplat.generator import cost_volume

    monkeypatch.setattr(cost_volume, "ALL_PAIRS_MAX_PIXELS", 10**6 if all_pairs else 0)
    # one plane of the warped features is 3 views x 6 channels x 8x10 pixels
    monkeypatch.setattr(cost_volume, "PLANE_CHUNK_VALUES", planes_per_chunk * 3 * 6 * 80)
    torch.manual_seed(5)
    cams = [Camera.look_at((0.3 * i, 0.1 * i, 0.0), (0.0, 0.0, 4.0), (0, -1, 0), 12.0, 10, 8)
            for i in range(2)]  # fmt: skip
    cams.append(Camera.look_at((0.2, 0.0, 6.0), (0.0, 0.0, 0.0), (0, -1, 0), 12.0, 10, 8))
    K = torch.stack([c.K for c in cams]).float()[None]
    w2c = torch.stack([c.world_to_cam for c in cams]).float()[None]
    cands = inverse_depth_candidates(torch.tensor([1.0]), torch.tensor([20.0]), 5)
    nbrs = nearest_views(w2c, 2)
    feats = torch.randn(1, 3, 6, 8, 10, requires_grad=True)
    cost = plane_sweep_cost_volume(feats, K, w2c, cands, nbrs)  # [1,3,5,8,10]
    ref = torch.zeros_like(cost)
    for n in range(2):
        grid = warp_grid(K, w2c, nbrs[..., n], cands, 8, 10)  # [1,3,5,8,10,2]
        for i in range(3):
            j = int(nbrs[0, i, n])
            for d in range(5):
                warped = F.grid_sample(feats[:, j], grid[:, i, d], align_corners=False)
                ref[0, i, d] += (feats[0, i] * warped[0]).sum(0) / (2 * math.sqrt(6))
    assert torch.allclose(cost, ref, atol=1e-5)
    with torch.no_grad():  # inference correlates one channel at a time
        assert torch.allclose(plane_sweep_cost_volume(feats, K, w2c, cands, nbrs), ref, atol=1e-5)
    g = torch.randn_like(cost)
    (ours,) = torch.autograd.grad(cost, feats, g)
    (theirs,) = torch.autograd.grad(ref, feats, g)
    assert torch.allclose(ours, theirs, atol=1e-5)


def test_inverse_depth_candidates_and_nearest_views():
    c = inverse_depth_candidates(torch.tensor([1.0]), torch.tensor([1e4]), 5)[0]
    assert c[0] == pytest.approx(1.0) and c[-1] == pytest.approx(1e4, rel=1e-4)
    steps = (1 / c).diff()
    assert torch.allclose(steps, steps[:1].expand_as(steps))  # uniform in 1/z
    xs = [0.0, 1.0, 3.0, 7.0, 8.0]
    w2c = torch.eye(4).repeat(1, 5, 1, 1)
    w2c[0, :, 0, 3] = -torch.tensor(xs)  # centres at x = xs
    nb = nearest_views(w2c, 2)[0]
    assert nb.tolist() == [[1, 2], [0, 2], [1, 0], [4, 2], [3, 2]]
    assert nearest_views(w2c[:, :2], 3).shape == (1, 2, 1)  # k clipped to the other views
    cam = Camera.from_intrinsics(70.0, 60.0, 31.0, 17.0, 64, 32)
    assert torch.allclose(scale_intrinsics(cam.K, 16 / 64, 8 / 32), cam.resized(16, 8).K)


# ---- the adapter: forced depth --------------------------------------------------------------
def test_adapter_unprojects_forced_depth_like_camera():
    torch.manual_seed(3)
    w, h = 16, 12
    cam = rig(2, w, h)[1]
    adapter = GaussianAdapter(
        8, sh_degree=1, scale_factor_min=0.25, scale_factor_max=4.0, max_offset_px=0.5
    )
    with torch.no_grad():
        adapter.head.weight.zero_()  # neutral head: no offset, factor 1, identity rotation
    depth = 2.0 + torch.rand(1, h, w)
    rgb = torch.rand(1, 3, h, w)
    K, w2c = cam.K.float()[None], cam.world_to_cam.float()[None]
    g = adapter(torch.randn(1, 8, h, w), torch.rand(1, 1, h, w), rgb, depth, K, w2c)
    expect = cam.unproject(cam.pixel_centers(torch.float64), depth[0].double())
    assert torch.allclose(g.means[0].double(), expect, atol=1e-4)
    assert torch.allclose(g.scales[0], (depth[0] / cam.fx)[..., None].expand(h, w, 3), rtol=1e-5)
    R = quat_to_rotmat(g.quats.reshape(-1, 4))  # camera frame identity -> world = cam-to-world
    assert torch.allclose(R, cam.R.T.float().expand_as(R), atol=1e-5)
    assert torch.allclose(g.sh[0, ..., 0, :], rgb_to_sh0(rgb[0].permute(1, 2, 0)), atol=1e-5)
    assert (g.sh[..., 1:, :] == 0).all()  # higher SH start at zero


def test_rotmat_to_quat_round_trip():
    q = torch.randn(64, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    q[0] = torch.tensor([0.0, 1.0, 0.0, 0.0])  # 180° turns: the trace branch is singular
    q[1] = torch.tensor([0.0, 0.0, 0.0, 1.0])
    R = quat_to_rotmat(q)
    assert torch.allclose(quat_to_rotmat(rotmat_to_quat(R)), R, atol=1e-10)


# ---- degenerate and invalid inputs ---------------------------------------------------------
def test_degenerate_inputs_give_finite_outputs(model):
    cams = rig(2, 32, 32)
    images, K, w2c = batch(cams)
    same = (images[:, :1].expand_as(images), K[:, :1].expand_as(K), w2c[:, :1].expand_as(w2c))
    const = torch.full_like(images, 0.5)
    with torch.no_grad():
        outs = [
            model(*same, NEAR, FAR),  # two identical views: zero baseline
            model(const, K, w2c, NEAR, FAR),  # textureless
            model(images, K, w2c, 0.01, 100.0),  # far / near = 1e4
            model(torch.zeros_like(images), K, w2c, 1e-3, 1e3),
        ]
    for out in outs:
        for t in (out.means, out.scales, out.opacities, out.sh, out.quats, out.depths):
            assert torch.isfinite(t).all()
        out.gaussians(0).validate()


def test_invalid_inputs_raise_value_error(model):
    images, K, w2c = batch(rig(2, 32, 32))
    with pytest.raises(ValueError, match="near must be < far"):
        model(images, K, w2c, 5.0, 5.0)
    with pytest.raises(ValueError, match="near must be > 0"):
        model(images, K, w2c, 0.0, 5.0)
    with pytest.raises(ValueError, match="at least 2 input views"):
        model(images[:, :1], K[:, :1], w2c[:, :1], NEAR, FAR)
    with pytest.raises(ValueError, match="multiple of 32"):
        model(images[..., :24], K, w2c, NEAR, FAR)
    with pytest.raises(ValueError, match="K must be"):
        model(images, K[:, :1], w2c, NEAR, FAR)
    bad = w2c.clone()
    bad[0, 1, 0, 3] = float("nan")
    with pytest.raises(ValueError, match="w2c contains NaN"):
        model(images, K, bad, NEAR, FAR)
    with pytest.raises(ValueError, match="near"):
        model(images, K, w2c, torch.tensor([1.0, 2.0]), FAR)  # wrong batch size
    with pytest.raises(ValueError, match="at most"):
        v = SMALL.max_views + 1
        big, Kb, wb = batch(rig(v, 32, 32))
        model(big, Kb, wb, NEAR, FAR)


# ---- config, checkpoints, pipeline ---------------------------------------------------------
def test_config_round_trip_and_presets():
    assert GeneratorConfig.from_json(BASE.to_json()) == BASE
    assert GeneratorConfig.from_dict(SMALL.to_dict()) == SMALL
    with pytest.raises(ValueError, match="no keys"):
        GeneratorConfig.from_dict({**TINY.to_dict(), "bogus": 1})
    with pytest.raises(ValueError, match="must divide"):
        GeneratorConfig(feature_channels=30, attention_heads=4)
    assert 0.3e6 <= Generator(TINY).num_parameters() <= 1e6
    assert 10e6 <= Generator(BASE).num_parameters() <= 30e6


def test_reconstruct_caps_the_gaussian_size_and_rounds_odd_sizes():
    """:meth:`ProSplat.reconstruct` places Gaussians at the inputs' size up to
    MAX_GAUSSIAN_SCALE x the matching height, on a multiple of 32: larger or odd inputs are
    resized first (so a 1080p camera's inputs do not make millions of Gaussians a view)."""
    torch.manual_seed(6)
    m = ProSplat(SMALL, trained_size=64)
    cap = pipeline.MAX_GAUSSIAN_SCALE * 64
    assert cap >= 128
    for size, expect in ((cap + 32, cap), (100, 96), (64, 64), (32, 32)):
        cams = rig(2, size, size)
        images = torch.rand(2, 3, size, size, generator=torch.Generator().manual_seed(size))
        out = m.reconstruct(images, cams, NEAR, FAR, budget="all")
        assert out.depths.shape[-2:] == (expect, expect), size
        assert (out.cameras[0].width, out.cameras[0].height) == (expect, expect)
        assert len(out.gaussians) == 2 * expect * expect


def test_save_load_round_trip(tmp_path):
    torch.manual_seed(4)
    a = ProSplat(SMALL)
    path = a.save(tmp_path / "gen.safetensors")
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # not the 0600 of a temp file
    # the file's weights alone: the depth sweep is a loading default (tests/pipeline/test_depth_sweep.py)
    b = ProSplat.from_pretrained(path, depth_sweep=False)
    assert b.config == SMALL
    cams = rig(2, 32, 32)
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    ga = a.reconstruct(images, cams, NEAR, FAR, budget="all").gaussians
    gb = b.reconstruct(images, cams, NEAR, FAR, budget="all").gaussians
    for name, t in ga.tensors().items():
        assert torch.equal(t, gb.tensors()[name]), name
    with pytest.raises(FileExistsError, match="overwrite=True"):
        a.save(path)
    torch.manual_seed(5)
    ProSplat(SMALL).save(path, overwrite=True)
    c = ProSplat.from_pretrained(path, depth_sweep=False)
    assert not torch.equal(
        c.reconstruct(images, cams, NEAR, FAR, budget="all").gaussians.means, ga.means
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gen.safetensors"]  # no temp files left
    with pytest.raises(ValueError, match="different generator config"):
        ProSplat.from_pretrained(path, config=TINY)


def test_from_pretrained_without_shipped_weights(tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline, "DEFAULT_WEIGHTS", tmp_path / "generator_tiny.safetensors")
    with pytest.raises(FileNotFoundError, match="prosplat train generator --config tiny --data"):
        ProSplat.from_pretrained()
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ProSplat.from_pretrained(tmp_path / "nope.safetensors")


def test_reconstruct_derives_near_far_and_rejects_coincident_cameras():
    torch.manual_seed(6)
    model = ProSplat(SMALL)
    cams = rig(3, 32, 32)
    near, far = near_far_from_cameras(cams)
    # the rig looks at the origin from ~4 units: near/far bracket the origin's depth
    depths = [float(c.world_to_camera(torch.zeros(1, 3, dtype=c.K.dtype))[0, 2]) for c in cams]
    assert near == pytest.approx(0.5 * min(depths), rel=1e-6)
    assert far == pytest.approx(2.5 * max(depths), rel=1e-6)
    # a forward-facing rig (parallel axes) keeps the baseline rule: matchable depths start at b·f/S
    parallel = [Camera.look_at((x, 0, -4), (x, 0, 0), (0, -1, 0), 28.8, 32, 32) for x in (0, 1)]
    pnear, pfar = near_far_from_cameras(parallel)
    assert pnear == pytest.approx(0.5 * 1.0 * 0.9) and pfar == pytest.approx(100.0)
    images = torch.rand(3, 3, 32, 32)
    out = model.run_generator(images, cams)
    assert (out.depths >= near * 0.999).all() and (out.depths <= far * 1.001).all()
    assert out.means.grad_fn is None
    assert model.run_generator(images, cams, grad=True).means.requires_grad
    # the generator's mode comes back as it was, every submodule with it (training resumes)
    for training in (True, False):
        model.generator.train(training)
        model.run_generator(images, cams)
        assert {m.training for m in model.generator.modules()} == {training}
    rotated = Camera.look_at(cams[0].center, (1.0, 0.0, 0.0), (0, -1, 0), 28.8, 32, 32)
    with pytest.raises(ValueError, match="same place"):
        model.reconstruct(images, [cams[0], rotated, cams[1]])
    g = model.reconstruct(images, [cams[0], rotated, cams[1]], near=1.0, far=10.0).gaussians
    assert torch.isfinite(g.means).all()
    with pytest.raises(ValueError, match="3 images but 2 cameras"):
        model.reconstruct(images, cams[:2])
    with pytest.raises(ValueError, match="resized"):
        model.reconstruct(images, rig(3, 64, 32))


def test_shipped_tiny_weights_load_and_reconstruct():
    """The packaged checkpoint loads with its config and gives finite Gaussians on its rays."""
    if not pipeline.DEFAULT_WEIGHTS.exists():
        pytest.fail(f"shipped weights missing: {pipeline.DEFAULT_WEIGHTS}")
    from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians

    model = pipeline.ProSplat.from_pretrained()
    cams = orbit_cameras(2, 64, 64)
    scene = pixel_aligned_gaussians(cams)
    images = torch.stack([render(scene, c).rgb for c in cams])
    out = model.run_generator(images, cams, near=1.0, far=8.0)
    g = out.gaussians(0)
    assert len(g) == 2 * 64 * 64
    assert torch.isfinite(out.depths).all() and (out.depths >= 1.0 - 1e-4).all()
    assert (out.depths <= 8.0 + 1e-3).all()
