"""Where each plane sweep peaks: the generator's learned cost volume against the images' own.

The depth head sees a cost volume over D planes from near to far. This measures, on scenes
with Blender's depth, how near the truth each volume's peak (argmax over the planes) lies,
per 1/4-resolution pixel fully covered by the truth, in normalised inverse depth t (where the
planes are uniform, one plane step = 1/(D-1)):

- ``learned``: the generator's correlation of its matching features (what its depth head gets);
- ``depth head t``: the depth head's own expectation at 1/4 resolution (what the full-size
  refiner then corrects, often by much);
- ``generator depth``: the generator's output depth, averaged to 1/4 resolution in inverse
  depth (the network's answer, for scale);
- ``image <res> w<N>``: the ZNCC plane sweep of the input images
  (:func:`prosplat.generator.image_cost.image_cost_volume`) at the matching size (``full``)
  or half of it (``half``), with an N-pixel window, averaged to 1/4 resolution.

Columns: median |t error|, the share within 1.5 plane steps, and the median seconds per scene
(the learned volume's time is not separable from the forward pass and is left blank).

    python benchmarks/plane_peaks.py --data data/val128 --sizes 64 128
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
import torch.nn.functional as F

from prosplat.data import SceneDataset
from prosplat.generator.cost_volume import (
    inverse_depth_candidates,
    nearest_views,
    scale_intrinsics,
)
from prosplat.generator.image_cost import image_cost_volume
from prosplat.pipeline import ProSplat


def peak_errors(volume: torch.Tensor, t_true: torch.Tensor, covered: torch.Tensor) -> torch.Tensor:
    """volume [V,D,h,w] (plane 0 nearest), t_true [V,h,w], covered [V,h,w] bool -> the
    |t error| of the argmax plane at every covered pixel, [n]."""
    d = volume.shape[1]
    t_planes = torch.linspace(1.0, 0.0, d, dtype=volume.dtype)  # near -> far
    return (t_planes[volume.argmax(1)] - t_true).abs()[covered]


def image_variant(name: str) -> tuple[int, int]:
    """ "half w5" -> (2, 5): the divisor of the matching size and the window."""
    res, window = name.split()
    return {"full": 1, "half": 2}[res], int(window.removeprefix("w"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/val128")
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument(
        "--image-variants", nargs="+", default=["full w5", "half w5", "half w3"],
        help="image sweeps to score, '<full|half> w<window>'",
    )  # fmt: skip
    ap.add_argument("--generator", default=None, help="weights (default: the shipped ones)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    variants = {name: image_variant(name) for name in args.image_variants}

    generator = ProSplat.from_pretrained(generator=args.generator).generator.eval()
    caught: dict[str, torch.Tensor] = {}

    def head_hook(module, inputs, out) -> None:
        caught["learned"], caught["head"] = inputs[0], out[0]  # [V,D,h,w], [V,1,h,w]

    handle = generator.depth_head.register_forward_hook(head_hook)
    d = generator.config.num_depth_candidates
    step = 1.0 / (d - 1)
    ds = SceneDataset(args.data, n_inputs=args.views)
    print(f"{len(ds)} scenes of {args.data}, {args.views} inputs, {d} planes")
    print("| px | volume | median abs t error | within 1.5 planes | s per scene |")
    print("|---:|---|---:|---:|---:|")
    for size in args.sizes:
        errors: dict[str, list[torch.Tensor]] = {}
        seconds: dict[str, list[float]] = {}
        for i in range(len(ds)):
            s = ds[i]
            native = s["input_images"].shape[-1]
            near, far = float(s["near"]), float(s["far"])
            w2c = s["input_w2c"][None]
            q = size // 4
            truth = s["input_depths"][:, None]  # [V,1,H,W], 0 where nothing was hit
            inv = F.interpolate(1 / truth.clamp(min=1e-6), size=(q, q), mode="area")[:, 0]
            covered = F.interpolate((truth > 0).float(), size=(q, q), mode="area")[:, 0] > 0.99
            t_true = (inv - 1 / far) / (1 / near - 1 / far)  # [V,h,w]
            images = F.interpolate(
                s["input_images"], size=(size, size), mode="bilinear", antialias=True
            )  # [V,3,size,size]
            K = scale_intrinsics(s["input_K"], size / native, size / native)[None]
            with torch.no_grad():
                depth = generator(images[None], K, w2c, near, far).depths[0]  # [V,size,size]
            inv_pred = F.interpolate(1 / depth[:, None], size=(q, q), mode="area")[:, 0]
            t_pred = (inv_pred - 1 / far) / (1 / near - 1 / far)  # [V,h,w]
            errors.setdefault("learned", []).append(peak_errors(caught["learned"], t_true, covered))
            errors.setdefault("depth head t", []).append(
                (caught["head"][:, 0] - t_true).abs()[covered]
            )
            errors.setdefault("generator depth", []).append((t_pred - t_true).abs()[covered])
            planes = inverse_depth_candidates(torch.tensor([near]), torch.tensor([far]), d)
            neighbours = nearest_views(w2c, generator.config.cost_volume_views)
            for name, (div, window) in variants.items():
                m = size // div
                sized = F.interpolate(images, size=(m, m), mode="bilinear", antialias=True)
                K_m = scale_intrinsics(s["input_K"], m / native, m / native)[None]
                start = time.perf_counter()
                volume = image_cost_volume(
                    sized.clamp(0, 1)[None], K_m, w2c, planes, neighbours, window, pool=4 // div
                )[0]
                seconds.setdefault(name, []).append(time.perf_counter() - start)
                errors.setdefault(f"image {name}", []).append(peak_errors(volume, t_true, covered))
        for name, parts in errors.items():
            e = torch.cat(parts)
            key = name.removeprefix("image ")
            took = f"{statistics.median(seconds[key]):.3f}" if key in seconds else ""
            print(
                f"| {size} | {name} | {float(e.median()):.4f} | "
                f"{float((e < 1.5 * step).float().mean()):.3f} | {took} |"
            )
    handle.remove()


if __name__ == "__main__":
    main()
