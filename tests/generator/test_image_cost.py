"""The images' own ZNCC plane sweep in the generator (prosplat.generator.image_cost): it peaks
at the true plane, says nothing where it knows nothing, and grows into trained weights without
changing them."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from test_generator import (
    FAR,
    NEAR,
    SMALL,
    batch,
    grown_then_trained,
    plane_features,
    render_loss,
    rig,
)

from prosplat import Camera
from prosplat.generator import Generator, GeneratorConfig
from prosplat.generator.cost_volume import inverse_depth_candidates, nearest_views
from prosplat.generator.image_cost import image_cost_volume
from prosplat.train.generator_config import TrainConfig

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one thread is faster


def _plane_image(cam: Camera, z0: float) -> torch.Tensor:
    """[3,H,W] in [0,1]: the world plane z = z0 painted with three plane waves of 0.7-2
    cycles per unit (periods of 4-14 px at half the test size: texture that survives the
    band's downsampling, where ``plane_features``' finer waves blur away)."""
    o = cam.center.double()
    d = cam.ray_directions(torch.float64)  # [H,W,3]
    xy = (o + ((z0 - o[2]) / d[..., 2])[..., None] * d)[..., :2]  # [H,W,2] on the plane
    freq = torch.tensor([0.7, 1.3, 2.0], dtype=torch.float64)
    ang = torch.tensor([0.3, 1.4, 2.5], dtype=torch.float64)
    dirs = torch.stack([ang.cos(), ang.sin()], -1)  # [3,2]
    return (0.5 + 0.5 * torch.sin(2 * torch.pi * freq * (xy @ dirs.T))).permute(2, 0, 1).float()


def _two_views(w: int, h: int, true_z: float, texture=None):
    """A reference camera at the origin looking +z and a neighbour 0.6 to its side, both
    seeing a textured plane at z = ``true_z``: [1,2,3,H,W] images in [0,1], K, w2c."""
    ref = Camera.from_intrinsics(0.9 * w, 0.9 * w, w / 2, h / 2, w, h)
    nb = Camera.look_at((0.6, 0.1, 0.0), (0.0, 0.0, true_z), (0, -1, 0), 0.9 * w, w, h)
    paint = texture or (lambda c, z: (plane_features(c, z, 6)[:3] + 1) / 2)
    images = torch.stack([paint(c, true_z) for c in (ref, nb)])[None]
    K = torch.stack([ref.K, nb.K]).float()[None]
    w2c = torch.stack([ref.world_to_cam, nb.world_to_cam]).float()[None]
    return images, K, w2c


def test_the_image_sweep_peaks_at_the_candidate_nearest_the_plane():
    """Per pixel, the ZNCC is ~1 at the candidate nearest the plane's depth in disparity and
    lower elsewhere; pooling averages 2x2 cells."""
    w, h, d = 48, 40, 16
    cands = inverse_depth_candidates(torch.tensor([NEAR]), torch.tensor([FAR]), d)  # [1,D]
    true_z = float(cands[0, 6])
    images, K, w2c = _two_views(w, h, true_z)
    vol = image_cost_volume(images, K, w2c, cands, nearest_views(w2c, 3), 5, pool=1)
    assert vol.shape == (1, 2, d, h, w)
    centre = vol[0, 0, :, h // 4 : 3 * h // 4, w // 4 : 3 * w // 4]  # seen by the neighbour
    assert (centre.argmax(0) == 6).float().mean() > 0.95
    assert centre[6].median() > 0.95
    assert centre[2].median() < 0.5 and centre[12].median() < 0.5
    pooled = image_cost_volume(images, K, w2c, cands, nearest_views(w2c, 3), 5, pool=2)
    assert pooled.shape == (1, 2, d, h // 2, w // 2)
    torch.testing.assert_close(pooled, torch.nn.functional.avg_pool3d(vol, (1, 2, 2)))


def test_the_image_sweep_in_chunks_of_planes_is_the_whole_sweep(monkeypatch):
    """Planes warped and correlated a few at a time (PLANE_CHUNK_VALUES, 3 of 16 here, a
    short last chunk) give the volume of all planes at once, bit for bit: the ZNCC's window
    never crosses planes."""
    from prosplat.generator import cost_volume

    w, h, d = 48, 40, 16
    cands = inverse_depth_candidates(torch.tensor([NEAR]), torch.tensor([FAR]), d)
    images, K, w2c = _two_views(w, h, float(cands[0, 6]))
    images = images + 0.05 * torch.rand_like(images)  # texture everywhere, not only the plane
    nbrs = nearest_views(w2c, 3)
    whole = image_cost_volume(images, K, w2c, cands, nbrs, 5, pool=2)
    # one plane of the ZNCC statistics: 2 views x (3 channels + 2) x 40x48 pixels
    monkeypatch.setattr(cost_volume, "PLANE_CHUNK_VALUES", 3 * 2 * 5 * h * w)
    chunked = image_cost_volume(images, K, w2c, cands, nbrs, 5, pool=2)
    assert torch.equal(chunked, whole)
    assert whole.abs().max() > 0.5  # it matched something


def test_flat_images_and_unseen_points_give_zero():
    """A flat image has no texture to match (0, not its noise), and a candidate that lands
    outside every neighbour's image gives 0 (no vote), not the correlation of padding."""
    w, h, d = 32, 32, 8
    cands = inverse_depth_candidates(torch.tensor([NEAR]), torch.tensor([FAR]), d)
    images, K, w2c = _two_views(w, h, 3.0)
    flat = torch.full_like(images, 0.5)
    vol = image_cost_volume(flat, K, w2c, cands, nearest_views(w2c, 3), 5, pool=1)
    assert vol.abs().max() < 1e-3
    far_away = w2c.clone()
    far_away[0, 1, 0, 3] += 1e3  # the neighbour moved far to the side: it sees none of it
    vol = image_cost_volume(images, K, far_away, cands, nearest_views(far_away, 3), 5, pool=1)
    assert torch.isfinite(vol).all() and vol.abs().max() == 0


def test_image_matching_feeds_the_depth_head_and_gets_gradients():
    """image_matching_window > 0: the depth head gets D more channels and a gain that learn;
    0 (every shipped generator) keeps the parameter layout, and the window must be odd."""
    torch.manual_seed(2)
    model = Generator(replace(SMALL, image_matching_window=3)).train()
    cams = rig(3, 32, 32)
    images, K, w2c = batch(cams[::2])
    target = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(5))
    render_loss(model, images, K, w2c, cams[1], target).backward()
    assert model.depth_head.image_gain.grad.abs() > 0
    plain = Generator(SMALL).state_dict()
    assert set(model.state_dict()) - set(plain) == {"depth_head.image_gain"}
    d = SMALL.num_depth_candidates
    assert model.state_dict()["depth_head.unet.inc.0.0.weight"].shape[1] == (
        plain["depth_head.unet.inc.0.0.weight"].shape[1] + d
    )
    for bad in (-1, 4):
        with pytest.raises(ValueError, match="image_matching_window"):
            GeneratorConfig(image_matching_window=bad)
    with pytest.raises(ValueError, match="odd"):
        TrainConfig(data="x", out="y", init="w.safetensors", grow_image_matching=4)
    with pytest.raises(ValueError, match="needs --init"):
        TrainConfig(data="x", out="y", grow_image_matching=5)


@pytest.mark.parametrize("fine", [0, 4])
def test_grow_image_matching_reproduces_the_trained_network_then_learns(fine):
    """Growing weights by the image sweep gives the same Gaussians as the original network
    (its U-Net channels and its prior gain start at zero), with or without a fine cost volume
    before it in the U-Net's input, and a gradient step opens both paths."""
    from prosplat.generator.grow import grow_image_matching

    base = replace(SMALL, fine_matching_channels=fine)
    old, cfg, state, new = grown_then_trained(base, grow_image_matching, 5)
    assert cfg == replace(base, image_matching_window=5)
    grads = {n: p.grad for n, p in new.named_parameters()}
    assert grads["depth_head.image_gain"].abs() > 0
    d = base.num_depth_candidates
    at = d * (2 if fine else 1)
    assert grads["depth_head.unet.inc.0.0.weight"][:, at : at + d].abs().max() > 0
    with pytest.raises(ValueError, match="already"):
        grow_image_matching(cfg, state, 5)
    with pytest.raises(ValueError, match="window"):
        grow_image_matching(base, old, 0)


# ---- the learned depth sweep (prosplat.generator.band) --------------------------------------
def test_the_band_peaks_at_the_true_depth_around_a_wrong_one():
    """Around a depth 15 % too far, the band's ZNCC peaks at the candidate e^-0.15 nearer
    (9 candidates over ±0.3 in log: index 2) wherever the neighbour sees the plane."""
    from prosplat.generator.band import BandRefiner

    w, h, true_z = 48, 40, 3.0
    images, K, w2c = _two_views(w, h, true_z, _plane_image)
    band = BandRefiner(9, 4)
    depth = torch.full((1, 2, h, w), true_z * math.exp(0.15))
    scores = band.scores(images, depth, K, w2c, nearest_views(w2c, 3))
    assert scores.shape == (1, 2, 9, h // 2, w // 2)
    ref = scores[0, 0, :, 3:-3, 3:-3]  # [9,..]: windows inside the image
    # the neighbour sees the left part of the view at no depth, and some pixels only at some
    # candidates (windows cut by its edge): scored where every candidate lands inside it
    seen = ref.abs().amin(0) > 0.01
    assert seen.float().mean() > 0.6
    assert (ref.argmax(0)[seen] == 2).float().mean() > 0.95
    assert ref[2][seen].median() > 0.9


def test_the_band_starts_closed_and_moves_depth_within_its_span():
    from prosplat.generator.band import BAND_SPAN, BandRefiner

    torch.manual_seed(0)
    w, h = 32, 32
    images, K, w2c = _two_views(w, h, 3.0)
    depth = torch.full((1, 2, h, w), 3.0)
    feats = torch.randn(2, 4, h, w)
    band = BandRefiner(5, 4)
    out = band(images, depth, feats, K, w2c, nearest_views(w2c, 3))
    torch.testing.assert_close(out, depth)  # closed: the depth passes through
    with torch.no_grad():
        band.delta.weight.normal_(0, 10.0)  # wide open, saturating the tanh
    out = band(images, depth, feats, K, w2c, nearest_views(w2c, 3))
    ratio = (out / depth).log()
    assert ratio.abs().max() <= BAND_SPAN + 1e-5 and ratio.abs().max() > 0.5 * BAND_SPAN
    with pytest.raises(ValueError, match="candidates"):
        BandRefiner(1, 4)


def test_grow_band_reproduces_the_trained_network_then_learns():
    """Growing weights by the band gives the same Gaussians (its last conv is zero), and a
    gradient step opens it."""
    from prosplat.generator.grow import grow_band

    old, cfg, state, new = grown_then_trained(SMALL, grow_band, 5)
    assert cfg == replace(SMALL, band_candidates=5)
    assert new.band.delta.weight.grad.abs().max() > 0
    with pytest.raises(ValueError, match="already"):
        grow_band(cfg, state, 5)
    with pytest.raises(ValueError, match="candidates"):
        grow_band(SMALL, old, 1)
    with pytest.raises(ValueError, match="band_candidates"):
        GeneratorConfig(band_candidates=1)
    with pytest.raises(ValueError, match="grow_band"):
        TrainConfig(data="x", out="y", init="w.safetensors", grow_band=1)
