"""A figure of what stage 2 models do to the same renders: to look at, not only to average.

Rows: one target view of each of ``--scenes`` test scenes (the generator at its trained size,
``--views`` inputs, the first target). Columns: Blender's image, the raw render, the MORI
reference warped through the rendered depth over the render (``warp paste``), and the render
enhanced by each ``--improve LABEL=PATH`` (and, with ``--distill-steps N``, the views each
model's enhanced targets distill into: :mod:`prosplat.pipeline.distill`). Each panel is titled with
its PSNR.

    python benchmarks/stage2_views.py --data data/test128 --size 128 \\
        --improve v5=prosplat/weights/improve_tiny.safetensors --out docs/stage2_views.png
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
from prosplat.data.rigs import pick_inputs  # noqa: E402
from prosplat.data.scene import resize_views  # noqa: E402
from prosplat.eval.ladder import SceneInputs  # noqa: E402
from prosplat.eval.ladder.rungs import warp_paste_view  # noqa: E402
from prosplat.improve.io import load_improver  # noqa: E402
from prosplat.metrics import psnr  # noqa: E402
from prosplat.pipeline.distill import distill_enhanced  # noqa: E402
from prosplat.pipeline.enhance import render_view  # noqa: E402
from prosplat.pipeline.model import ProSplat  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--scenes", type=int, default=6, help="spread evenly over the folder")
    ap.add_argument("--generator", default=None)
    ap.add_argument("--improve", action="append", default=[], metavar="LABEL=PATH")
    ap.add_argument("--distill-steps", type=int, default=0,
                    help="also each model's views distilled (prosplat.pipeline.distill, all the scene's "
                    "targets together) for N steps: a 'LABEL distilled' column")  # fmt: skip
    ap.add_argument("--out", type=Path, default=Path("out/stage2_views.png"))
    args = ap.parse_args()
    model = ProSplat.from_pretrained(args.generator, improve=False)
    improvers = {}
    for spec in args.improve:
        label, _, path = spec.partition("=")
        improvers[label] = load_improver(path)
    folders = spread_scenes(args.data, args.scenes)
    distilled = [f"{label} distilled" for label in improvers] if args.distill_steps else []
    cols = ["Blender", "raw", "warp paste", *improvers, *distilled]
    fig, axes = plt.subplots(len(folders), len(cols), figsize=(2 * len(cols), 2.1 * len(folders)))
    for r, folder in enumerate(folders):
        scene = load_scene(folder)
        idx = pick_inputs(scene, args.views)
        near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
        imgs, cams = resize_views(scene.images[idx], [scene.cameras[i] for i in idx], args.size)
        t = scene.target_indices[0]
        gt_all, tcam = resize_views(scene.images[[t]], [scene.cameras[t]], args.size)
        gt, cam = gt_all[0], tcam[0]
        g = model.reconstruct(imgs, cams, near, far).gaussians
        inp = SceneInputs(imgs, cams, None, near, far)
        panels = {"Blender": gt, "raw": render_view(g, cam).image}
        panels["warp paste"] = warp_paste_view(g, cam, inp).image
        for label, imp in improvers.items():
            panels[label] = render_view(g, cam, imgs, cams, imp).image
            if args.distill_steps:  # every target of the scene, as a set of views is rendered
                _, tcams = resize_views(scene.images[scene.target_indices],
                                        [scene.cameras[k] for k in scene.target_indices], args.size)  # fmt: skip
                with torch.enable_grad():
                    fitted = distill_enhanced(g, imgs, cams, tcams, imp, steps=args.distill_steps)
                panels[f"{label} distilled"] = render_view(fitted.gaussians, cam).image
        for c, name in enumerate(cols):
            img = panels[name].clamp(0, 1)
            title = name if name == "Blender" else f"{name} {float(psnr(img, gt)):.1f}"
            draw_panel(axes[r, c], img, title, folder.name if c == 0 else None)
        print(f"{folder.name} done", flush=True)
    save_figure(fig, args.out)


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
