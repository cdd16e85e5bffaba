"""benchmarks/poses.py: evenly spaced subsets, medians over repeats, and a whole run on three
small synthetic photos (registered or not: a failed run is a row too) writing its table,
json and plot."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from benchmark_scripts import load_benchmark

try:
    from prosplat.poses import estimate_poses  # noqa: F401  (the benchmark's subject)
except ImportError:  # the pose step is not there yet: nothing to time
    pytest.skip("prosplat.poses.estimate_poses is not available", allow_module_level=True)


def test_subset_is_evenly_spaced_with_both_ends() -> None:
    bench = load_benchmark("poses")
    photos = [Path(f"{k:04d}.jpg") for k in range(50)]
    ten = bench.subset(photos, 10)
    assert ten[0] == photos[0] and ten[-1] == photos[-1] and len(set(ten)) == 10
    steps = np.diff([photos.index(p) for p in ten])
    assert steps.min() >= 5 and steps.max() <= 6
    assert bench.subset(photos, 50) == photos and bench.subset(photos, 80) == photos


def test_summary_takes_medians_and_keeps_a_failure() -> None:
    bench = load_benchmark("poses")
    runs = [
        {"seconds": dict.fromkeys(bench.PHASES, s), "total": 5 * s, "registered": n,
         "reprojection_error": e, "error": None}
        for s, n, e in [(1.0, 9, 0.5), (3.0, 10, 0.7), (2.0, 10, 0.6)]
    ]  # fmt: skip
    s = bench.summarise(runs)
    assert s["seconds"]["match"] == 2.0 and s["total"] == 10.0
    assert s["registered"] == 10 and s["reprojection_error"] == 0.6
    failed = {"seconds": {}, "total": 1.0, "registered": 0, "reprojection_error": None,
              "error": "only 1 of 3 photos could be matched"}  # fmt: skip
    assert bench.summarise([failed])["error"].startswith("only 1 of 3")
    rows = [
        {"photos": 3, "feature_size": 256, "matching": "exhaustive", **bench.summarise([failed])}
    ]
    assert "| 3 | 256 | exhaustive |" in bench.table(rows) and "failed" in bench.table(rows)


def _rotation(axis, degrees: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.radians(degrees)
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k


def test_pose_errors_see_through_a_similarity_transform() -> None:
    """Poses moved, turned and scaled as a whole have no error; one camera turned by 3° and
    one moved shows up in the medians only as far as they are the median."""
    bench = load_benchmark("poses")
    rng = np.random.default_rng(0)
    ref = {}
    for k in range(5):
        c2w = np.eye(4)
        c2w[:3, :3] = _rotation(rng.normal(size=3), rng.uniform(0, 180))
        c2w[:3, 3] = rng.normal(size=3) * 2
        ref[f"{k:04d}"] = c2w
    turn, scale, shift = _rotation([1, 2, 3], 40), 0.3, np.array([5.0, -1.0, 2.0])
    est = {}
    for k, c2w in ref.items():
        e = np.eye(4)
        e[:3, :3] = turn @ c2w[:3, :3]
        e[:3, 3] = scale * turn @ c2w[:3, 3] + shift
        est[k] = e
    errs = bench.pose_errors(est, ref)
    assert errs["rotation_deg"] < 1e-6 and errs["centre_pct"] < 1e-6
    est["0000"][:3, :3] = est["0000"][:3, :3] @ _rotation([0, 1, 0], 3)
    est["0001"][:3, :3] = est["0001"][:3, :3] @ _rotation([1, 0, 0], 3)
    est["0002"][:3, :3] = est["0002"][:3, :3] @ _rotation([0, 0, 1], 3)
    assert bench.pose_errors(est, ref)["rotation_deg"] == pytest.approx(3.0, abs=1e-6)
    assert bench.pose_errors({"0000": est["0000"]}, ref) is None


def test_runs_on_three_small_photos(tmp_path, capsys) -> None:
    """Three 240x180 crops of one textured picture, shifted and zoomed a little."""
    rng = np.random.default_rng(0)
    blocks = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    texture = np.kron(blocks, np.ones((3, 3, 1), np.uint8))  # 360x480
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(3):
        crop = np.ascontiguousarray(texture[40 + 10 * k : 220 + 10 * k, 60 + 30 * k : 300 + 30 * k])
        buf = oiio.ImageBuf(oiio.ImageSpec(240, 180, 3, oiio.UINT8))
        buf.set_pixels(oiio.ROI(), crop)
        assert buf.write(str(photos / f"p{k}.png")), oiio.geterror()
    out = tmp_path / "bench"
    bench = load_benchmark("poses")
    rows = bench.main(["--photos", str(photos), "--counts", "3", "--feature-sizes", "256",
                       "--matching", "exhaustive", "--out", str(out)])  # fmt: skip
    assert len(rows) == 1 and rows[0]["photos"] == 3
    assert "| 3 | 256 | exhaustive |" in capsys.readouterr().out
    saved = json.loads((out / "poses.json").read_text())
    assert saved["rows"][0]["feature_size"] == 256 and saved["meta"]["repeats"] == 1
    assert (out / "poses.png").stat().st_size > 0 and (out / "poses.md").is_file()
