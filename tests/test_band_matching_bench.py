"""benchmarks/band_matching.py: the band scores and the captured generator maps."""

from __future__ import annotations

import pytest
import torch
from benchmark_scripts import load_benchmark

from prosplat.generator import Generator, GeneratorConfig


def test_band_scores_peak_at_the_truth_random_and_out_of_band_pixels():
    bench = load_benchmark("band_matching")
    v, h, w, dc = 2, 4, 6, 9
    t = torch.full((v, 1, h, w), 0.5)
    offsets = torch.linspace(-0.1, 0.1, dc)
    band = t + offsets[None, :, None, None]  # [V,Dc,h,w]
    t_true = t + 0.05  # on candidate 6 (0.025 spacing)
    t_true[0, 0, 0] = 0.9  # row 0 of view 0: outside the band
    covered = torch.ones_like(t)
    covered[1, 0, :, 0] = 0.5  # a column of view 1 half sky: not scored
    peak = torch.zeros(v, dc, h, w)
    peak[:, 6] = 1.0
    row = bench.band_scores(
        t, t_true, covered, band, {"peak": peak, "flat": -peak}, 0.1, torch.Generator()
    )
    scored = v * h * w - w - h  # minus the out-of-band row and the half-covered column
    assert row["in band"] == pytest.approx(scored / (v * h * w))
    assert row["estimate"] == pytest.approx(0.05)
    assert row["peak"] == pytest.approx(0.0, abs=1e-6)
    assert row["flat"] == pytest.approx(0.15)  # argmax of -peak: candidate 0 (ties: first)
    assert 0.0 < row["random"] < 0.15


def test_captured_holds_the_depth_heads_t_and_the_matching_features():
    bench = load_benchmark("band_matching")
    cfg = GeneratorConfig(
        feature_channels=8, num_depth_candidates=4, fine_matching_channels=4, mono_channels=8,
        mono_blocks=1, unet_channels=(8, 8, 8), refine_channels=4,
    )  # fmt: skip
    g = Generator(cfg).eval()
    captured = bench.Captured(g)
    K = torch.tensor([[32.0, 0, 16], [0, 32.0, 16], [0, 0, 1]]).expand(1, 2, 3, 3)
    w2c = torch.eye(4).repeat(1, 2, 1, 1)
    w2c[0, 1, 0, 3] = 0.3
    with torch.no_grad():
        g(torch.rand(1, 2, 3, 32, 32), K, w2c, 1.0, 10.0)
    assert captured.maps["t"].shape == (2, 1, 8, 8)
    assert captured.maps["feats"].shape == (1, 2, 8, 8, 8)
    assert captured.maps["fine"].shape == (1, 2, 4, 16, 16)
    captured.close()
    captured.maps.clear()
    with torch.no_grad():
        g(torch.rand(1, 2, 3, 32, 32), K, w2c, 1.0, 10.0)
    assert not captured.maps  # the hooks are gone
