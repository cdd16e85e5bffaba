"""The generator's two sweeps as they were at a commit against now: one bare reconstruction
(no depth sweep, no pruning) of test scenes, timed both ways interleaved in one process so
both see the same machine load, with the paired ratio and how far the Gaussians moved.

The sweeps are the learned cost volume (``prosplat.generator.cost_volume``) and the images'
own ZNCC volume (``prosplat.generator.image_cost``, with the box filters of
``prosplat.geometry.matching``). The older code is read from git (``git show
COMMIT:path``) into modules of its own and swapped into ``prosplat.generator.model`` for its
turns, so the rest of the network is the same code both ways.

Part 1 times the two ways to correlate one neighbour (``warped_correlation``,
``sampled_correlation``) at the generator's feature shapes, which is where
``ALL_PAIRS_MAX_PIXELS`` comes from. Part 2 times the pieces that changed (box filter, warp
grid, inference correlation) before and now; ``--parts-only`` stops there.

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


#: Modules that moved in the redesign (issue 67): older code is read with its imports of
#: them rewritten, so it runs against today's package.
MOVED = {
    "prosplat.camera": "prosplat.core.camera",
    "prosplat.gaussians": "prosplat.core.gaussians",
    "prosplat.rotations": "prosplat.core.rotations",
    "prosplat.baselines.plane_sweep": "prosplat.geometry.matching",
}


def _module_at(commit: str, paths: tuple[str, ...], name: str, folder: Path):
    """The first of ``paths`` that exists at ``commit`` (a file's places before and after
    the moves), as it was then, imported as module ``name``."""
    for path in paths:
        found = subprocess.run(
            ["git", "show", f"{commit}:{path}"], cwd=ROOT, capture_output=True, text=True
        )
        if found.returncode == 0:
            break
    else:
        raise FileNotFoundError(f"none of {paths} exists at {commit}")
    text = found.stdout
    for before, now in MOVED.items():
        text = text.replace(f"from {before} import", f"from {now} import")
    file = folder / f"{name}.py"
    file.write_text(text)
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def modules_at(commit: str, folder: Path) -> tuple:
    """(cost_volume, plane_sweep, image_cost) as at ``commit``, the image volume wired to
    the warp grid and box filters of that commit."""
    cv = _module_at(commit, ("prosplat/generator/cost_volume.py",), "old_cost_volume", folder)
    matching = ("prosplat/geometry/matching.py", "prosplat/baselines/plane_sweep.py")
    ps = _module_at(commit, matching, "old_plane_sweep", folder)
    ic = _module_at(commit, ("prosplat/generator/image_cost.py",), "old_image_cost", folder)
    ic.warp_grid, ic.patch_mean_var, ic.window_zncc = (
        cv.warp_grid,
        ps.patch_mean_var,
        ps.window_zncc,
    )
    return cv, ps, ic


def sweeps_at(commit: str, folder: Path) -> tuple:
    """(plane_sweep_cost_volume, image_cost_volume) as at ``commit`` (:func:`modules_at`)."""
    cv, _, ic = modules_at(commit, folder)
    return cv.plane_sweep_cost_volume, ic.image_cost_volume


def _interleaved_ms(fn, modules: tuple, repeats: int) -> list[float]:
    """Median milliseconds of ``fn(module)`` for each module, the modules taking turns in
    every round so that all see the same machine load."""
    for module in modules:  # warm up
        fn(module)
    times: list[list[float]] = [[] for _ in modules]
    for _ in range(repeats):
        for k, module in enumerate(modules):
            t0 = time.perf_counter()
            fn(module)
            times[k].append(time.perf_counter() - t0)
    return [statistics.median(t) * 1e3 for t in times]


def time_parts(before: tuple, repeats: int, size: int = 64) -> None:
    """The three pieces that changed, before and now, at the image sweep's shapes for 128-px
    inputs (4 views, 32 candidates, ``size`` x ``size``): the ZNCC box filter (5 statistics,
    window 5), one neighbour's warp grid, and the learned volume's correlation of 16
    channels without gradients."""
    from prosplat.geometry import matching as plane_sweep

    old_cv, old_ps, _ = before
    g = torch.Generator().manual_seed(1)
    stats = torch.rand(4, 5, 32, size, size, generator=g)
    K = torch.tensor([[size, 0.0, size / 2], [0.0, size, size / 2], [0.0, 0.0, 1.0]])
    K = K.expand(1, 4, 3, 3).clone()
    w2c = torch.eye(4).expand(1, 4, 4, 4).clone()
    w2c[0, :, 0, 3] = torch.tensor([0.0, 0.3, 0.6, 0.9])
    nbr = cost_volume.nearest_views(w2c, 1)[..., 0]
    planes = cost_volume.inverse_depth_candidates(torch.tensor([1.0]), torch.tensor([20.0]), 32)
    feats = torch.randn(1, 4, 16, size, size, generator=g)
    warped = torch.randn(1, 4, 16, 32, size, size, generator=g)
    parts = {
        "box filter": (lambda m: m.box_mean(stats, 5), old_ps, plane_sweep),
        "warp grid": (lambda m: m.warp_grid(K, w2c, nbr, planes, size, size), old_cv, cost_volume),
        "correlation": (lambda m: m.correlate(feats, warped), old_cv, cost_volume),
    }
    print(f"\n| part ({size}x{size}, 32 planes) | before ms | now ms | ratio |")
    print("|---|---:|---:|---:|")
    with torch.no_grad():
        for name, (fn, then, now) in parts.items():
            a, b = _interleaved_ms(fn, (then, now), repeats)
            print(f"| {name} | {a:.1f} | {b:.1f} | {a / b:.2f}x |")


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
    from prosplat.data.rigs import pick_inputs
    from prosplat.data.scene import resize_views
    from prosplat.pipeline.model import ProSplat

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
                            g = model.reconstruct(*inputs, near, far, budget="all").gaussians
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
    ap.add_argument("--parts-only", action="store_true", help="skip the whole generator")
    args = ap.parse_args()
    print(f"torch threads {torch.get_num_threads()}")
    time_correlations(max(args.repeats, 5))
    with tempfile.TemporaryDirectory() as tmp:
        before = modules_at(args.before, Path(tmp))
        time_parts(before, max(args.repeats, 7))
        if not args.parts_only:
            time_generator(args, (before[0].plane_sweep_cost_volume, before[2].image_cost_volume))


if __name__ == "__main__":
    sys.exit(main())
