"""Does blending the warps of every input cure stage 2's flicker? (It does not.)

The shipped stage 2 sees the MORI reference warped into the view. Along a camera path MORI
switches reference, so the texture could jump where it does. This script gives the same
model, per target and along a 24-frame path per scene, other warps in its 4 channels:

- ``mori``: the shipped input (MORI's reference alone);
- ``fill``: MORI's warp, its invalid pixels filled from the valid input seen at the smallest
  angle (more coverage, same texture);
- ``tN``: every valid input blended per pixel with weights exp(-(θ - θ_min)/N°), θ the angle
  at the surface point between the input's ray and the target's (unstructured-lumigraph
  style; large N averages, small N picks), so the warp changes continuously with the camera.

It prints mean PSNR / LPIPS over the targets and the median flicker ratio to the raw renders
(:mod:`prosplat.flicker`) per variant.

    python benchmarks/warp_blend.py --data data/test128 --size 64 --scenes 8
"""

from __future__ import annotations

import argparse
import statistics as st

import torch

from prosplat import ProSplat
from prosplat.data import find_scenes, load_scene
from prosplat.enhance import enhance
from prosplat.evaluate import scene_at
from prosplat.flicker import camera_path, flicker
from prosplat.improve.mori import select_reference
from prosplat.improve.warp import warp_reference
from prosplat.metrics import LPIPS, psnr
from prosplat.render import render

VARIANTS = ("mori", "fill", "t2", "t5", "t15", "t45")


def every_warp(cam, depth, alpha, images, cams, ref_depths):
    """Each input warped into ``cam`` [N,3,H,W], its validity [N,H,W] and the angle in
    degrees between its ray and the target's at the surface point [N,H,W]."""
    warps, valid = zip(
        *(
            warp_reference(images[i], c, cam, depth, alpha, ref_depths[i])
            for i, c in enumerate(cams)
        )
    )
    points = cam.unproject(cam.pixel_centers(torch.float64), depth.double())  # [H,W,3]
    to_target = torch.nn.functional.normalize(points - cam.center.double(), dim=-1)
    angles = [
        torch.rad2deg(
            torch.arccos(
                (torch.nn.functional.normalize(points - c.center.double(), dim=-1) * to_target)
                .sum(-1)
                .clamp(-1, 1)
            )
        )
        for c in cams
    ]
    return torch.stack(warps), torch.stack(valid), torch.stack(angles)


def variant_warp(name: str, warps, valid, angles, j: int):
    """The 4-channel warp input of variant ``name`` (MORI's reference is input ``j``)."""
    far = torch.full_like(angles, 1e9)
    if name == "mori":
        w, v = warps[j], valid[j]
    elif name == "fill":
        best = torch.where(valid, angles, far).argmin(0)
        pick = torch.where(valid[j], torch.full_like(best, j), best)
        w = torch.gather(warps, 0, pick[None, None].expand(1, 3, *pick.shape))[0]
        v = valid.any(0)
    else:
        tau = float(name[1:])
        a = torch.where(valid, angles, far)
        weight = torch.where(valid, torch.exp(-(a - a.min(0).values) / tau), 0.0).float()
        v = valid.any(0)
        w = (warps * weight[:, None]).sum(0) / weight.sum(0).clamp_min(1e-8)[None]
        w = torch.where(v[None], w, warps[j])
    return torch.cat([w, v[None].float()])


def enhanced_variants(state, cam):
    """(raw render, {variant: the view enhanced with that warp input}) of ``cam``;
    ``state``: (improver, Gaussians, input images, input cameras, their rendered depths)."""
    improver, g, inp, icams, ref_depths = state
    with torch.no_grad():
        r = render(g, cam)
        j = select_reference(cam, icams, method="paper")
        warps, valid, angles = every_warp(cam, r.depth, r.alpha, inp, icams, ref_depths)
        out = {
            v: enhance(improver, r.rgb, cam, inp[j], icams[j], alpha=r.alpha,
                       warp=variant_warp(v, warps, valid, angles, j))
            for v in VARIANTS
        }  # fmt: skip
    return r, out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="data/test128")
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--scenes", type=int, default=8)
    p.add_argument("--frames", type=int, default=24)
    args = p.parse_args()
    model, lpips = ProSplat.from_pretrained(), LPIPS()
    scores = {v: ([], []) for v in VARIANTS}
    ratios = {v: [] for v in VARIANTS}
    for folder in find_scenes(args.data)[: args.scenes]:
        scene = load_scene(folder, load_depth=False)
        at = scene_at(scene, 4, args.size)
        images, cams, inp, icams = at.images, at.cameras, at.input_images, at.input_cameras
        g = model.reconstruct_pruned(inp, icams, at.near, at.far).gaussians
        with torch.no_grad():
            ref_depths = [render(g, c).depth for c in icams]
        state = (model.improver, g, inp, icams, ref_depths)
        for t in scene.target_indices:
            _, out = enhanced_variants(state, cams[t])
            for v in VARIANTS:
                scores[v][0].append(float(psnr(out[v], images[t])))
                scores[v][1].append(float(lpips(out[v][None], images[t][None])))
        path = camera_path(
            cams[scene.target_indices[0]], cams[scene.target_indices[1]], args.frames
        )
        frames = [enhanced_variants(state, c) for c in path]
        depths = torch.stack([r.depth for r, _ in frames])
        raw = flicker(torch.stack([r.rgb for r, _ in frames]), depths, path)
        for v in VARIANTS:
            ratios[v].append(flicker(torch.stack([o[v] for _, o in frames]), depths, path) / raw)
        print(folder.name, flush=True)
    print("| warp input | PSNR | LPIPS | flicker / raw (median) |\n|---|---:|---:|---:|")
    for v in VARIANTS:
        print(f"| {v} | {st.mean(scores[v][0]):.2f} | {st.mean(scores[v][1]):.3f} | "
              f"{st.median(ratios[v]):.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
