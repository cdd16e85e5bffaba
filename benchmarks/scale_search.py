"""The depth sweep's scene-wide factor (``DepthSweepOptions.scale_candidates``) on and off,
paired target by target.

For every scene and size the pipeline reconstructs twice from the same inputs
(``ProSplat.reconstruct_pruned``): with the shipped depth sweep (local ZNCC sweep, then the
scene-wide factor of :func:`prosplat.depth_sweep.scale_search`) and without the factor
(``depth_scale=False``); the two keep the same Gaussians, so the factor chosen is the ratio
of their depths. Each target is scored raw and enhanced and, with
``--refine-steps N``, after N steps of refinement from each variant's own Gaussians and
enhanced (the pipeline refines from the scaled depth, the "on" variant, since 2026-11-28;
before, from the local sweep's); the table gives both means
and the paired difference with a 95 % bootstrap interval, overall and per scene type, and
the factors the search chose.

    python benchmarks/scale_search.py --data data/val128 --sizes 64 128 --refine-steps 100 \\
        --out runs/scale_search/val
"""

from __future__ import annotations

import argparse
import json
import math
import random
import statistics as st
import time
from collections import defaultdict
from pathlib import Path

import torch

from prosplat.data import find_scenes, load_scene
from prosplat.evaluate import scene_at
from prosplat.metrics import lpips, psnr
from prosplat.pipeline import ProSplat
from prosplat.refine import refine


def paired(diffs: list[float], seed: int = 0, rounds: int = 4000) -> tuple[float, float, float]:
    """Mean of ``diffs`` and its 95 % bootstrap interval."""
    rng = random.Random(seed)
    n = len(diffs)
    means = sorted(sum(diffs[rng.randrange(n)] for _ in range(n)) / n for _ in range(rounds))
    return sum(diffs) / n, means[int(0.025 * rounds)], means[int(0.975 * rounds) - 1]


def score_targets(model, g, images, cameras, targets, target_cams, enhance: bool) -> list:
    """[(psnr, lpips)] of each target view, raw or enhanced."""
    out = []
    for gt, cam in zip(targets, target_cams):
        view = model.render(g, cam, images, cameras, enhance=enhance)
        pred = view.image.clamp(0, 1)
        out.append((float(psnr(pred, gt)), float(lpips(pred, gt))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--data", nargs="+", default=["data/val128"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[64])
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--scenes", type=int, default=0, help="first N scenes per folder (0: all)")
    ap.add_argument("--refine-steps", type=int, default=0, help="also refine N steps (0: no)")
    ap.add_argument("--weights", default=None, help="generator weights (default: shipped)")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    model = ProSplat.from_pretrained(args.weights, improve=True)
    if model.depth_sweep is None:
        raise SystemExit("these weights run without the depth sweep; nothing to compare")
    rows = ["raw", "enhanced"] + (
        [f"refine {args.refine_steps} enhanced"] * bool(args.refine_steps)
    )
    # (size, row, variant) -> [(scene type, psnr, lpips)] in target order
    scores: dict = defaultdict(list)
    factors: dict = defaultdict(list)  # size -> [(scene, factor)]
    folders = [f for root in args.data for f in find_scenes(root)[: args.scenes or None]]
    t0 = time.perf_counter()
    for folder in folders:
        scene = load_scene(folder)
        kind = folder.name.rsplit("_", 1)[0]
        for size in args.sizes:
            r = scene_at(scene, args.views, size)
            images, cams = r.input_images, r.input_cameras
            targets = scene.target_indices
            t_images = r.images[targets]
            t_cams = [r.cameras[i] for i in targets]
            depths = {}
            for name in ("off", "on"):
                pruned = model.reconstruct_pruned(
                    images, cams, r.near, r.far, depth_scale=name == "on"
                )
                g, depths[name] = pruned.gaussians, pruned.depths
                runs = [("raw", g, False), ("enhanced", g, True)]
                if args.refine_steps:
                    fitted = refine(
                        g,
                        images,
                        cams,
                        steps=args.refine_steps,
                        depths=pruned.depths_for(images),
                        view_index=pruned.view_index,
                    ).gaussians
                    runs.append((rows[-1], fitted, True))
                for row, gg, enh in runs:
                    for p, lp in score_targets(model, gg, images, cams, t_images, t_cams, enh):
                        scores[size, row, name].append((kind, p, lp))
            # the same Gaussians either way, the "on" depth scaled by the factor it chose
            has_depth = depths["off"] > 0
            factor = float((depths["on"][has_depth] / depths["off"][has_depth]).median())
            factors[size].append((folder.name, factor))
        print(f"{folder.name}: factors " + ", ".join(
            f"{s} px {f[-1][1]:.3f}" for s, f in factors.items()), flush=True)  # fmt: skip

    lines = [
        f"{len(folders)} scenes of {' '.join(args.data)}, {args.views} inputs, "
        f"{time.perf_counter() - t0:.0f} s",
        "",
        "| size | row | search off PSNR / LPIPS | on | on − off, PSNR [95 %] | LPIPS |",
        "|---|---|---:|---:|---:|---:|",
    ]
    per_type: list[str] = []
    result = {"args": {k: str(v) for k, v in vars(args).items()}, "factors": factors, "rows": []}
    for size in args.sizes:
        for row in rows:
            off, on_ = scores[size, row, "off"], scores[size, row, "on"]
            dp = [b[1] - a[1] for a, b in zip(off, on_)]
            dl = [b[2] - a[2] for a, b in zip(off, on_)]
            m, lo, hi = paired(dp)
            mean = lambda xs, i: st.mean(x[i] for x in xs)  # noqa: E731
            lines.append(
                f"| {size} | {row} | {mean(off, 1):.2f} / {mean(off, 2):.3f} | "
                f"{mean(on_, 1):.2f} / {mean(on_, 2):.3f} | {m:+.2f} [{lo:+.2f}, {hi:+.2f}] | "
                f"{st.mean(dl):+.4f} |"
            )
            by_kind = defaultdict(list)
            for a, d in zip(off, dp):
                by_kind[a[0]].append(d)
            per_type.append(
                f"| {size} | {row} | "
                + ", ".join(f"{k} {st.mean(v):+.2f}" for k, v in sorted(by_kind.items()))
                + " |"
            )
            result["rows"].append(dict(size=size, row=row, off=off, on=on_))
    fs = [f for per in factors.values() for _, f in per]
    head = ["| size | row | on − off by scene type (PSNR) |", "|---|---|---|"]
    lines += ["", *head, *per_type, ""]
    lines.append(
        f"Factors chosen: median {st.median(fs):.3f}, "
        f"{sum(f != 1.0 for f in fs)} of {len(fs)} reconstructions moved, "
        f"range {min(fs):.3f}-{max(fs):.3f}"
    )
    table = "\n".join(lines)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scale_search.md").write_text(table + "\n")
    (args.out / "scale_search.json").write_text(json.dumps(result, indent=1))
    if any(math.isnan(f) for f in fs):
        raise SystemExit("a factor came back NaN")


if __name__ == "__main__":
    main()
