"""The generator's 1/2-resolution band search (prosplat.generator.cascade): per-pixel candidate
depths warp exactly as planes do, the band's correlation peaks at the true depth, and growing
trained weights by the stage keeps their outputs and opens a path that learns."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera, render
from prosplat.generator import Generator, GeneratorConfig
from prosplat.generator.cascade import BAND_STEPS, CascadeStage
from prosplat.generator.cost_volume import (
    inverse_depth_candidates,
    plane_sweep_cost_volume,
    warp_grid,
)
from prosplat.generator.grow import grow_cascade

NEAR, FAR = 1.0, 10.0
#: Small enough for well under a second a test; with the fine matching features the stage needs.
SMALL = GeneratorConfig(
    feature_channels=16,
    num_depth_candidates=8,
    cost_volume_views=2,
    fine_matching_channels=4,
    mono_channels=8,
    mono_blocks=1,
    unet_channels=(8, 8, 16),
    refine_channels=8,
)


@pytest.fixture(autouse=True)
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def two_cameras(w: int, h: int, z: float) -> tuple[Camera, Camera]:
    ref = Camera.from_intrinsics(0.9 * w, 0.9 * w, w / 2, h / 2, w, h)  # origin, looking +z
    nb = Camera.look_at((0.5, 0.1, 0.0), (0.0, 0.0, z), (0, -1, 0), 0.9 * w, w, h)
    return ref, nb


def stack(cams):
    K = torch.stack([c.K for c in cams]).float()[None]
    w2c = torch.stack([c.world_to_cam for c in cams]).float()[None]
    return K, w2c


def plane_features(cam: Camera, z0: float, channels: int = 16) -> torch.Tensor:
    """[C,H,W] features of the world plane z = z0 seen by ``cam``: cos/sin of plane waves, so
    two views' features agree exactly where they see the same point of the plane."""
    g = torch.Generator().manual_seed(7)
    o, d = cam.center.double(), cam.ray_directions(torch.float64)  # [3], [H,W,3]
    xy = (o + ((z0 - o[2]) / d[..., 2])[..., None] * d)[..., :2]  # [H,W,2]
    ang = torch.rand(channels // 2, generator=g, dtype=torch.float64) * math.pi
    freq = 1 + 3 * torch.rand(channels // 2, generator=g, dtype=torch.float64)
    phase = 2 * math.pi * freq * (xy @ torch.stack([ang.cos(), ang.sin()], -1).T)  # [H,W,C/2]
    return torch.cat([phase.cos(), phase.sin()], -1).permute(2, 0, 1).float()


def test_per_pixel_depths_warp_exactly_as_the_planes_they_pick():
    """Each pixel's own candidates land where the same depth's plane sends that pixel."""
    w, h, d = 12, 8, 5
    K, w2c = stack(two_cameras(w, h, 4.0))
    planes = inverse_depth_candidates(torch.tensor([NEAR]), torch.tensor([FAR]), d)  # [1,D]
    nbr = torch.tensor([[1, 0]])
    by_plane = warp_grid(K, w2c, nbr, planes, h, w)  # [1,2,D,h,w,2]
    rows = torch.arange(h)[:, None].expand(h, w)
    pick = (torch.arange(d)[:, None, None] + rows) % d  # [D,h,w]: pixel row r shifts by r
    per_pixel = planes[0][pick][None, None].expand(1, 2, d, h, w)  # [1,2,D,h,w]
    grid = warp_grid(K, w2c, nbr, per_pixel, h, w)
    expect = torch.gather(by_plane, 2, pick[None, None, ..., None].expand(1, 2, d, h, w, 2))
    torch.testing.assert_close(grid, expect, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="per pixel"):
        warp_grid(K, w2c, nbr, per_pixel[:, :1], h, w)


def test_band_correlation_peaks_at_the_candidate_nearest_the_true_depth():
    """A band centred off the true depth, but holding it, still finds it."""
    w, h, z_true, dc = 48, 32, 3.0, 9
    ref, nb = two_cameras(w, h, z_true)
    feats = torch.stack([plane_features(c, z_true) for c in (ref, nb)])[None]  # [1,2,C,h,w]
    K, w2c = stack((ref, nb))
    stage = CascadeStage(dc, coarse_candidates=8, hidden_channels=4, fine_channels=16)
    t_of = lambda z: (1 / z - 1 / FAR) / (1 / NEAR - 1 / FAR)  # noqa: E731
    start = torch.full((2, 1, h, w), t_of(z_true) + 0.6 * BAND_STEPS / 7)  # 0.6 of the band off
    band = stage.band(start)  # [2,Dc,h,w]
    depths = 1 / (1 / FAR + band * (1 / NEAR - 1 / FAR))
    cost = plane_sweep_cost_volume(feats, K, w2c, depths[None], torch.tensor([[[1], [0]]]))
    nearest = int((band[0, :, 0, 0] - t_of(z_true)).abs().argmin())
    assert 0 < nearest < dc - 1  # inside the band, not at its edge
    best = cost[0, 0].argmax(0)  # [h,w] for the reference view
    crop = best[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4]
    assert (crop == nearest).float().mean() > 0.95, crop


def test_grow_cascade_reproduces_the_trained_network_then_learns():
    torch.manual_seed(3)
    old = Generator(SMALL).eval()
    with torch.no_grad():  # trained weights are not at their init
        for p in old.parameters():
            p.add_(0.05 * torch.randn_like(p))
    cfg, state = grow_cascade(SMALL, old.state_dict(), 5)
    assert cfg.cascade_candidates == 5
    new = Generator(cfg).eval()
    new.load_state_dict(state)
    cams = [
        Camera.look_at(
            (4 * math.sin(a), 0.2, -4 * math.cos(a)), (0, 0, 0), (0, -1, 0), 29.0, 32, 32
        )
        for a in (-0.3, 0.0, 0.3)
    ]
    images = torch.rand(1, 3, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    K, w2c = stack(cams)
    with torch.no_grad():
        a, b = old(images, K, w2c, NEAR, FAR), new(images, K, w2c, NEAR, FAR)
    torch.testing.assert_close(b.depths, a.depths, atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(b.means, a.means, atol=1e-6, rtol=1e-6)

    new.train()  # one gradient step on the stage alone moves the depth
    out = new(images[:, ::2], K[:, ::2], w2c[:, ::2], NEAR, FAR)
    rgb = render(out.gaussians(0), cams[1], torch.tensor([0.5, 0.5, 0.5])).rgb
    target = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(5))
    torch.nn.functional.mse_loss(rgb, target).backward()
    grads = {n: p.grad for n, p in new.named_parameters() if n.startswith("cascade.")}
    assert grads["cascade.logits.weight"].abs().max() > 0
    assert grads["cascade.cost_gain"].abs() > 0
    with torch.no_grad():
        for name, g in grads.items():
            dict(new.named_parameters())[name].sub_(1e3 * g)
        moved = new.eval()(images, K, w2c, NEAR, FAR).depths
    assert (moved - a.depths).abs().max() > 1e-3

    with pytest.raises(ValueError, match="already"):
        grow_cascade(cfg, state, 5)
    with pytest.raises(ValueError, match="fine_matching_channels"):
        GeneratorConfig(cascade_candidates=5)  # tiny has no fine matching features
    with pytest.raises(ValueError, match="cascade_candidates"):
        GeneratorConfig(**{**SMALL.to_dict(), "cascade_candidates": 1})
