"""A figure of what generators make of the same inputs: to look at, not only to average.

Rows: ``--scenes`` test scenes spread over the folder (``--views`` inputs picked as every
evaluation picks them, the scene's first target). Columns: Blender's target image and its
depth at the first input camera, then for each ``--generator LABEL=PATH`` the raw render of
the target as the pipeline makes it (the generator matching at its trained size, its Gaussians
at and seen at ``--size``; black where no Gaussian lands) and the depth it predicts for that first input.
Renders are titled with their PSNR, depth maps with their mean AbsRel; depth shares one
colour scale per row (inverse depth, near = bright).

    python benchmarks/generator_views.py --data data/test128 --size 128 \\
        --generator v4=runs/generator_v4.safetensors --generator v5=runs/generator_v5.safetensors \\
        --out docs/generator_views.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402
from view_grid import draw_panel, save_figure, spread_scenes  # noqa: E402

from prosplat.data import load_scene  # noqa: E402
from prosplat.eval.generator import scene_at  # noqa: E402
from prosplat.eval.ladder.geometry import resize_depths  # noqa: E402
from prosplat.metrics import psnr  # noqa: E402
from prosplat.pipeline.enhance import render_view  # noqa: E402
from prosplat.pipeline.model import ProSplat  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--scenes", type=int, default=6, help="spread evenly over the folder")
    ap.add_argument("--generator", action="append", default=[], metavar="LABEL=PATH",
                    help="repeatable (default: the shipped one as 'shipped')")  # fmt: skip
    ap.add_argument("--low-res-gaussians", action="store_true",
                    help="also each generator with its Gaussians at the size it matches at "
                    "(columns 'LABEL low'; ProSplat.full_res_gaussians off)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=Path("out/generator_views.png"))
    args = ap.parse_args()
    models = {}
    for spec in args.generator or ["shipped="]:
        label, _, path = spec.partition("=")
        models[label] = ProSplat.from_pretrained(path or None, improve=False)
        if args.low_res_gaussians:
            models[f"{label} low"] = ProSplat.from_pretrained(path or None, improve=False)
            models[f"{label} low"].full_res_gaussians = False
    folders = spread_scenes(args.data, args.scenes)
    cols = ["Blender", "Blender depth"] + [
        f"{lab} {kind}" for lab in models for kind in ("raw", "depth")
    ]
    fig, axes = plt.subplots(len(folders), len(cols), figsize=(2 * len(cols), 2.1 * len(folders)),
                             squeeze=False)  # fmt: skip
    for r, folder in enumerate(folders):
        scene = load_scene(folder)
        rs = scene_at(scene, args.views, args.size)
        t = scene.target_indices[0]
        gt = rs.images[t]
        first = rs.inputs[0]
        true_depth = resize_depths(
            scene.depths[[first]], rs.cameras[0].width, rs.cameras[0].height
        )[0]
        valid = true_depth > 0
        inv = torch.where(valid, 1 / true_depth.clamp_min(1e-6), torch.zeros_like(true_depth))
        vmax = float(inv[valid].quantile(0.98)) if valid.any() else 1.0
        panels = {"Blender": (gt, "Blender"), "Blender depth": (inv, "Blender depth")}
        for label, model in models.items():
            rec = model.reconstruct(rs.input_images, rs.input_cameras, rs.near, rs.far)
            raw = render_view(rec.gaussians, rs.cameras[t]).image.clamp(0, 1)
            panels[f"{label} raw"] = (raw, f"{label} raw {float(psnr(raw, gt)):.1f}")
            d = resize_depths(rec.depths[:1], true_depth.shape[-1], true_depth.shape[-2])[0]
            rel = float(((d - true_depth).abs() / true_depth)[valid].mean())
            panels[f"{label} depth"] = (1 / d.clamp_min(1e-6), f"{label} depth {rel:.2f}")
        for c, name in enumerate(cols):
            img, title = panels[name]
            draw_panel(axes[r, c], img, title, folder.name if c == 0 else None,
                       cmap="magma", vmin=0, vmax=vmax)  # fmt: skip
        print(f"{folder.name} done", flush=True)
    save_figure(fig, args.out)


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
