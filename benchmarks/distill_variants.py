"""Distilling, and enhancing once more after it: which renders to show.

Per scene (4 inputs, the shipped models): the 8 targets enhanced one by one; the targets
distilled (:mod:`prosplat.distill`) for each ``--steps`` count, scored raw and enhanced once
more; and a ``--frames``-frame path between the first two targets, distilled from its own
enhanced frames, with the flicker ratio to the raw renders (:mod:`prosplat.flicker`) of the
enhanced frames, the distilled renders and the distilled renders enhanced again. Prints mean
PSNR / LPIPS per row and median flicker ratios.

    python benchmarks/distill_variants.py --data data/test128 --size 64 --steps 400 800
"""

from __future__ import annotations

import argparse
import statistics as st

import torch

from prosplat import ProSplat
from prosplat.data import find_scenes, load_scene
from prosplat.distill import distill, enhance_views
from prosplat.enhance import render_view
from prosplat.evaluate import scene_at
from prosplat.flicker import camera_path, flicker
from prosplat.metrics import LPIPS, psnr


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="data/test128")
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--scenes", type=int, default=None)
    p.add_argument("--steps", type=int, nargs="+", default=[400, 800])
    p.add_argument("--frames", type=int, default=24)
    args = p.parse_args()
    model, lpips = ProSplat.from_pretrained(), LPIPS()
    imp = model.improver
    scores: dict[str, tuple[list, list]] = {}
    ratios: dict[str, list] = {}

    def score(key, image, truth):
        psnrs, lp = scores.setdefault(key, ([], []))
        psnrs.append(float(psnr(image, truth)))
        lp.append(float(lpips(image[None], truth[None])))

    for folder in find_scenes(args.data)[: args.scenes]:
        scene = load_scene(folder, load_depth=False)
        at = scene_at(scene, 4, args.size)
        images, cams, inp, icams = at.images, at.cameras, at.input_images, at.input_cameras
        g = model.reconstruct_pruned(inp, icams, at.near, at.far).gaussians
        targets = list(scene.target_indices)
        tcams = [cams[t] for t in targets]
        enhanced = enhance_views(g, inp, icams, tcams, imp)  # [T,3,H,W], scored and fitted
        for t, image in zip(targets, enhanced):
            score("enhanced", image, images[t])
        for n in args.steps:
            fitted = distill(g, inp, icams, enhanced, tcams, steps=n).gaussians
            for t, cam in zip(targets, tcams):
                v = render_view(fitted, cam, inp, icams, imp)
                score(f"distill {n}", v.raw, images[t])
                score(f"distill {n} + enhanced again", v.image, images[t])
        path = camera_path(tcams[0], tcams[1], args.frames)
        plain = [render_view(g, c, inp, icams, imp) for c in path]
        depths = torch.stack([v.depth for v in plain])
        raw = flicker(torch.stack([v.raw for v in plain]), depths, path)
        ratios.setdefault("enhanced", []).append(
            flicker(torch.stack([v.image for v in plain]), depths, path) / raw
        )
        n = args.steps[0]
        frames = torch.stack([v.image for v in plain]).clamp(0, 1)
        fitted = distill(g, inp, icams, frames, path, steps=n).gaussians
        again = [render_view(fitted, c, inp, icams, imp) for c in path]
        own = torch.stack([v.depth for v in again])
        for key, frames in ((f"distill {n}", [v.raw for v in again]),
                            (f"distill {n} + enhanced again", [v.image for v in again])):  # fmt: skip
            ratios.setdefault(key, []).append(flicker(torch.stack(frames), own, path) / raw)
        print(folder.name, flush=True)
    print("| row | PSNR | LPIPS |\n|---|---:|---:|")
    for key, (psnrs, lp) in scores.items():
        print(f"| {key} | {st.mean(psnrs):.2f} | {st.mean(lp):.3f} |")
    print("\n| path frames | flicker / raw (median) |\n|---|---:|")
    for key, rs in ratios.items():
        print(f"| {key} | {st.median(rs):.2f} |")


if __name__ == "__main__":
    main()
