"""Refinement: generator vs generator + refine N steps, on target views (never the inputs).

For each scene, the generator reconstructs from ``--views`` inputs at ``--size`` px, the
automatic Gaussian budget prunes, and each variant (a set of :class:`RefineOptions`) refines
for each step count; every target view is rendered raw and enhanced (shipped stage 2, MORI
reference) and scored against Blender's image. The pasted MORI reference and the generator
alone are the first rows. Refinement is timed once per (scene, variant, steps); the seconds
column is the median over scenes of the refinement alone (generator + pruning excluded).

    python benchmarks/refine.py --data /tmp/refine_data --size 64 --steps 50,100,300

``--profile`` instead profiles refinement steps (cProfile and torch.profiler) and prints
steps per second at each of ``--sizes``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import torch

from prosplat.data import find_scenes, load_scene
from prosplat.data.scene import resize_views
from prosplat.evaluate import pick_inputs
from prosplat.metrics import lpips, psnr, ssim
from prosplat.pipeline import ProSplat
from prosplat.refine import RefineOptions, refine

#: variant name -> options; "default" is RefineOptions() as shipped
VARIANTS: dict[str, RefineOptions] = {
    "default": RefineOptions(),
    "none": RefineOptions.unregularised(),
    "depth 0.1": RefineOptions.unregularised(depth_weight=0.1),
    "depth 0.3": RefineOptions.unregularised(depth_weight=0.3),
    "opacity 0.01": RefineOptions.unregularised(opacity_weight=0.01),
    "scale 0.01": RefineOptions.unregularised(scale_weight=0.01),
    "freeze 30": RefineOptions.unregularised(freeze_means_steps=30),
    "sh 1": RefineOptions.unregularised(sh_degree=1),
    "all": RefineOptions.unregularised(
        depth_weight=0.1, opacity_weight=0.01, scale_weight=0.01, freeze_means_steps=30
    ),
    "means lr x0.3": RefineOptions.unregularised(
        lr=replace(RefineOptions().lr, means=RefineOptions().lr.means * 0.3)
    ),
    "means lr x3": RefineOptions.unregularised(
        lr=replace(RefineOptions().lr, means=RefineOptions().lr.means * 3)
    ),
    "means lr x10": RefineOptions.unregularised(
        lr=replace(RefineOptions().lr, means=RefineOptions().lr.means * 10)
    ),
    "colour lr x3": RefineOptions.unregularised(
        lr=replace(RefineOptions().lr, sh=RefineOptions().lr.sh * 3)
    ),
    "ray 0.003": RefineOptions.unregularised(ray_scale_lr=0.003),
    "ray 0.01": RefineOptions.unregularised(ray_scale_lr=0.01),
    "ray 0.03": RefineOptions.unregularised(ray_scale_lr=0.03),
    "means fixed": RefineOptions.unregularised(freeze_means_steps=10**9),
    "opacity 0.1": RefineOptions.unregularised(opacity_weight=0.1),
    "drop 0.1": RefineOptions.unregularised(drop_rate=0.1),
    "drop 0.2": RefineOptions.unregularised(drop_rate=0.2),
    "drop 0.3": RefineOptions.unregularised(drop_rate=0.3),
    "cross 0.3": RefineOptions.unregularised(cross_view_weight=0.3),
    "cross 1": RefineOptions.unregularised(cross_view_weight=1.0),
    "cross 3": RefineOptions.unregularised(cross_view_weight=3.0),
    "cross 1, means lr x10": RefineOptions.unregularised(
        cross_view_weight=1.0, lr=replace(RefineOptions().lr, means=RefineOptions().lr.means * 10)
    ),
}


def scene_inputs(scene, views: int, size: int):
    idx = pick_inputs(scene, views)
    near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
    imgs, cams = resize_views(scene.images[idx], [scene.cameras[i] for i in idx], size)
    t_idx = scene.target_indices
    timgs, tcams = resize_views(scene.images[t_idx], [scene.cameras[i] for i in t_idx], size)
    return imgs, cams, near, far, timgs, tcams


def score(model, g, imgs, cams, timgs, tcams, enhance: bool, paste: bool = False) -> dict:
    out = defaultdict(list)
    for gt, cam in zip(timgs, tcams):
        view = model.render(g, cam, imgs, cams, enhance=enhance or paste)
        pred = imgs[view.reference] if paste else view.image
        pred = pred.clamp(0, 1)
        with torch.no_grad():
            out["psnr"].append(float(psnr(pred, gt)))
            out["ssim"].append(float(ssim(pred, gt)))
            out["lpips"].append(float(lpips(pred, gt)))
    return {k: sum(v) / len(v) for k, v in out.items()}


def sweep(args) -> None:
    model = ProSplat.from_pretrained(args.weights, improve=True)
    steps = [int(s) for s in args.steps.split(",") if s.strip()]
    names = [v.strip() for v in args.variants.split(",")] if args.variants else list(VARIANTS)
    ablations = [v.strip() for v in args.ablations.split(",") if v.strip()]
    ablation_steps = [int(s) for s in args.ablation_steps.split(",") if s.strip()]
    seconds = [float(s) for s in args.seconds.split(",") if s.strip()]
    rows = defaultdict(lambda: defaultdict(list))  # (label, enhance) -> metric -> per scene
    folders = [f for root in args.data for f in find_scenes(root)[: args.scenes]]
    for folder in folders:
        sc = load_scene(folder)
        imgs, cams, near, far, timgs, tcams = scene_inputs(sc, args.views, args.size)
        # 0: the generator at --size (this benchmark's default); N: at most N px high
        # the one-pass rows as the pipeline runs them (with the depth sweep's scene-wide
        # factor); refinement starts from them, as ProSplat.reconstruct_refined does
        height = args.generator_size or 0
        one_pass = model.reconstruct_pruned(imgs, cams, near, far, generator_height=height)
        pruned = (  # --local-start: refine from the local sweep's depth, factor left out
            one_pass
            if not args.local_start
            else model.reconstruct_pruned(
                imgs, cams, near, far, generator_height=height, depth_scale=False
            )
        )
        g, depths, view_index = pruned.gaussians, pruned.depths_for(imgs), pruned.view_index
        for key, kw in (("pasted reference", dict(enhance=False, paste=True)),):
            for m, v in score(model, g, imgs, cams, timgs, tcams, **kw).items():
                rows[key, False][m].append(v)
        for enh in (False, True):
            for m, v in score(model, one_pass.gaussians, imgs, cams, timgs, tcams, enh).items():
                rows["generator", enh][m].append(v)
        plan = [(name, n, None) for name in names for n in steps]
        plan += [(name, n, None) for name in ablations for n in ablation_steps]
        plan += [(name, None, sec) for name in names for sec in seconds]
        for name, n, sec in plan:
            r = refine(
                g,
                imgs,
                cams,
                steps=n,
                seconds=sec,
                depths=depths,
                view_index=view_index,
                options=VARIANTS[name],
            )
            label = f"refine {n}, {name}" if sec is None else f"refine {sec:g} s, {name}"
            rows[label, False]["steps"].append(r.stats.steps)
            for enh in (False, True):
                rows[label, enh]["seconds"].append(r.stats.seconds)
                for m, v in score(model, r.gaussians, imgs, cams, timgs, tcams, enh).items():
                    rows[label, enh][m].append(v)
        print(f"{folder.name} done", flush=True)
    lines = [
        f"| {args.size} px, {args.views} inputs | enhance | PSNR ↑ | SSIM ↑ | LPIPS ↓ | refine s "
        "| steps |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    summary = []
    for (label, enh), m in rows.items():
        mean = {k: sum(v) / len(v) for k, v in m.items() if k not in ("seconds", "steps")}
        secs = statistics.median(m["seconds"]) if m.get("seconds") else float("nan")
        per_scene = {k: v for k, v in m.items()}
        n_steps = (
            statistics.median(rows[label, False]["steps"]) if "steps" in rows[label, False] else ""
        )
        summary.append(
            dict(label=label, enhance=enh, seconds=secs, n=len(m["psnr"]), per_scene=per_scene)
            | mean
        )
        lines.append(
            f"| {label} | {'on' if enh else 'off'} | {mean['psnr']:.2f} | {mean['ssim']:.3f} | "
            f"{mean['lpips']:.3f} | {secs:.1f} | {n_steps} |"
        )
    table = "\n".join(lines)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = f"refine_{args.size}px"
    (args.out / f"{stem}.md").write_text(table + "\n")
    meta = dict(args={k: str(v) for k, v in vars(args).items()}, scenes=[f.name for f in folders])
    (args.out / f"{stem}.json").write_text(json.dumps(dict(meta=meta, rows=summary), indent=1))


def profile(args) -> None:
    import cProfile
    import pstats

    model = ProSplat.from_pretrained(args.weights, improve=False)
    sc = load_scene(find_scenes(args.data[0])[0])
    for size in [int(s) for s in args.sizes.split(",")]:
        imgs, cams, near, far, _, _ = scene_inputs(sc, args.views, size)
        pruned = model.reconstruct_pruned(imgs, cams, near, far, generator_height=0)
        g, depths = pruned.gaussians, pruned.depths
        refine(g, imgs, cams, steps=5, depths=depths)  # warm-up
        r = refine(g, imgs, cams, steps=args.profile_steps, depths=depths)
        print(
            f"{size} px: {len(g)} Gaussians, {r.stats.steps_per_s:.1f} steps/s "
            f"({1e3 / r.stats.steps_per_s:.1f} ms/step, {torch.get_num_threads()} threads)"
        )
        if size in (64, 128) and not args.timing_only:
            prof = cProfile.Profile()
            prof.enable()
            refine(g, imgs, cams, steps=args.profile_steps, depths=depths)
            prof.disable()
            pstats.Stats(prof).sort_stats("tottime").print_stats(12)
            from torch.profiler import ProfilerActivity
            from torch.profiler import profile as tprofile

            with tprofile(activities=[ProfilerActivity.CPU]) as tp:
                refine(g, imgs, cams, steps=args.profile_steps, depths=depths)
            print(tp.key_averages().table(sort_by="self_cpu_time_total", row_limit=15))


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--data", type=Path, nargs="+", required=True)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--scenes", type=int, default=None, help="at most N scenes per folder")
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument(
        "--generator-size",
        type=int,
        default=None,
        help="run the generator at most this high (default: at --size) and refine/render at --size",
    )
    ap.add_argument("--steps", default="50,100,300")
    ap.add_argument("--seconds", default="", help="time budgets (s) run for each variant")
    ap.add_argument("--variants", default=None, help=f"comma-separated of {list(VARIANTS)}")
    ap.add_argument(
        "--local-start",
        action="store_true",
        help="refine from the local sweep's depth (the depth sweep's scene-wide factor left "
        "out, as the pipeline refined until 2026-11-28) instead of from the one-pass Gaussians",
    )
    ap.add_argument("--ablations", default="", help="variants run only at --ablation-steps")
    ap.add_argument("--ablation-steps", default="100")
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--sizes", default="64,128,256", help="--profile: sizes")
    ap.add_argument("--profile-steps", type=int, default=30)
    ap.add_argument("--timing-only", action="store_true", help="--profile: steps/s only")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    profile(args) if args.profile else sweep(args)
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
