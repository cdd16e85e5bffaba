"""Plot the stage-2 ablation (``prosplat eval improve``'s scores.json): PSNR gain and LPIPS
against ms per view, one point per row, interpolation and extrapolation separately.

    python benchmarks/ablation_plot.py out/ablation/scores.json --out docs/ablation_tiny64.png

Prints each row's mean gain over "generator only" on the same views (all input-view counts).
"""

from __future__ import annotations

import argparse
import json
import statistics
from collections import defaultdict
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scores", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    rows = json.loads(args.scores.read_text())
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in rows:
        groups[(r["method"], r["kind"])].append(r)
    ref = "generator only"
    print("| row | targets | Δ PSNR vs generator | LPIPS | ms/view (median) |")
    print("|---|---|---:|---:|---:|")
    points = []
    for (method, kind), sub in sorted(groups.items()):
        gen = groups[(ref, kind)]
        gain = statistics.mean(r["psnr"] for r in sub) - statistics.mean(r["psnr"] for r in gen)
        lp = statistics.mean(r["lpips"] for r in sub)
        ms = statistics.median(r["render_ms"] for r in sub)
        points.append((method, kind, gain, lp, ms))
        print(f"| {method} | {kind} | {gain:+.2f} | {lp:.3f} | {ms:.1f} |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, (k, label) in zip(axes, [(2, "Δ PSNR vs generator only (dB)"), (3, "LPIPS")]):
        for kind, marker in (("interpolation", "o"), ("extrapolation", "s")):
            pts = [p for p in points if p[1] == kind]
            ax.scatter([p[4] for p in pts], [p[k] for p in pts], marker=marker, label=kind)
            for p in pts:
                ax.annotate(
                    p[0].split(".")[0],
                    (p[4], p[k]),
                    fontsize=7,
                    xytext=(3, 2),
                    textcoords="offset points",
                )
        ax.set_xlabel("ms per view (render + MORI + enhancement, median)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("stage-2 ablation, test split at 64², 2/4/6 input views (labels: table rows)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)


if __name__ == "__main__":
    main()
