"""benchmarks/plane_peaks.py: the peak errors and the variant names."""

from __future__ import annotations

import pytest
import torch
from benchmark_scripts import load_benchmark


def test_peak_errors_read_the_argmax_plane_in_t_on_covered_pixels():
    bench = load_benchmark("plane_peaks")
    v, d, h, w = 2, 5, 3, 4  # planes at t = 1, 0.75, 0.5, 0.25, 0 (near -> far)
    volume = torch.zeros(v, d, h, w)
    volume[0, 1] = 1.0  # view 0 peaks at t = 0.75
    volume[1, 4] = 1.0  # view 1 at t = 0
    t_true = torch.full((v, h, w), 0.7)
    covered = torch.ones(v, h, w, dtype=torch.bool)
    covered[1, 0] = False  # a row of view 1 is sky: not scored
    e = bench.peak_errors(volume, t_true, covered)
    assert e.shape == (h * w + (h - 1) * w,)
    assert torch.allclose(e[: h * w], torch.tensor(0.05))
    assert torch.allclose(e[h * w :], torch.tensor(0.7))


def test_image_variant_names():
    bench = load_benchmark("plane_peaks")
    assert bench.image_variant("half w5") == (2, 5)
    assert bench.image_variant("full w3") == (1, 3)
    with pytest.raises(KeyError):
        bench.image_variant("quarter w3")
