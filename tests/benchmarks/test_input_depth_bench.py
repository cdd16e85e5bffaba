"""benchmarks/input_depth.py: the depth scores, the scale bias's sign included."""

from __future__ import annotations

import math

import pytest
import torch
from benchmark_scripts import load_benchmark


def _module():
    return load_benchmark("input_depth")


@pytest.mark.parametrize("factor", [0.7, 0.85, 1.0, 1.3])
def test_depth_scores_bias_has_the_sign_of_the_error(factor):
    gt = torch.linspace(1.0, 9.0, 2 * 8 * 8).reshape(2, 8, 8).double()
    pred = gt * factor
    pred[0, 0, :3] = 100.0  # a few wild pixels move AbsRel's mean, not the median bias
    mask = torch.ones_like(gt, dtype=torch.bool)
    mask[1, -1] = False
    s = _module().depth_scores(pred, gt, mask)
    assert s["bias"] == pytest.approx(math.log(factor), abs=1e-9)
    assert s["median"] == pytest.approx(abs(factor - 1), abs=1e-9)
    assert s["mean"] > s["median"]
    expected_delta = (1 - 3 / int(mask.sum())) if 0.8 < factor < 1.25 else 0.0
    assert s["delta"] == pytest.approx(expected_delta)
