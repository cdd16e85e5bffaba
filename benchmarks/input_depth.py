"""How good is the generator's depth where it is made: the input views (the generator issue's
"input-depth AbsRel" bar, ≤ 0.15).

The ladder scores the depth *rendered at the targets* from all Gaussians; this script scores
the per-input-view depth maps the generator predicts, against Blender's depth at those
cameras, beside two answers that need no learning:

- ``constant``: every pixel at the scene's median true depth (an oracle scale, no shape);
- ``plane sweep``: ZNCC plane-sweep stereo's winner-take-all depth
  (:func:`prosplat.eval.baselines.plane_sweep.plane_sweep_depths`, 64 candidates), and the same on
  its most confident 30 % of pixels (``sweep top 30 %``) next to the generator on those
  pixels (``<model> on the sweep's top 30 %``).

With ``--crop WxH`` every input is the centre window of that size of its ``--size`` frame (the
principal point moved to match, the focal length kept): the cameras of another aspect ratio or
a narrower field of view than the square renders, as users' cameras are.

Per scene type it prints the mean AbsRel (what the ladder and the issue report: a few pixels
placed far behind the truth dominate it), the median AbsRel and δ < 1.25 (the share of
pixels within 25 % of the truth).

    python benchmarks/input_depth.py --data data/test128 --size 64 \\
        --generator v3=runs/generator_v3.safetensors --generator v4=runs/gen_v4/generator.safetensors
    python benchmarks/input_depth.py --data data/test128 --size 128 --crop 128x64 --no-sweep
    python benchmarks/input_depth.py --data data/test128 --size 128 --no-sweep --depth-sweep

``ProSplat.run_generator`` is the generator alone: its depth before the pipeline's depth sweep
(``--depth-sweep`` adds the swept rows).
"""

from __future__ import annotations

import argparse
import math
import statistics as st
from collections import defaultdict

import torch

from prosplat import ProSplat
from prosplat.core.camera import Camera
from prosplat.data import find_scenes, load_scene
from prosplat.eval.baselines.plane_sweep import plane_sweep_depths
from prosplat.eval.generator import scene_at
from prosplat.eval.ladder.geometry import resize_depths
from prosplat.pipeline.depth_sweep import sweep_depths


def depth_scores(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor) -> dict[str, float]:
    """Mean and median AbsRel, δ < 1.25 and the scale bias (median log ratio) of ``pred``
    against ``gt`` [V,H,W] on ``mask``. AbsRel has no sign; the bias says which way a
    generator errs: a depth placed 10 % too far in most pixels is +0.095."""
    p, g = pred[mask].double(), gt[mask].double()
    rel = (p - g).abs() / g
    ratio = torch.maximum(p / g, g / p)
    return {
        "mean": float(rel.mean()),
        "median": float(rel.median()),
        "delta": float((ratio < 1.25).double().mean()),
        "bias": float(torch.log(p / g).median()),
    }


def centre_crop(images: torch.Tensor, cameras: list[Camera], width: int, height: int):
    """The centre ``width`` x ``height`` window of images [V,3,H,W] (or depths [V,H,W]) and
    the cameras that see exactly it (principal point shifted, focal length kept)."""
    h, w = images.shape[-2:]
    if not (0 < width <= w and 0 < height <= h):
        raise SystemExit(f"--crop {width}x{height} does not fit {w}x{h} inputs")
    top, left = (h - height) // 2, (w - width) // 2
    cams = []
    for c in cameras:
        K = c.K.clone()
        K[0, 2] -= left
        K[1, 2] -= top
        cams.append(Camera(K, c.world_to_cam, width, height))
    return images[..., top : top + height, left : left + width].contiguous(), cams


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/test128")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--scenes", type=int, default=0, help="first N scenes (0 = all)")
    ap.add_argument(
        "--generator",
        action="append",
        default=[],
        metavar="LABEL=PATH",
        help="a generator to score (repeatable; default: the shipped one as 'shipped')",
    )
    ap.add_argument("--no-sweep", action="store_true", help="skip the plane-sweep rows")
    ap.add_argument(
        "--depth-sweep",
        action="store_true",
        help="also score each generator's depth after the local sweep the pipeline runs "
        "(prosplat.pipeline.depth_sweep, rows '<model> + depth sweep')",
    )
    ap.add_argument(
        "--crop",
        metavar="WxH",
        help="score the centre WxH window of each input (cameras shifted to match)",
    )
    args = ap.parse_args()
    crop = tuple(int(v) for v in args.crop.lower().split("x")) if args.crop else None
    torch.set_grad_enabled(False)
    models = {}
    for spec in args.generator or ["shipped="]:
        label, _, path = spec.partition("=")
        models[label] = ProSplat.from_pretrained(path or None, improve=False, depth_sweep=True)

    rows: dict[str, dict[str, list[dict]]] = defaultdict(lambda: defaultdict(list))
    folders = find_scenes(args.data)
    for folder in folders[: args.scenes or None]:
        scene = load_scene(folder)
        kind = folder.name.rsplit("_", 1)[0]
        r = scene_at(scene, args.views, args.size)
        gt = resize_depths(scene.depths[r.inputs], r.cameras[0].width, r.cameras[0].height)
        images, cameras = r.input_images, r.input_cameras
        if crop:
            images, cameras = centre_crop(images, cameras, *crop)
            gt = centre_crop(gt, r.input_cameras, *crop)[0]
        valid = gt > 0  # [V,H,W]: pixels with a surface
        const = torch.full_like(gt, float(gt[valid].median()))
        rows["constant (true median)"][kind].append(depth_scores(const, gt, valid))
        preds = {
            label: m.run_generator(images, cameras, r.near, r.far).depths[0]
            for label, m in models.items()
        }
        if args.depth_sweep:
            for label, d in list(preds.items()):
                swept = sweep_depths(images, cameras, d, models[label].depth_sweep)[0]
                preds[f"{label} + depth sweep"] = swept
        for label, d in preds.items():
            rows[label][kind].append(depth_scores(d, gt, valid))
        if not args.no_sweep:
            sweep, conf = plane_sweep_depths(images, cameras, r.near, r.far, 64)
            top = valid & (conf >= conf[valid].quantile(0.7))
            rows["plane sweep"][kind].append(depth_scores(sweep, gt, valid))
            rows["sweep top 30 %"][kind].append(depth_scores(sweep, gt, top))
            for label, d in preds.items():
                rows[f"{label} on the sweep's top 30 %"][kind].append(depth_scores(d, gt, top))
        print(
            f"{folder.name}: "
            + ", ".join(f"{label} {rows[label][kind][-1]['mean']:.3f}" for label in preds),
            flush=True,
        )

    kinds = sorted({k for per in rows.values() for k in per})
    print(
        f"\n{args.data} at {args.size} px{f' (centre {args.crop})' if crop else ''}, "
        f"{args.views} inputs; mean AbsRel / median AbsRel / "
        "δ<1.25 over scenes (per-type columns: mean AbsRel)\n"
    )
    print("| depth | mean AbsRel | median AbsRel | δ<1.25 | " + " | ".join(kinds) + " |")
    print("|---|---:|---:|---:|" + "---:|" * len(kinds))
    for label, per in rows.items():
        every = [s for k in kinds for s in per.get(k, [])]
        cells = [f"{st.mean(s[m] for s in every):.3f}" for m in ("mean", "median", "delta")]
        cells += [f"{st.mean(s['mean'] for s in per[k]):.3f}" if per.get(k) else "" for k in kinds]
        print(f"| {label} | " + " | ".join(cells) + " |")
    print(
        "\nScale bias: exp(median log(pred / true)) - 1 over each scene's valid pixels, mean "
        "over scenes (+10 % = placed 10 % too far)\n"
    )
    print("| depth | all | " + " | ".join(kinds) + " |")
    print("|---|---:|" + "---:|" * len(kinds))
    for label, per in rows.items():
        every = [s for k in kinds for s in per.get(k, [])]
        biases = [st.mean(s["bias"] for s in every)]
        biases += [st.mean(s["bias"] for s in per[k]) if per.get(k) else None for k in kinds]
        cells = ["" if b is None else f"{100 * (math.exp(b) - 1):+.1f} %" for b in biases]
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
