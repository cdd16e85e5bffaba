"""One generator training step, timed by part: where the CPU time of `train generator` goes.

Fixed batches are drawn once from ``--data`` (so data loading is timed on its own), then each
step runs the generator forward, the render loss (every target and input camera) and the
backward pass, once with the torch projection (``--backends cpu``) and once with the fused C++
projection (``cpu-fused``, what training uses), interleaved so both see the same machine load.
Prints the median per part over ``--repeats`` rounds, and a cProfile of one backend's steps.

    OMP_NUM_THREADS=1 python benchmarks/generator_step.py --data data/train128 --steps 20
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from prosplat.data import SceneDataset
from prosplat.metrics import LPIPS
from prosplat.pipeline import ProSplat
from prosplat.train.generator import (
    TrainConfig,
    _model_inputs,
    render_loss,
    resize_batch,
)


def batches(cfg: TrainConfig, n: int, seed: int) -> tuple[list[dict], float]:
    """n collated single-scene batches (inputs at the step's size, targets at target_scale x)
    and the median seconds a scene takes to load from disk (no cache)."""
    ds = SceneDataset(cfg.data, n_inputs=4, n_targets=cfg.targets, seed=seed, any_view=True)
    ds_nocache = SceneDataset(cfg.data, n_inputs=4, n_targets=cfg.targets, cache_size=0)
    out, load = [], []
    size = cfg.size_choices[0]
    for i in range(n):
        t0 = time.perf_counter()
        ds_nocache.scene(i % len(ds_nocache))
        load.append(time.perf_counter() - t0)
        views = (2, 3, 4, 5, 6)[i % 5]
        item = ds[(i % len(ds), 0, views)]
        batch = {k: v[None] for k, v in item.items()}
        out.append(resize_batch(batch, size, size * cfg.target_scale))
    return out, statistics.median(load)


def step(model, batch, cfg, lpips_fn, backend: str) -> dict[str, float]:
    """Seconds of forward, loss (renders + LPIPS) and backward for one batch."""
    model.zero_grad(set_to_none=True)
    t0 = time.perf_counter()
    output = model(*_model_inputs(batch))
    t1 = time.perf_counter()
    loss, _ = render_loss(output, batch, cfg, lpips_fn, cpu_backend=backend)
    t2 = time.perf_counter()
    loss.backward()
    t3 = time.perf_counter()
    return {"forward": t1 - t0, "loss": t2 - t1, "backward": t3 - t2, "step": t3 - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/train128")
    ap.add_argument("--weights", default=None, help="generator weights (default: shipped)")
    ap.add_argument("--steps", type=int, default=20, help="batches per round")
    ap.add_argument("--repeats", type=int, default=3, help="rounds (the median is reported)")
    ap.add_argument("--backends", default="cpu,cpu-fused")
    ap.add_argument("--profile", default="cpu-fused", help="backend to cProfile ('' for none)")
    args = ap.parse_args()
    cfg = TrainConfig(
        data=args.data, out="", sizes="64", target_scale=2, targets=2, any_view=True,
        input_depth_weight=0.3, depth_weight=0.1, input_render_weight=0.5,
    )  # fmt: skip
    lpips_fn = LPIPS() if cfg.lpips_weight > 0 else None
    model = ProSplat.from_pretrained(args.weights).generator.train()
    data, load_s = batches(cfg, args.steps, seed=1)
    backends = [b for b in args.backends.split(",") if b]
    rounds = {b: [] for b in backends}
    for _ in range(args.repeats):
        for b in backends:  # interleaved: both see the same load
            parts = [step(model, batch, cfg, lpips_fn, b) for batch in data]
            rounds[b].append({k: sum(p[k] for p in parts) / len(parts) for k in parts[0]})
    print(
        f"torch threads {torch.get_num_threads()}, {args.steps} steps x {args.repeats} rounds, "
        f"2-6 inputs + 2 targets at 64 px -> 128 px; a scene loads from disk in {load_s * 1e3:.0f} ms"
    )
    print("| backend | forward ms | loss ms (renders + LPIPS) | backward ms | step ms |")
    print("|---|---:|---:|---:|---:|")
    for b in backends:
        med = {k: statistics.median(r[k] for r in rounds[b]) * 1e3 for k in rounds[b][0]}
        print(
            f"| {b} | {med['forward']:.0f} | {med['loss']:.0f} | {med['backward']:.0f} "
            f"| {med['step']:.0f} |"
        )
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.enable()
        for batch in data:
            step(model, batch, cfg, lpips_fn, args.profile)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
