"""Which depth-sweep settings (``prosplat.depth_sweep.DepthSweepOptions``) help novel views:
the generator with each variant, its targets rendered raw (black holes), filled (pull-push)
and enhanced (shipped stage 2), against the generator alone on the same scenes. Chosen on
the validation scenes, never the test split.

    python benchmarks/depth_sweep_variants.py --data data/val128 --size 64 \\
        --variants "smooth .03 c0.2" "smooth .03 c0.4" "per pixel"
"""

from __future__ import annotations

import argparse
import statistics as st
import time
from collections import defaultdict

import torch

from prosplat import ProSplat
from prosplat.data import find_scenes, load_scene
from prosplat.data.scene import resize_views
from prosplat.depth_sweep import DepthSweepOptions
from prosplat.evaluate import pick_inputs
from prosplat.metrics import lpips, psnr

#: the variants tried on data/val128 (BENCHMARKS "Depth sweep"); "default" is as shipped
VARIANTS: dict[str, DepthSweepOptions] = {
    "default": DepthSweepOptions(),
    "per pixel": DepthSweepOptions(smooth=0.0, min_confidence=0.0),
    "per pixel c0.2": DepthSweepOptions(smooth=0.0, min_confidence=0.2),
    "smooth .03": DepthSweepOptions(smooth=0.03, min_confidence=0.0),
    "smooth .08": DepthSweepOptions(smooth=0.08, min_confidence=0.0),
    "smooth .015 c0.2": DepthSweepOptions(smooth=0.015, min_confidence=0.2),
    "smooth .03 c0.2": DepthSweepOptions(smooth=0.03, min_confidence=0.2),
    "smooth .03 c0.4": DepthSweepOptions(smooth=0.03, min_confidence=0.4),
    "smooth .03 c0.2 span .2": DepthSweepOptions(
        smooth=0.03, min_confidence=0.2, span=0.2, candidates=17
    ),
    "smooth .03 c0.4 span .2": DepthSweepOptions(
        smooth=0.03, min_confidence=0.4, span=0.2, candidates=17
    ),
    "smooth .03 c0.2 span .5": DepthSweepOptions(
        smooth=0.03, min_confidence=0.2, span=0.5, candidates=41
    ),
    # the scene-wide factor search (scale_search), the sweep's dearest part; counts spelled
    # out, so a variant keeps its meaning when the default moves (9 until 2026-11-27, then 5)
    "no scale": DepthSweepOptions(scale_candidates=0),
    "scale 9": DepthSweepOptions(scale_candidates=9),
    "scale 9 at 32 px": DepthSweepOptions(scale_candidates=9, scale_height=32),
    "scale 5": DepthSweepOptions(scale_candidates=5),
    "scale 5 at 32 px": DepthSweepOptions(scale_candidates=5, scale_height=32),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/val128")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--variants", nargs="+", default=["default"], help=f"of {list(VARIANTS)}")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    if unknown := [v for v in args.variants if v not in VARIANTS]:
        raise SystemExit(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.set_grad_enabled(False)
    model = ProSplat.from_pretrained(improve=True, depth_sweep=False)
    variants = {"generator": None, **{v: VARIANTS[v] for v in args.variants}}
    rows = defaultdict(lambda: defaultdict(list))  # (variant, mode) -> metric -> per scene
    for folder in find_scenes(args.data):
        sc = load_scene(folder)
        idx, t_idx = pick_inputs(sc, args.views), sc.target_indices
        imgs, cams = resize_views(sc.images[idx], [sc.cameras[i] for i in idx], args.size)
        timgs, tcams = resize_views(sc.images[t_idx], [sc.cameras[i] for i in t_idx], args.size)
        near, far = float(sc.near[idx].min()), float(sc.far[idx].max())
        for name, options in variants.items():
            model.depth_sweep = options
            t0 = time.perf_counter()
            g = model.reconstruct_pruned(imgs, cams, near, far).gaussians
            rows[name, "raw"]["s"].append(time.perf_counter() - t0)
            for mode in ("raw", "filled", "enhanced"):
                ps, lp = [], []
                for gt, cam in zip(timgs, tcams):
                    view = model.render(g, cam, imgs, cams, enhance=mode == "enhanced",
                                        fill_holes=mode == "filled")  # fmt: skip
                    pred = view.image.clamp(0, 1)
                    ps.append(float(psnr(pred, gt)))
                    lp.append(float(lpips(pred, gt)))
                rows[name, mode]["psnr"].append(st.mean(ps))
                rows[name, mode]["lpips"].append(st.mean(lp))
        print(f"{folder.name} done", flush=True)
    print(f"\n| {args.data}, {args.size} px, {args.views} inputs | PSNR | LPIPS | recon s "
          "| Δ PSNR vs generator |")  # fmt: skip
    print("|---|---:|---:|---:|---:|")
    for (name, mode), r in rows.items():
        base = rows["generator", mode]["psnr"]
        delta = st.mean(a - b for a, b in zip(r["psnr"], base))
        secs = st.median(rows[name, "raw"]["s"])
        print(f"| {name}, {mode} | {st.mean(r['psnr']):.2f} | {st.mean(r['lpips']):.3f} | "
              f"{secs:.2f} | {delta:+.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
