"""Stage-2 checkpoints side by side on a curated validation set: PSNR, LPIPS and the
fixed-pattern score of the change each makes (``prosplat.improve.pattern``).

    python benchmarks/stage2_val.py --data runs/s2v2/val.safetensors \\
        --improve v1=prosplat/weights/improve_tiny.safetensors --improve v2=runs/s2v2/run/improve.safetensors

Curated samples are whole views at the curated size, with alpha when the set has it (models
without the alpha input ignore it).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from prosplat.improve.io import load_improver
from prosplat.improve.pattern import fixed_pattern_score
from prosplat.metrics import LPIPS, psnr
from prosplat.train.curate import curated_alpha, curated_batch, load_curated


@torch.no_grad()
def score(model, data, lpips: LPIPS, batch: int = 16) -> dict[str, float]:
    n = data["render"].shape[0]
    ps, lp, changes, ps_raw, lp_raw = [], [], [], [], []
    for i in range(0, n, batch):
        idx = torch.arange(i, min(n, i + batch))
        raw, ref, fund, gt = curated_batch(data, idx, "paper", "cpu")
        alpha = curated_alpha(data, idx, "cpu")
        out = model(raw, ref, fund, alpha)
        ps += [float(psnr(o, g)) for o, g in zip(out, gt, strict=True)]
        lp += lpips(out, gt).flatten().tolist()
        ps_raw += [float(psnr(o, g)) for o, g in zip(raw, gt, strict=True)]
        lp_raw += lpips(raw, gt).flatten().tolist()
        changes.append(out - raw)
    mean = lambda v: sum(v) / len(v)  # noqa: E731
    return {
        "raw_psnr": mean(ps_raw),
        "raw_lpips": mean(lp_raw),
        "psnr": mean(ps),
        "lpips": mean(lp),
        "pattern": fixed_pattern_score(torch.cat(changes)).ratio,
        "n": n,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="curated validation set")
    p.add_argument("--improve", action="append", required=True, help="LABEL=PATH (repeatable)")
    args = p.parse_args(argv)
    data = load_curated(args.data)
    lpips = LPIPS()
    print("| model | samples | raw PSNR / LPIPS | PSNR / LPIPS | pattern |")
    print("|---|---|---|---|---|")
    for spec in args.improve:
        label, _, path = spec.rpartition("=")
        s = score(load_improver(path).eval(), data, lpips)
        print(
            f"| {label or path} | {s['n']} | {s['raw_psnr']:.2f} / {s['raw_lpips']:.3f} | "
            f"{s['psnr']:.2f} / {s['lpips']:.3f} | {s['pattern']:.2f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
