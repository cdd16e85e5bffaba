"""Seconds to reconstruct with and without the depth sweep (``ProSplat.depth_sweep``), side by
side on the same scenes: the generator (+ sweep) + Gaussian budget, as ``reconstruct_pruned``
runs it, medians over ``--repeats`` runs of each scene, at each of ``--sizes``.

    python benchmarks/depth_sweep_speed.py --data data/test256 --sizes 64 128 256 --scenes 3
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
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.set_grad_enabled(False)
    model = ProSplat.from_pretrained(improve=False, depth_sweep=False)
    scenes = [load_scene(f) for f in find_scenes(args.data)[: args.scenes]]
    print(f"| px | without sweep s | with sweep s | ratio | ({torch.get_num_threads()} threads)")
    print("|---:|---:|---:|---:|")
    for size in args.sizes:
        times = {False: [], True: []}
        for scene in scenes:
            r = scene_at(scene, args.views, size)
            for _ in range(args.repeats):
                for on in (False, True):  # interleaved, so load drifts hit both alike
                    model.depth_sweep = DepthSweepOptions() if on else None
                    t0 = time.perf_counter()
                    model.reconstruct_pruned(r.input_images, r.input_cameras, r.near, r.far)
                    times[on].append(time.perf_counter() - t0)
        off, on = statistics.median(times[False]), statistics.median(times[True])
        print(f"| {size} | {off:.2f} | {on:.2f} | {on / off:.1f}× |", flush=True)


if __name__ == "__main__":
    main()
