"""Plot a training run's loss and validation curve from its ``log.jsonl``.

    python benchmarks/training_curve.py runs/tiny/log.jsonl --out docs/train_tiny.png

Prints the validation rows as a Markdown table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("log", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    rows = [json.loads(line) for line in args.log.read_text().splitlines() if line.strip()]
    val = [r for r in rows if "val_psnr" in r]
    nan = float("nan")
    print(
        "| step | minutes | train loss | val PSNR | val PSNR of the input (raw) | val SSIM | val LPIPS |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for r in val:  # stage-2 logs add val_psnr_raw; generator logs add val_ssim / val_lpips
        print(
            f"| {r['step']} | {r['seconds'] / 60:.1f} | {r['loss']:.4f} | {r['val_psnr']:.2f} | "
            f"{r.get('val_psnr_raw', nan):.2f} | {r.get('val_ssim', nan):.3f} | "
            f"{r.get('val_lpips', nan):.3f} |"
        )

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.5))
    a.plot([r["step"] for r in rows], [r["loss"] for r in rows], lw=0.8)
    a.set_xlabel("step")
    a.set_ylabel("train loss (MSE + λ·LPIPS)")
    b.plot([r["step"] for r in val], [r["val_psnr"] for r in val], "o-", label="val PSNR")
    if any("val_psnr_raw" in r for r in val):
        raw = [r["val_psnr_raw"] for r in val]
        b.plot([r["step"] for r in val], raw, ":", color="gray", label="val PSNR of the raw render")
    b.set_xlabel("step")
    b.set_ylabel("PSNR (dB)")
    if any("val_lpips" in r for r in val):
        c = b.twinx()
        c.plot(
            [r["step"] for r in val],
            [r["val_lpips"] for r in val],
            "s--",
            color="C1",
            label="val LPIPS",
        )
        c.set_ylabel("LPIPS")
    fig.legend(loc="upper center", ncol=2)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)


if __name__ == "__main__":
    main()
