"""benchmarks/enhance_views.py's summary: the raw view scored on black, with its holes filled
(issue 12's re-rendered inputs are scored filled) and filled as the pipeline shows it (the
colour favouring the nearest input), then each stage-2 variant."""

from __future__ import annotations

from benchmark_scripts import load_benchmark


def test_summary_reports_the_raw_view_on_black_and_filled() -> None:
    bench = load_benchmark("enhance_views")
    rows = [
        {"size": 64, "psnr_raw": 10.0 + k, "lpips_raw": 0.5, "psnr_filled": 20.0 + k,
         "lpips_filled": 0.25, "psnr_favoured": 21.0 + k, "lpips_favoured": 0.2,
         "psnr m ws64": 30.0, "lpips m ws64": 0.1,
         "departure m ws64": 0.0, "coverage": 1.0}
        for k in range(2)
    ]  # fmt: skip
    text = bench.summary(rows, ["m ws64"])
    header, rule, row = text.splitlines()[:3]
    assert header == (
        "| size | views | raw PSNR / LPIPS | raw, holes filled | filled, nearest input favoured "
        "| m ws64 PSNR / LPIPS |"
    )
    assert rule.count("|---") == 6
    assert row == "| 64 | 2 | 10.50 / 0.500 | 20.50 / 0.250 | 21.50 / 0.200 | 30.00 / 0.100 |"
