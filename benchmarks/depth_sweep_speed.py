"""Seconds to reconstruct with and without the depth sweep (``ProSplat.depth_sweep``), side by
side on the same scenes: the generator (+ sweep) + Gaussian budget, as ``reconstruct_pruned``
runs it, medians over ``--repeats`` runs of each scene, at each of ``--sizes``. With
``--scale-factors N...`` the sweep runs once per N, its scene-wide search trying N factors
(``DepthSweepOptions.scale_candidates``; 0: no search), all interleaved.

    python benchmarks/depth_sweep_speed.py --data data/test256 --sizes 64 128 256 --scenes 3 \
        --scale-factors 9 5
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from prosplat import ProSplat
from prosplat.data import find_scenes, load_scene
from prosplat.depth_sweep import DepthSweepOptions
from prosplat.evaluate import scene_at


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/test256")
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default torch's)")
    ap.add_argument(
        "--scale-factors",
        type=int,
        nargs="+",
        default=[DepthSweepOptions().scale_candidates],
        help="one sweep per count of scene-wide factors tried (default: the shipped count)",
    )
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.set_grad_enabled(False)
    model = ProSplat.from_pretrained(improve=False, depth_sweep=False)
    scenes = [load_scene(f) for f in find_scenes(args.data)[: args.scenes]]
    variants = {"without sweep": None} | {
        f"sweep, {k} factors": DepthSweepOptions(scale_candidates=k) for k in args.scale_factors
    }
    names = list(variants)
    print(
        f"| px | {' s | '.join(names)} s | ratios to without | ({torch.get_num_threads()} threads)"
    )
    print("|---:|" + "---:|" * (len(names) + 1))
    for size in args.sizes:
        times: dict[str, list[float]] = {name: [] for name in names}
        for scene in scenes:
            r = scene_at(scene, args.views, size)
            for _ in range(args.repeats):
                for name in names:  # interleaved, so load drifts hit every variant alike
                    model.depth_sweep = variants[name]
                    t0 = time.perf_counter()
                    model.reconstruct_pruned(r.input_images, r.input_cameras, r.near, r.far)
                    times[name].append(time.perf_counter() - t0)
        med = {name: statistics.median(t) for name, t in times.items()}
        ratios = " / ".join(f"{med[n] / med[names[0]]:.1f}×" for n in names[1:])
        cells = " | ".join(f"{med[n]:.2f}" for n in names)
        print(f"| {size} | {cells} | {ratios} |", flush=True)


if __name__ == "__main__":
    main()
