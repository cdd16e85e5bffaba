"""A contact sheet of the hole fill: per scene, one target's raw render (holes black), the
same filled (:mod:`prosplat.render.hole_fill`), enhanced by stage 2, enhanced and blended with
the fill (``render_view(..., fill_holes=True)``), and the ground truth, left to right.

    python benchmarks/fill_views.py --data data/test128 --size 128 \\
        --scenes room_987003 tabletop_987001 textureless thin_structures room_987009 \\
        --out docs/fill_views.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from prosplat import ProSplat
from prosplat.data import find_scenes, load_scene
from prosplat.enhance import render_view
from prosplat.evaluate import scene_at
from prosplat.image_io import write_image
from prosplat.render.hole_fill import fill_holes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/test128")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--target", type=int, default=1, help="which of each scene's targets")
    ap.add_argument("--scenes", nargs="+", required=True, help="parts of scene folder names")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    model = ProSplat.from_pretrained()
    folders = [f for f in find_scenes(args.data) if any(k in f.name for k in args.scenes)]
    if not folders:
        raise SystemExit(f"no scene of {args.data} matches {args.scenes}")
    rows = []
    for folder in folders:
        scene = load_scene(folder, load_depth=False)
        r = scene_at(scene, args.views, args.size)
        ims, cams = r.input_images, r.input_cameras
        g = model.reconstruct_pruned(ims, cams, r.near, r.far).gaussians
        t = scene.target_indices[args.target]
        plain = render_view(g, r.cameras[t], ims, cams, model.improver)
        filled = render_view(g, r.cameras[t], ims, cams, model.improver, fill_holes=True)
        row = [plain.raw, fill_holes(plain.raw, plain.alpha), plain.image, filled.image]
        rows.append(torch.cat(row + [r.images[t]], -1))  # [3,H,5W]
        print(folder.name, flush=True)
    print(f"wrote {write_image(args.out, torch.cat(rows, -2).clamp(0, 1))}")


if __name__ == "__main__":
    main()
