"""What the generator's 1/4-resolution depth costs once upsampled: the true-depth bound again.

The generator predicts depth at 1/4 of its matching size and upsamples it x4 bilinearly, then
corrects it with a small full-resolution network (``DepthRefiner``). This benchmark takes that
step out of the generator: Blender's true input depth is averaged to 1/4 (``--factor``)
resolution in inverse depth (sky at the ladder's sky shell, ``SKY_DEPTH_FACTOR`` x the
farthest surface) and brought back to full resolution by

- ``bilinear``: what the generator's depth head does before its refiner;
- ``nearest``: the cell's own value;
- ``best of 4``: per pixel, the one of the four samples bilinear interpolation reads that is
  nearest the true inverse depth, the best that learned (convex) upsampling weights over
  those samples can do;
- ``best of 9``: the same over the cell's 3x3 neighbourhood.

Each depth map becomes Gaussians as the ladder's true-depth row makes them
(:func:`prosplat.ladder.geometry.true_depth_gaussians`), and the targets are scored raw with
their holes filled, as issue 12 scores the generator.

    python benchmarks/depth_upsampling.py --data data/test128 --size 128 --views 4
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.data import find_scenes, load_scene
from prosplat.enhance import render_view
from prosplat.evaluate import scene_at
from prosplat.ladder.geometry import SKY_DEPTH_FACTOR, resize_depths, true_depth_gaussians
from prosplat.metrics import LPIPS, psnr

FACTOR = 4  # the generator's depth is predicted at 1/4 of its matching size (--factor)
METHODS = ("true depth", "bilinear", "nearest", "best of 4", "best of 9")


def bilinear_support(n_low: int, n_high: int) -> tuple[Tensor, Tensor, Tensor]:
    """Along one axis, where ``F.interpolate(mode="bilinear", align_corners=False)`` from
    ``n_low`` to ``n_high`` samples reads: ``i0, i1 [n_high]`` the two source indices and
    ``frac [n_high]`` the weight of ``i1`` (coordinates below 0 clamp to 0, indices above
    ``n_low - 1`` to it, as torch does)."""
    src = ((torch.arange(n_high) + 0.5) * (n_low / n_high) - 0.5).clamp(min=0)
    i0 = src.floor().long().clamp(max=n_low - 1)
    return i0, (i0 + 1).clamp(max=n_low - 1), src - i0


def _candidates_4(low: Tensor, height: int, width: int) -> Tensor:
    """low [V,1,h,w] -> [V,4,H,W]: the four samples bilinear interpolation reads per pixel."""
    y0, y1, _ = bilinear_support(low.shape[-2], height)
    x0, x1, _ = bilinear_support(low.shape[-1], width)
    return torch.cat([low[:, :, ys][:, :, :, xs] for ys in (y0, y1) for xs in (x0, x1)], 1)


def _candidates_9(low: Tensor, factor: int) -> Tensor:
    """low [V,1,h,w] -> [V,9,H,W]: the 3x3 low-resolution neighbourhood of each pixel's cell."""
    v, _, h, w = low.shape
    near = F.unfold(F.pad(low, (1, 1, 1, 1), mode="replicate"), 3).view(v, 9, h, w)
    return F.interpolate(near, scale_factor=factor, mode="nearest")


def upsampled_depths(depth: Tensor, method: str, factor: int = FACTOR) -> Tensor:
    """depth [V,H,W] (0 = sky), H and W multiples of ``factor`` -> [V,H,W] after the
    1/``factor``-resolution round trip of ``method`` (sky kept at the sky shell's depth)."""
    if method == "true depth":
        return depth
    if depth.shape[-2] % factor or depth.shape[-1] % factor:
        raise ValueError(
            f"upsampled_depths: a {depth.shape[-1]}x{depth.shape[-2]} depth map does not split "
            f"into {factor}x{factor} cells; pick --size and --factor so both sides divide"
        )
    surface = depth > 0
    far = SKY_DEPTH_FACTOR * float(depth[surface].max()) if surface.any() else 1.0
    inv = 1.0 / torch.where(surface, depth, torch.full_like(depth, far))[:, None]  # [V,1,H,W]
    low = F.avg_pool2d(inv, factor)  # [V,1,h,w]
    height, width = inv.shape[-2:]
    if method == "bilinear":
        up = F.interpolate(low, size=(height, width), mode="bilinear", align_corners=False)
    elif method == "nearest":
        up = F.interpolate(low, size=(height, width), mode="nearest")
    else:  # best of 4 / best of 9: the candidate nearest the true inverse depth
        four = method == "best of 4"
        cands = _candidates_4(low, height, width) if four else _candidates_9(low, factor)
        up = cands.gather(1, (cands - inv).abs().argmin(1, keepdim=True))
    return 1.0 / up[:, 0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/test128")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--scenes", type=int, default=None, help="only the first N scenes")
    ap.add_argument(
        "--factor", type=int, default=FACTOR, help="the low resolution is 1/FACTOR (default 4)"
    )
    args = ap.parse_args()
    if args.factor < 1 or args.size % args.factor:
        raise SystemExit(f"--size must be a multiple of --factor, got {args.size}, {args.factor}")
    lpips = LPIPS()
    scores: dict[str, list[tuple[float, float]]] = {m: [] for m in METHODS}
    folders = find_scenes(Path(args.data))[: args.scenes]
    for n, folder in enumerate(folders):
        scene = load_scene(folder, load_depth=True)
        at = scene_at(scene, args.views, args.size)
        h, w = at.images.shape[-2:]
        depth = resize_depths(scene.depths[at.inputs], w, h)  # [V,H,W]
        for method in METHODS:
            g = true_depth_gaussians(
                at.input_images,
                upsampled_depths(depth, method, args.factor),
                at.input_cameras,
                part="all",
            )
            for t in scene.target_indices:
                gt = at.images[t]
                with torch.no_grad():
                    view = render_view(g, at.cameras[t], fill_holes=True).image.clamp(0, 1)
                    scores[method].append(
                        (float(psnr(view, gt)), float(lpips(view[None], gt[None])))
                    )
        print(f"[{n + 1}/{len(folders)}] {folder.name}", flush=True)
    n = len(scores["bilinear"])
    print(f"\n{args.data}, {args.size} px, 1/{args.factor} res, {args.views} inputs, {n} targets")
    print("| input depth | PSNR (filled) | LPIPS |\n|---|---:|---:|")
    for method, rows in scores.items():
        p = statistics.mean(r[0] for r in rows)
        lp = statistics.mean(r[1] for r in rows)
        print(f"| {method} | {p:.2f} | {lp:.3f} |")


if __name__ == "__main__":
    main()
