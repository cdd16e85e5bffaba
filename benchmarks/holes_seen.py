"""Where the raw render's holes are: in parts of a target that some input saw, or in parts no
input saw.

A hole (render alpha < 0.5) where no input camera saw the surface is out of reach of any
reconstruction from those inputs (only a fill or stage 2 can paint it); a hole over a surface
that an input saw is the generator's fault, and a loss can teach it away. Blender's depth
decides, through the ladder's valid region (:func:`prosplat.ladder.geometry.valid_mask`: the
target's surface point, or its sky direction, lands unoccluded in some input's frame). The
Gaussians at Blender's true input depth are scored too: their holes in seen parts are the
mask's own error and the cracks between true-depth splats.

    python benchmarks/holes_seen.py --data data/test128 --size 128 --views 4 \\
        --generator runs/generator_v10.safetensors runs/generator_v11.safetensors
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch
from torch import Tensor

from prosplat import ProSplat
from prosplat.data import find_scenes, load_scene
from prosplat.evaluate import scene_at
from prosplat.ladder.geometry import VISIBILITY_TOL, resize_depths, true_depth_gaussians, valid_mask
from prosplat.render import render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/test128")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--tolerance", type=float, default=VISIBILITY_TOL, help="occlusion slack")
    ap.add_argument("--generator", nargs="+", default=[None], help="weights (default: shipped)")
    ap.add_argument("--scenes", type=int, default=None, help="only the first N scenes")
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    folders = find_scenes(args.data)[: args.scenes]
    models: dict[str, ProSplat | None] = {
        str(g): ProSplat.from_pretrained(g, improve=False) for g in args.generator
    }
    models["true-depth"] = None  # the upper bound: its seen holes are the mask's own error
    totals = {name: torch.zeros(6) for name in models}  # pixels, seen, holes, seen holes, ...
    header = "scene | seen % | " + " | ".join(
        f"{Path(n).stem}: holes % / in seen % / PSNR seen / unseen" for n in models
    )
    print(header)
    for folder in folders:
        scene = load_scene(folder)
        r = scene_at(scene, args.views, args.size)
        h, w = r.images.shape[-2:]
        depths = resize_depths(scene.depths, w, h)
        cams_in = [r.cameras[i] for i in r.inputs]
        ims = r.images[r.inputs]
        seen_of = {  # the same masks score every model
            t: valid_mask(r.cameras[t], depths[t], cams_in, depths[r.inputs], args.tolerance)
            for t in scene.target_indices
        }
        line = None
        for name, model in models.items():
            if model is None:
                g = true_depth_gaussians(ims, depths[r.inputs], cams_in)
            else:
                g = model.reconstruct_pruned(ims, cams_in, r.near, r.far).gaussians
            row = torch.zeros(6)
            for t, seen in seen_of.items():
                out = render(g, r.cameras[t])
                hole = out.alpha.reshape(h, w) < 0.5
                gt = r.images[t]
                se = ((out.rgb.clamp(0, 1) - gt) ** 2).mean(0)
                row += torch.tensor(
                    [
                        seen.numel(),
                        seen.sum(),
                        hole.sum(),
                        (hole & seen).sum(),
                        se[seen].sum(),
                        se[~seen].sum(),
                    ],
                    dtype=torch.float32,
                )
            totals[name] += row
            cell = _cell(row)
            line = (line or f"{folder.name} | {100 * row[1] / row[0]:.0f}") + f" | {cell}"
        print(line, flush=True)
    line = "all | " + f"{100 * next(iter(totals.values()))[1] / next(iter(totals.values()))[0]:.0f}"
    print(line + "".join(f" | {_cell(t)}" for t in totals.values()))


def _cell(row: Tensor) -> str:
    n, seen, holes, seen_holes, se_seen, se_unseen = row.tolist()
    p_seen = -10 * math.log10(max(se_seen / max(seen, 1), 1e-10))
    p_unseen = -10 * math.log10(max(se_unseen / max(n - seen, 1), 1e-10))
    return (
        f"{100 * holes / n:.1f} / {100 * seen_holes / max(holes, 1):.0f} / "
        f"{p_seen:.2f} / {p_unseen:.2f}"
    )


if __name__ == "__main__":
    main()
