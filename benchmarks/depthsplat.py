"""DepthSplat encoder on the CPU: time and peak memory of one forward pass.

Random weights by the parity recipe (the speed does not depend on the values); 4 views
at 256x448 with the small configuration by default, as the issue's target.

    python benchmarks/depthsplat.py [--config small] [--views 4] [--size 256 448] \
        [--repeats 3] [--threads 2] [--profile]

Runs the forward passes in this process after one warm-up pass; prints as JSON the
median wall time and every time, the median process CPU time (user + system, all threads:
on a busy machine the wall time says more about the neighbours than about the model), the
load average, and the process's peak RSS (ru_maxrss: weights, activations, torch itself).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import time

import torch

from prosplat.generator.depthsplat import random_encoder
from prosplat.generator.depthsplat.config import BASE, BASE_448, LARGE, SMALL, SMALL_448

CONFIGS = {
    "small": SMALL,
    "small_448": SMALL_448,
    "base": BASE,
    "base_448": BASE_448,
    "large": LARGE,
}


def inputs(v: int, h: int, w: int, device):
    g = torch.Generator().manual_seed(0)
    images = torch.rand(1, v, 3, h, w, generator=g)
    K = torch.tensor([[0.9, 0, 0.5], [0, 0.9 * w / h, 0.5], [0, 0, 1]]).expand(1, v, 3, 3).clone()
    c2w = torch.eye(4).repeat(1, v, 1, 1)
    for i in range(v):  # cameras on an arc looking at the origin
        a = (i - (v - 1) / 2) * 0.3
        eye = torch.tensor([3 * math.sin(a), 0.1 * i, -3 * math.cos(a)])
        z = -eye / eye.norm()
        x = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0]), z)
        x = x / x.norm()
        c2w[0, i, :3, :3] = torch.stack([x, torch.linalg.cross(z, x), z], dim=1)
        c2w[0, i, :3, 3] = eye
    near, far = torch.full((1, v), 1.0), torch.full((1, v), 10.0)
    return [t.to(device) for t in (images, K, c2w, near, far)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", default="small", choices=sorted(CONFIGS))
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", type=int, nargs=2, default=(256, 448))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.set_grad_enabled(False)
    model = random_encoder(CONFIGS[args.config], 0).to(args.device)
    x = inputs(args.views, *args.size, args.device)
    sync = torch.cuda.synchronize if args.device.startswith("cuda") else (lambda: None)
    model.forward_reference(*x)  # warm-up
    sync()
    times, cpu = [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        model.forward_reference(*x)
        sync()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    if args.profile:
        from torch.profiler import profile

        with profile() as prof:
            model.forward_reference(*x)
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=15))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # GiB (ru_maxrss in KiB)
    result = {
        "config": args.config,
        "views": args.views,
        "size": list(args.size),
        "threads": args.threads,
        "device": args.device,
        "median_s": round(statistics.median(times), 2),
        "times_s": [round(t, 2) for t in times],
        "median_cpu_s": round(statistics.median(cpu), 2),
        "load_avg": round(os.getloadavg()[0], 1),
        "peak_rss_gib": round(rss, 2),
    }
    if args.device.startswith("cuda"):
        result["peak_cuda_gib"] = round(torch.cuda.max_memory_allocated() / 2**30, 2)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
