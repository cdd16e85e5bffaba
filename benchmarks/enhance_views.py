"""How stage 2 is applied to a view: working size and guard, measured per target view.

For every scene, evaluation size and target: the generator's raw render, the enhancement at
each ``--working-sizes`` (0 = at the view's own size, the behaviour before working sizes), the
render's coverage (mean alpha) and each enhancement's departure on confident pixels. Prints
mean PSNR / LPIPS per size and working size, then the guard's threshold sweep (the mean PSNR
if views failing ``coverage >= c`` or ``departure <= d`` keep their raw render), and writes
``views.csv`` + ``summary.md`` into ``--out``.

    python benchmarks/enhance_views.py --data data/val128 --sizes 64 128 --out out/enhance_val

Calibrate the guard on validation scenes, report on test scenes with the chosen thresholds.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import math
import sys
from pathlib import Path

import torch

from prosplat import ProSplat
from prosplat.budget import prune_pixel_aligned
from prosplat.data import find_scenes, load_scene
from prosplat.data.scene import resize_views
from prosplat.enhance import EnhanceOptions, enhance, render_view
from prosplat.evaluate import pick_inputs
from prosplat.flicker import camera_path, flicker
from prosplat.image_io import write_image
from prosplat.improve.mori import select_reference
from prosplat.improve.pattern import fixed_pattern_score
from prosplat.metrics import LPIPS, psnr
from prosplat.render import render


def _departure(raw: torch.Tensor, out: torch.Tensor, alpha: torch.Tensor) -> float:
    sure = alpha > EnhanceOptions().confident_alpha
    return float((out - raw).abs().mean(0)[sure].mean()) if bool(sure.any()) else 0.0


def _flicker_row(model, g, inp_images, inp_cams, cams, scene, size, args) -> dict:
    """Raw and enhanced flicker along a path between the scene's first two targets."""
    t0, t1 = scene.target_indices[:2]
    path = camera_path(cams[t0], cams[t1], args.flicker_frames)
    raw, enhanced, depths = [], [], []
    for cam in path:
        v = render_view(g, cam, inp_images, inp_cams, model.improver)
        raw.append(v.raw)
        enhanced.append(v.image)
        depths.append(v.depth)
    raw_t, enh_t, d = torch.stack(raw), torch.stack(enhanced), torch.stack(depths)
    f_raw, f_enh = flicker(raw_t, d, path), flicker(enh_t, d, path)
    return {"scene": scene.folder.name, "size": size, "raw": f_raw, "enhanced": f_enh}


def measure(args: argparse.Namespace, changes: dict, flicker_rows: list) -> list[dict]:
    """Per-view rows; ``changes[(size, ws)]`` collects each enhanced - raw [3,H,W] and
    ``flicker_rows`` each scene's flicker figures."""
    torch.manual_seed(0)
    model = ProSplat.from_pretrained()
    lpips = LPIPS()
    folders = [f for root in args.data for f in find_scenes(root)[: args.scenes]]
    rows = []
    for n, folder in enumerate(folders):
        scene = load_scene(folder, load_depth=False)
        idx = pick_inputs(scene, args.views)
        near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
        for size in args.sizes:
            images, cams = resize_views(scene.images, scene.cameras, size)
            inp_images, inp_cams = images[idx], [cams[i] for i in idx]
            gen_size = min(size, args.generator_size or size)
            gen_images, gen_cams = resize_views(
                scene.images[idx], [scene.cameras[i] for i in idx], gen_size
            )
            with torch.no_grad():
                out = model.reconstruct_full(gen_images, gen_cams, near, far)
                g = prune_pixel_aligned(out.gaussians(0), out.depths[0], gen_cams)[0]
            if args.flicker_frames:
                flicker_rows.append(
                    _flicker_row(model, g, inp_images, inp_cams, cams, scene, size, args)
                )
            for t in scene.target_indices:
                cam, gt = cams[t], images[t]
                with torch.no_grad():
                    r = render(g, cam)
                    j = select_reference(cam, inp_cams, method="paper")
                    row = {
                        "scene": folder.name,
                        "family": str(scene.meta.get("name") or scene.meta.get("family", "?")),
                        "size": size,
                        "target": t,
                        "coverage": float(r.alpha.mean()),
                        "psnr_raw": float(psnr(r.rgb, gt)),
                        "lpips_raw": float(lpips(r.rgb[None], gt[None])),
                    }
                    for ws in args.working_sizes:
                        e = enhance(
                            model.improver, r.rgb, cam, inp_images[j], inp_cams[j], working_size=ws
                        )
                        row[f"psnr_ws{ws}"] = float(psnr(e, gt))
                        row[f"lpips_ws{ws}"] = float(lpips(e[None], gt[None]))
                        row[f"departure_ws{ws}"] = _departure(r.rgb, e, r.alpha)
                        changes.setdefault((size, ws), []).append(e - r.rgb)
                rows.append(row)
        print(f"[{n + 1}/{len(folders)}] {folder.name}", file=sys.stderr, flush=True)
    return rows


def _mean(values) -> float:
    values = list(values)
    return sum(values) / len(values) if values else math.nan


def summary(rows: list[dict], working_sizes: list[int]) -> str:
    lines = [
        "| size | views | raw PSNR / LPIPS | "
        + " | ".join(f"ws {ws} PSNR / LPIPS" for ws in working_sizes)
        + " |",
        "|---" * (3 + len(working_sizes)) + "|",
    ]
    for size in sorted({r["size"] for r in rows}):
        rs = [r for r in rows if r["size"] == size]
        cells = [
            f"{_mean(r['psnr_raw'] for r in rs):.2f} / {_mean(r['lpips_raw'] for r in rs):.3f}"
        ]
        for ws in working_sizes:
            p = _mean(r[f"psnr_ws{ws}"] for r in rs)
            lp = _mean(r[f"lpips_ws{ws}"] for r in rs)
            cells.append(f"{p:.2f} / {lp:.3f}")
        lines.append(f"| {size} | {len(rs)} | " + " | ".join(cells) + " |")
    ws = working_sizes[-1]
    lines += [
        "",
        f"Guard sweep (working size {ws}): mean PSNR over all sizes, views kept raw",
        "",
        "| min coverage | max departure | PSNR | raw kept |",
        "|---|---|---|---|",
    ]
    for c, d in itertools.product((0.0, 0.05, 0.1, 0.2, 0.3), (0.05, 0.1, 0.15, 0.2, 1.0)):
        opts = EnhanceOptions(min_coverage=c, max_departure=d)
        vals, kept = [], 0
        for r in rows:
            bad = r["coverage"] < opts.min_coverage or r[f"departure_ws{ws}"] > opts.max_departure
            kept += bad
            vals.append(r["psnr_raw"] if bad else r[f"psnr_ws{ws}"])
        lines.append(f"| {c} | {d} | {_mean(vals):.3f} | {kept}/{len(rows)} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, nargs="+", required=True, help="scene folders' roots")
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--working-sizes", type=int, nargs="+", default=[0, 64])
    p.add_argument(
        "--generator-size",
        type=int,
        default=None,
        help="run the generator at most this high (default: the evaluation size)",
    )
    p.add_argument(
        "--flicker-frames",
        type=int,
        default=0,
        help="also measure flicker along an N-frame path per scene (e.g. 24)",
    )
    p.add_argument("--scenes", type=int, default=None, help="at most N scenes per root")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    changes: dict = {}
    flicker_rows: list[dict] = []
    rows = measure(args, changes, flicker_rows)
    args.out.mkdir(parents=True, exist_ok=True)
    pattern = [
        "",
        "Fixed pattern (prosplat.improve.pattern; ~1 = none)",
        "",
        "| size | working size | views | ratio |",
        "|---|---|---|---|",
    ]
    for (size, ws), items in sorted(changes.items()):
        shapes = {tuple(c.shape) for c in items}
        if len(shapes) != 1:
            continue  # views of different shapes cannot be averaged pixel by pixel
        stack = torch.stack(items)
        score = fixed_pattern_score(stack)
        pattern.append(f"| {size} | {ws} | {score.views} | {score.ratio:.2f} |")
        mean = stack.mean(0)
        amplified = (0.5 + 0.5 * mean / mean.abs().max().clamp_min(1e-6)).clamp(0, 1)
        write_image(args.out / f"mean_change_{size}_ws{ws}.png", amplified, overwrite=True)
    with open(args.out / "views.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    text = summary(rows, args.working_sizes) + "\n".join(pattern)
    if flicker_rows:
        text += "\n\nFlicker along a path between two targets (prosplat.flicker)\n\n"
        text += (
            "| size | scenes | raw | enhanced | ratio (median of scenes) |\n|---|---|---|---|---|\n"
        )
        for size in sorted({r["size"] for r in flicker_rows}):
            fr = [r for r in flicker_rows if r["size"] == size and r["raw"] == r["raw"]]
            ratios = sorted(r["enhanced"] / r["raw"] for r in fr if r["raw"] > 0)
            med = ratios[len(ratios) // 2] if ratios else math.nan
            text += (
                f"| {size} | {len(fr)} | {_mean(r['raw'] for r in fr):.4f} | "
                f"{_mean(r['enhanced'] for r in fr):.4f} | {med:.2f} |\n"
            )
    (args.out / "summary.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
