"""The generator's two sweeps as they were at a commit against now: one bare reconstruction
(no depth sweep, no pruning) of test scenes, timed both ways interleaved in one process so
both see the same machine load, with the paired ratio and how far the Gaussians moved.

The sweeps are the learned cost volume (``prosplat.generator.cost_volume``) and the images'
own ZNCC volume (``prosplat.generator.image_cost``, with the box filters of
``prosplat.baselines.plane_sweep``). The older code is read from git (``git show
COMMIT:path``) into modules of its own and swapped into ``prosplat.generator.model`` for its
turns, so the rest of the network is the same code both ways.

Part 1 times the two ways to correlate one neighbour (``warped_correlation``,
``sampled_correlation``) at the generator's feature shapes, which is where
``ALL_PAIRS_MAX_PIXELS`` comes from.

    OMP_NUM_THREADS=1 python benchmarks/sweep_speed.py --before f3f56fe \\
        --generator runs/generator_v14a.safetensors --scenes 6
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

import prosplat.generator.cost_volume as cost_volume
import prosplat.generator.model as generator_model

ROOT = Path(__file__).resolve().parents[1]
#: (C, h, w) of the feature maps the generator correlates, 4 views and 32 candidates: at
#: 64 px inputs 48 channels at 16x16 and 16 at 32x32; at 128 px 48 at 32x32 and 16 at 64x64
SHAPES = ((48, 16, 16), (16, 32, 32), (48, 32, 32), (16, 64, 64))


def _module_at(commit: str, path: str, name: str, folder: Path):
    """The file ``path`` as it was at ``commit``, imported as module ``name``."""
    text = subprocess.run(
        ["git", "show", f"{commit}:{path}"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    file = folder / f"{name}.py"
    file.write_text(text)
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def sweeps_at(commit: str, folder: Path) -> tuple:
    """(plane_sweep_cost_volume, image_cost_volume) as at ``commit``, wired to each other's
    code of that commit (the image volume's warp grid and box filters included)."""
    cv = _module_at(commit, "prosplat/generator/cost_volume.py", "old_cost_volume", folder)
    ps = _module_at(commit, "prosplat/baselines/plane_sweep.py", "old_plane_sweep", folder)
    ic = _module_at(commit, "prosplat/generator/image_cost.py", "old_image_cost", folder)
    ic.warp_grid, ic.patch_mean_var, ic.window_zncc = (
        cv.warp_grid,
        ps.patch_mean_var,
        ps.window_zncc,
    )
    return cv.plane_sweep_cost_volume, ic.image_cost_volume


def time_correlations(repeats: int) -> None:
    g = torch.Generator().manual_seed(0)
    print("| C, h, w | warped, then dotted ms | all pairs, then sampled ms | ratio |")
    print("|---|---:|---:|---:|")
    for c, h, w in SHAPES:
        feats = torch.randn(1, 4, c, h, w, generator=g)
        src = torch.randn(1, 4, c, h, w, generator=g)
        grid = torch.rand(1, 4, 32, h, w, 2, generator=g) * 2.4 - 1.2
        times: dict[str, list[float]] = {"warped": [], "sampled": []}
        with torch.no_grad():
            for _ in range(repeats):
                for name in times:
                    fn = getattr(cost_volume, f"{name}_correlation")
                    t0 = time.perf_counter()
                    fn(feats, src, grid)
                    times[name].append(time.perf_counter() - t0)
        a, b = (statistics.median(times[k]) * 1e3 for k in ("warped", "sampled"))
        print(f"| {c}, {h}, {w} | {a:.1f} | {b:.1f} | {a / b:.2f}x |")


def time_generator(args: argparse.Namespace, before: tuple) -> None:
    from prosplat.data import load_scene
    from prosplat.data.scene import resize_views
    from prosplat.evaluate import pick_inputs
    from prosplat.pipeline import ProSplat

    model = ProSplat.from_pretrained(path=args.generator, improve=False)
    model.depth_sweep = (
        None  # the bare generator, as the ladder's generator row with --no-depth-sweep
    )
    now = (generator_model.plane_sweep_cost_volume, generator_model.image_cost_volume)
    ways = {"before": before, "now": now}
    scenes = sorted(p for p in Path(args.data).iterdir() if (p / "transforms.json").is_file())
    print(f"\n{args.generator}, {min(args.scenes, len(scenes))} scenes of {args.data}, 4 inputs")
    print("| inputs px | before ms | now ms | paired ratio (median) | max Gaussian shift |")
    print("|---:|---:|---:|---:|---:|")
    try:
        for size in args.sizes:
            times: dict[str, list[float]] = {"before": [], "now": []}
            shift = 0.0
            for folder in scenes[: args.scenes]:
                scene = load_scene(folder, load_depth=False)
                images, cameras = resize_views(scene.images, scene.cameras, size)
                idx = pick_inputs(scene, 4)
                inputs = (images[idx], [cameras[i] for i in idx])
                near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
                means = {}
                with torch.no_grad():
                    for rep in range(args.repeats + 1):  # the first round warms up
                        for name, (psv, icv) in ways.items():
                            generator_model.plane_sweep_cost_volume = psv
                            generator_model.image_cost_volume = icv
                            t0 = time.perf_counter()
                            g = model.reconstruct(*inputs, near, far)
                            if rep:
                                times[name].append(time.perf_counter() - t0)
                            means[name] = g.means
                shift = max(shift, float((means["before"] - means["now"]).abs().max()))
            ratio = statistics.median(a / b for a, b in zip(times["before"], times["now"]))
            b, n = (statistics.median(times[k]) * 1e3 for k in ("before", "now"))
            print(f"| {size} | {b:.0f} | {n:.0f} | {ratio:.2f}x | {shift:.1e} |")
    finally:
        generator_model.plane_sweep_cost_volume, generator_model.image_cost_volume = now


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default="f3f56fe", help="the commit to compare against")
    ap.add_argument("--generator", default=None, help="generator weights (default: shipped)")
    ap.add_argument("--data", default="data/test128")
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--repeats", type=int, default=3, help="timed rounds per scene and way")
    args = ap.parse_args()
    print(f"torch threads {torch.get_num_threads()}")
    time_correlations(max(args.repeats, 5))
    with tempfile.TemporaryDirectory() as tmp:
        time_generator(args, sweeps_at(args.before, Path(tmp)))


if __name__ == "__main__":
    sys.exit(main())
