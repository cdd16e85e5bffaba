"""The flicker figure (prosplat.eval.flicker) and the fixed-pattern score (prosplat.improve.pattern)
against analytic references: a textured plane seen by two cameras, and synthetic changes with
and without a position-locked pattern."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat.core.camera import Camera
from prosplat.eval.flicker import camera_path, flicker, warp_next
from prosplat.improve.pattern import fixed_pattern_score, lattice_score

Z = 3.0  # the plane z = Z (world), seen by cameras at z = 0 looking along +z


def _cam(x: float, size: int = 48) -> Camera:
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[0, 3] = -x  # centre at (x, 0, 0)
    return Camera.from_intrinsics(40.0, 40.0, size / 2, size / 2, size, size, w2c)


def _texture(X: torch.Tensor, Y: torch.Tensor) -> torch.Tensor:
    """A smooth colour pattern on the plane: [3,...]."""
    return torch.stack(
        [0.5 + 0.4 * torch.sin(3 * X), 0.5 + 0.4 * torch.cos(2 * Y), 0.5 + 0.2 * torch.sin(X + Y)]
    )


def _frame(cam: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """The plane's exact image [3,H,W] and z-depth [H,W] from ``cam``."""
    uv = cam.pixel_centers(torch.float64)
    depth = torch.full(uv.shape[:2], Z, dtype=torch.float64)
    p = cam.unproject(uv, depth)
    return _texture(p[..., 0], p[..., 1]).float(), depth.float()


def test_warp_next_reproduces_the_first_frame():
    a, b = _cam(0.0), _cam(0.3)
    fa, da = _frame(a)
    fb, db = _frame(b)
    warped, mask = warp_next(fb, da, db, a, b)
    # b sees the plane shifted by f * 0.3 / Z = 4 px: that strip of a is not in b
    assert 0.85 < mask.float().mean() < 0.95
    assert (warped - fa).abs().mean(0)[mask].max() < 0.02  # bilinear error on a smooth texture


def test_occluded_pixels_do_not_count():
    a, b = _cam(0.0), _cam(0.3)
    fa, da = _frame(a)
    fb, db = _frame(b)
    db = db.clone()
    db[:, :10] = 1.0  # something nearer covers b's left columns
    _, mask = warp_next(fb, da, db, a, b)
    _, full = warp_next(fb, da, _frame(b)[1], a, b)
    assert mask.sum() < full.sum() - 10 * 30


def test_flicker_separates_consistent_frames_from_noisy_ones():
    cams = [_cam(0.05 * i) for i in range(5)]
    frames, depths = zip(*(_frame(c) for c in cams), strict=True)
    frames, depths = torch.stack(frames), torch.stack(depths)
    steady = flicker(frames, depths, cams)
    g = torch.Generator().manual_seed(0)
    noisy = (frames + 0.1 * (torch.rand(frames.shape, generator=g) - 0.5)).clamp(0, 1)
    jumpy = flicker(noisy, depths, cams)
    assert steady < 0.01
    # two frames of independent uniform noise of width 0.1 differ by ~0.033 on average
    assert 0.025 < jumpy < 0.045


def test_camera_path_ends_and_midpoint():
    a = Camera.look_at([0, 0, 0], [0, 0, 1], [0, -1, 0], 40.0, 32, 32)
    b = Camera.look_at([1, 0, 0], [2, 0, 1], [0, -1, 0], 50.0, 32, 32)
    path = camera_path(a, b, 5)
    assert torch.allclose(path[0].world_to_cam, a.world_to_cam.double(), atol=1e-9)
    assert torch.allclose(path[-1].world_to_cam, b.world_to_cam.double(), atol=1e-9)
    mid = path[2]
    assert torch.allclose(mid.center, torch.tensor([0.5, 0.0, 0.0], dtype=torch.float64))
    assert mid.fx == pytest.approx(45.0)
    # b is turned 45 degrees about y from a: the midpoint is turned 22.5 degrees
    cos = float(mid.forward @ a.forward.double())
    assert math.degrees(math.acos(min(1.0, cos))) == pytest.approx(22.5, abs=1e-6)
    with pytest.raises(ValueError, match="at least 2"):
        camera_path(a, b, 1)


def _content_changes(n: int, seed: int = 0) -> torch.Tensor:
    """Changes that depend on content only: smooth random fields, one per view."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.randn(n, 3, 8, 8, generator=g) * 0.05
    return torch.nn.functional.interpolate(coarse, size=(64, 64), mode="bilinear")


def test_pattern_score_is_near_one_without_a_fixed_pattern():
    score = fixed_pattern_score(_content_changes(60))
    assert score.views == 60
    assert 0.3 < score.ratio < 2.5


def test_pattern_score_finds_a_stamped_pattern():
    changes = _content_changes(60)
    blobs = torch.zeros(3, 64, 64)
    for c in range(8, 56, 8):  # a row of small green blobs, as weak as the content
        blobs[1, 40:42, c : c + 2] = 0.05
    score = fixed_pattern_score(changes + blobs)
    assert score.ratio > 3
    # a global brightening is not a pattern
    assert fixed_pattern_score(changes + 0.05).ratio < 2.5
    with pytest.raises(ValueError, match="N>=2"):
        fixed_pattern_score(changes[:1])


def _lattice_changes(n: int, period: int, amplitude: float, seed: int = 0) -> torch.Tensor:
    """``n`` changes [n,3,64,64]: noise plus, with ``amplitude``, one blob per ``period``-px
    cell, each view's lattice at its own random phase (as a model that paints on its
    bottleneck grid wherever the render is washed out)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(64), torch.arange(64), indexing="ij")
    out = []
    for _ in range(n):
        dy, dx = (int(v) for v in torch.randint(0, period, (2,), generator=g))
        r2 = ((yy + dy) % period - period / 2) ** 2 + ((xx + dx) % period - period / 2) ** 2
        blob = torch.exp(-r2 / 4.0)[None].expand(3, -1, -1)
        out.append(amplitude * blob + 0.05 * torch.randn(3, 64, 64, generator=g))
    return torch.stack(out)


def test_lattice_score_finds_a_lattice_whatever_its_phase():
    """A lattice that moves with each view averages away in the fixed-pattern score; the
    lattice score, on power spectra, still finds it; noise alone scores about 1."""
    lattice = _lattice_changes(24, 16, 0.1)
    assert fixed_pattern_score(lattice).ratio < 1.5  # the position-locked test misses it
    assert lattice_score(lattice, 16).ratio > 2.0
    assert lattice_score(_lattice_changes(24, 16, 0.0), 16).ratio == pytest.approx(1.0, abs=0.2)
    with pytest.raises(ValueError, match="multiple of the period"):
        lattice_score(lattice[:, :, :60], 16)


def test_lattice_score_is_not_fooled_by_structure_along_one_axis():
    """Changes that vary along one image axis only (a sky-to-floor gradient, a table edge at
    some height) put all their power on that frequency axis. They are no lattice, and score
    about 1 (the 8-bin ring scored these 3.9); horizontal bands every 8 px as strong as the
    content's edges are a lattice, and are found."""
    g = torch.Generator().manual_seed(0)
    yy = torch.arange(64, dtype=torch.float32)[:, None].expand(64, 64)
    views = []
    for _ in range(32):
        edge = int(torch.randint(8, 56, (1,), generator=g))
        ramp = float(torch.rand(1, generator=g)) * yy / 64 + 0.05 * (yy > edge).float()
        views.append(ramp[None].expand(3, -1, -1) + 0.01 * torch.randn(3, 64, 64, generator=g))
    rows = torch.stack(views)
    assert lattice_score(rows, 8).ratio == pytest.approx(1.0, abs=0.25)
    assert lattice_score(rows.transpose(2, 3), 8).ratio == pytest.approx(1.0, abs=0.25)
    bands = 0.05 * torch.cos(2 * torch.pi * yy / 8)
    assert lattice_score(rows + bands, 8).ratio > 1.5
