"""benchmarks/sweep_speed.py compares like with like: the sweeps it reads from git at the
commit before the speed-ups compute the volumes today's code does, so its timings compare
the same work, and today's faster code is the older code's numbers."""

from __future__ import annotations

import subprocess

import pytest
import torch
from benchmark_scripts import BENCHMARKS, load_benchmark

from prosplat import Camera
from prosplat.generator.cost_volume import (
    inverse_depth_candidates,
    nearest_views,
    plane_sweep_cost_volume,
)
from prosplat.generator.image_cost import image_cost_volume

BEFORE = "f3f56fe"  # the last commit before the all-pairs correlation and the in-place sweeps


@pytest.fixture(scope="module")
def before(tmp_path_factory):
    found = subprocess.run(
        ["git", "cat-file", "-e", f"{BEFORE}^{{commit}}"], cwd=BENCHMARKS.parent,
        capture_output=True,
    )  # fmt: skip
    if found.returncode:
        pytest.skip(f"commit {BEFORE} is not in this clone's history (a shallow clone)")
    return load_benchmark("sweep_speed").sweeps_at(BEFORE, tmp_path_factory.mktemp("before"))


def _rig(size: int, views: int = 4):
    """Views on an arc facing a point 4 units out, the last one facing back at the others
    (candidates behind it), as [1,V,3,3] K and [1,V,4,4] w2c at ``size`` x ``size``."""
    cams = [Camera.look_at((0.4 * i, 0.1 * i, 0.0), (0.0, 0.0, 4.0), (0, -1, 0), size, size, size)
            for i in range(views - 1)]  # fmt: skip
    cams.append(Camera.look_at((0.3, 0.0, 6.0), (0.0, 0.0, 0.0), (0, -1, 0), size, size, size))
    K = torch.stack([c.K for c in cams]).float()[None]
    w2c = torch.stack([c.world_to_cam for c in cams]).float()[None]
    return K, w2c


@pytest.mark.parametrize("size", [16, 64])  # all pairs first (16² px), warped first (64²)
def test_cost_volume_is_the_one_before_the_speed_ups(before, size) -> None:
    old_cost, _ = before
    torch.manual_seed(0)
    K, w2c = _rig(size)
    feats = torch.randn(1, 4, 8, size, size)
    cands = inverse_depth_candidates(torch.tensor([1.0]), torch.tensor([20.0]), 12)
    nbrs = nearest_views(w2c, 3)
    with torch.no_grad():
        now = plane_sweep_cost_volume(feats, K, w2c, cands, nbrs)
        then = old_cost(feats, K, w2c, cands, nbrs)
    # the warp grids differ by float rounding (1e-6 of the image, multiplied by 1/z once where
    # it was divided twice), which random per-pixel features turn into 2e-5 at 64² px
    assert torch.allclose(now, then, atol=1e-4)


def test_image_cost_volume_is_the_one_before_the_speed_ups(before) -> None:
    _, old_image_cost = before
    torch.manual_seed(1)
    K, w2c = _rig(32)
    images = torch.rand(1, 4, 3, 32, 32)
    cands = inverse_depth_candidates(torch.tensor([1.0]), torch.tensor([20.0]), 12)
    nbrs = nearest_views(w2c, 2)
    now = image_cost_volume(images, K, w2c, cands, nbrs, 5, 2)
    then = old_image_cost(images, K, w2c, cands, nbrs, 5, 2)
    assert torch.allclose(now, then, atol=1e-5)


def test_correlation_table_runs(capsys) -> None:
    bench = load_benchmark("sweep_speed")
    bench.SHAPES = ((4, 8, 8),)
    bench.time_correlations(1)
    assert "| 4, 8, 8 |" in capsys.readouterr().out


def test_parts_table_runs(before, tmp_path, capsys) -> None:
    """Part 2 times the changed pieces of the commit before against now (tiny shapes)."""
    bench = load_benchmark("sweep_speed")
    bench.time_parts(bench.modules_at(BEFORE, tmp_path), 1, size=16)
    out = capsys.readouterr().out
    for part in ("box filter", "warp grid", "correlation"):
        assert f"| {part} |" in out
