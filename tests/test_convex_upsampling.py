"""Learned x4 depth upsampling (``GeneratorConfig.convex_upsampling``) and growing trained
weights by it."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
import torch.nn.functional as F
from test_generator import SMALL, grown_then_trained

from prosplat.train.generator import TrainConfig


def test_convex_upsample_is_bilinear_at_zero_and_follows_its_weights():
    """Zero logits reproduce torch's bilinear x4 (align_corners=False, borders clamped) and
    large logits pick one of the four samples bilinear reads: a step edge stays a step."""
    from prosplat.generator.depth_head import convex_upsample

    torch.manual_seed(0)
    t = torch.rand(2, 1, 8, 6, dtype=torch.float64)
    zero = torch.zeros(2, 4, 32, 24, dtype=torch.float64)
    bilinear = F.interpolate(t, size=(32, 24), mode="bilinear", align_corners=False)
    torch.testing.assert_close(convex_upsample(t, zero), bilinear, atol=1e-5, rtol=0)
    step = torch.zeros(1, 1, 4, 4, dtype=torch.float64)
    step[..., 2:] = 1.0  # a depth edge between low-res columns 1 and 2
    ramp = convex_upsample(step, torch.zeros(1, 4, 16, 16, dtype=torch.float64))
    assert 0.1 < float(ramp[0, 0, 5, 7]) < 0.9  # bilinear: in between at the edge
    pick_left = torch.full((1, 4, 16, 16), -30.0, dtype=torch.float64)
    pick_left[:, [0, 2]] = 30.0  # columns i0 only
    sharp = convex_upsample(step, pick_left)
    assert float(sharp[0, 0, 5, 7]) < 1e-6 and float(sharp[0, 0, 5, 12]) > 1 - 1e-6


def test_grow_convex_upsampling_reproduces_the_trained_network_then_learns():
    """Growing weights by learned upsampling gives the same Gaussians (its conv is zero, which
    is bilinear), and a gradient step opens it."""
    from prosplat.generator.grow import grow_convex_upsampling

    old, cfg, state, new = grown_then_trained(
        SMALL, lambda c, s, _: grow_convex_upsampling(c, s), 0
    )
    assert cfg == replace(SMALL, convex_upsampling=True)
    assert new.refiner.mask.weight.grad.abs().max() > 0
    with pytest.raises(ValueError, match="already"):
        grow_convex_upsampling(cfg, state)
    with pytest.raises(ValueError, match="grow_convex_upsampling"):
        TrainConfig(data="x", out="y", grow_convex_upsampling=True)


def test_depth_upsampling_bench_round_trips():
    """benchmarks/depth_upsampling.py: a constant depth comes back from every method, a depth
    constant over each 4x4 cell from all but bilinear; at a step edge off the cells' grid
    bilinear invents in-between depths, the best of the four samples it reads does not, and
    the sky stays far."""
    from benchmark_scripts import load_benchmark

    bench = load_benchmark("depth_upsampling")
    cells = torch.tensor([[1.0, 2.0], [4.0, 8.0]]).repeat_interleave(4, 0).repeat_interleave(4, 1)
    for method in bench.METHODS:
        flat = torch.full((1, 8, 12), 3.0)
        torch.testing.assert_close(bench.upsampled_depths(flat, method), flat, rtol=1e-5, atol=0)
        if method != "bilinear":
            out = bench.upsampled_depths(cells[None], method)
            torch.testing.assert_close(out, cells[None], rtol=1e-5, atol=0)
    step = torch.full((1, 16, 16), 2.0)
    step[..., 6:] = 8.0  # the edge cuts cell 1 (columns 4-7) in half
    step[:, :4] = 0.0  # sky over the top row of cells
    far = bench.SKY_DEPTH_FACTOR * 8.0
    bil = bench.upsampled_depths(step, "bilinear")
    best = bench.upsampled_depths(step, "best of 4")
    values = {2.0, 8.0, far}
    assert any(min(abs(float(v) - u) for u in values) > 0.5 for v in bil[0, 8])
    assert float(best[0, 0, 0]) == pytest.approx(far)  # the sky: at the shell, not nearer
    assert abs(float(best[0, 8, 1]) - 2.0) < 1e-4 and abs(float(best[0, 8, 14]) - 8.0) < 1e-4
