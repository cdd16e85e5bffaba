"""The cost volume's correlation: ``einsum`` (the code until 2026-11-26) against multiplying and
summing over channels (now), alone and inside a whole generator training step.

``torch.einsum("bvchw,bvcdhw->bvdhw")`` contracts over C through a batched matmul of per-pixel
1xC by CxD products, so it first copies the warped volume [B,V,C,D,h,w] into a pixel-major
layout, forward and backward; a profile of a 128-px training step put a third of the
generator's time in that copy. The multiply-and-sum reads both tensors in their own layout.

Part 1 times the op alone at the training shapes (forward + backward). Part 2 runs the same
fixed training batches (`benchmarks/generator_step.py`) with each correlation swapped into
the cost volume (``prosplat.generator.cost_volume.correlate``), interleaved so both see the
same machine load; medians over ``--repeats``.

    OMP_NUM_THREADS=1 python benchmarks/cost_volume.py --data data/val128 --steps 10
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch
from torch import Tensor

import prosplat.generator.cost_volume as cost_volume

#: (B, V, C, D, h, w) of the volumes a training step correlates: the coarse volume of 4 views
#: at 128 px (64 px features), the fine one (48 candidates at 32 px), 6 views at 64 px
SHAPES = ((1, 4, 32, 16, 64, 64), (1, 4, 32, 48, 32, 32), (1, 6, 32, 16, 32, 32))


def einsum_correlation(feats: Tensor, warped: Tensor) -> Tensor:
    return torch.einsum("bvchw,bvcdhw->bvdhw", feats, warped)


def time_op(repeats: int) -> None:
    print("| B, V, C, D, h, w | einsum ms | multiply-and-sum ms | speed-up |")
    print("|---|---:|---:|---:|")
    for shape in SHAPES:
        b, v, c, d, h, w = shape
        feats = torch.randn(b, v, c, h, w, requires_grad=True)
        warped = torch.randn(b, v, c, d, h, w, requires_grad=True)
        grad = torch.randn(b, v, d, h, w)
        times: dict[str, list[float]] = {"einsum": [], "sum": []}
        for _ in range(repeats):
            for name, fn in (("einsum", einsum_correlation), ("sum", cost_volume.correlate)):
                t0 = time.perf_counter()
                fn(feats, warped).backward(grad)
                times[name].append(time.perf_counter() - t0)
        e, s = (statistics.median(times[k]) * 1e3 for k in ("einsum", "sum"))
        print(f"| {', '.join(map(str, shape))} | {e:.0f} | {s:.0f} | {e / s:.2f}x |")


def time_steps(data: str, sizes: list[int], steps: int, repeats: int) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from generator_step import batches, step

    from prosplat.metrics import LPIPS
    from prosplat.pipeline import ProSplat
    from prosplat.train.generator import TrainConfig

    lpips_fn = LPIPS()
    model = ProSplat.from_pretrained().generator.train()
    shipped = cost_volume.correlate
    print("| inputs px | correlation | forward ms | loss ms | backward ms | step ms |")
    print("|---:|---|---:|---:|---:|---:|")
    for size in sizes:
        # v8's losses; the targets at 2x the inputs at 64 px, at the inputs' size at 128 px
        cfg = TrainConfig(data=data, out="", sizes=str(size), target_scale=2 if size < 128 else 1,
                          targets=2, any_view=True, input_depth_weight=1, depth_weight=0.1,
                          input_render_weight=0.5)  # fmt: skip
        fixed, _ = batches(cfg, steps, seed=1)
        rounds: dict[str, list[dict]] = {"einsum": [], "multiply-and-sum": []}
        try:
            for _ in range(repeats):
                for name, fn in (("einsum", einsum_correlation), ("multiply-and-sum", shipped)):
                    cost_volume.correlate = fn  # looked up by plane_sweep_cost_volume per call
                    parts = [step(model, batch, cfg, lpips_fn, "cpu-fused") for batch in fixed]
                    rounds[name].append({k: statistics.mean(p[k] for p in parts) for k in parts[0]})
        finally:
            cost_volume.correlate = shipped
        for name, r in rounds.items():
            med = {k: statistics.median(x[k] for x in r) * 1e3 for k in r[0]}
            print(f"| {size} | {name} | {med['forward']:.0f} | {med['loss']:.0f} | "
                  f"{med['backward']:.0f} | {med['step']:.0f} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/val128", help="scene folders for the step batches")
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="input heights")
    ap.add_argument("--steps", type=int, default=10, help="fixed batches per round")
    ap.add_argument("--repeats", type=int, default=3, help="rounds (the median is reported)")
    ap.add_argument("--op-only", action="store_true", help="part 1 only")
    args = ap.parse_args()
    print(f"torch threads {torch.get_num_threads()}")
    time_op(max(args.repeats, 5))
    if not args.op_only:
        time_steps(args.data, args.sizes, args.steps, args.repeats)


if __name__ == "__main__":
    main()
