"""benchmarks/artist_speed.py: the speed table at artist sizes, run end to end on the
analytic scene at a tiny size (the numbers in BENCHMARKS.md come from a 512-px scene)."""

from __future__ import annotations

import json
import math

from benchmark_scripts import load_benchmark


def test_every_step_is_timed_against_its_target_and_written(tmp_path):
    bench = load_benchmark("artist_speed")
    result = bench.main(["--size", "64", "--repeats", "1", "--out", str(tmp_path)])
    assert list(result["seconds"]) == list(bench.TARGETS)
    assert all(0 < s < 120 and math.isfinite(s) for s in result["seconds"].values())
    assert result["gaussians"] > 0 and result["peak_rss_gb"] > 0
    assert json.loads((tmp_path / "speed.json").read_text())["seconds"] == result["seconds"]
    assert (tmp_path / "speed.png").stat().st_size > 1000
    text = bench.table(result)
    assert text.count("\n| ") == 1 + len(bench.TARGETS) and "| target s |" in text
    assert "| raw view, 64 px (warm) |" in text and "SIZE" not in text  # the size named
    cam = bench.scene_views(None, 64)[2]
    big = bench.hd(cam)
    assert (big.width, big.height) == (1920, 1080)
    assert float(big.K[0, 0]) == float(cam.K[0, 0]) * 1920 / 64
