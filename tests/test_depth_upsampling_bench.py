"""benchmarks/depth_upsampling.py: the 1/4-resolution round trips of the true-depth bound."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from benchmark_scripts import load_benchmark


def test_bilinear_support_matches_torch():
    """The four samples and weights the benchmark reads are torch's own bilinear x4
    (align_corners=False, borders clamped)."""
    bench = load_benchmark("depth_upsampling")
    torch.manual_seed(0)
    low = torch.rand(2, 1, 8, 6, dtype=torch.float64)
    y0, y1, fy = bench.bilinear_support(8, 32)
    x0, x1, fx = bench.bilinear_support(6, 24)
    rows = low[:, :, y0] * (1 - fy)[:, None] + low[:, :, y1] * fy[:, None]  # [2,1,32,6]
    ours = rows[..., x0] * (1 - fx) + rows[..., x1] * fx
    torch.testing.assert_close(ours, F.interpolate(low, size=(32, 24), mode="bilinear"))


def test_depth_upsampling_bench_round_trips():
    """benchmarks/depth_upsampling.py: a constant depth comes back from every method, a depth
    constant over each 4x4 cell from all but bilinear; at a step edge off the cells' grid
    bilinear invents in-between depths, the best of the four samples it reads does not, and
    the sky stays far; a map that does not split into cells is refused."""
    bench = load_benchmark("depth_upsampling")
    cells = torch.tensor([[1.0, 2.0], [4.0, 8.0]]).repeat_interleave(4, 0).repeat_interleave(4, 1)
    for method in bench.METHODS:
        flat = torch.full((1, 8, 12), 3.0)
        for factor in (2, 4):
            out = bench.upsampled_depths(flat, method, factor)
            torch.testing.assert_close(out, flat, rtol=1e-5, atol=0)
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
    with pytest.raises(ValueError, match="--size and --factor"):
        bench.upsampled_depths(torch.full((1, 8, 10), 3.0), "bilinear", 4)  # 10 px wide
