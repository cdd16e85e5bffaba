"""Could a learned second search in a narrow band around the generator's depth sharpen it?

A cascade (CasMVSNet-style) searches again in a band around the depth head's estimate at a
finer resolution, correlating the same matching features. That only helps if (a) the truth
lies inside the band and (b) the band's correlation peaks nearer the truth than the estimate.
This measures both for the shipped generator, at 1/2 resolution, on scenes with Blender's
depth: for each input pixel (1/2 resolution, fully covered by the truth) the band is
``--candidates`` depths within ``--band-steps`` coarse candidate steps of the estimate, in
normalised inverse depth t (where the coarse candidates are uniform); the table gives the
share of pixels whose truth lies inside the band and, on those, the mean |t error| of the
estimate, of the band candidate where the correlation peaks (fine 1/2-resolution features;
the 1/4-resolution features upsampled; both summed), and of a band candidate drawn at random.

    python benchmarks/band_matching.py --data data/val128 --sizes 64 128
"""

from __future__ import annotations

import argparse

import torch
import torch.nn.functional as F

from prosplat.data import SceneDataset
from prosplat.generator.cost_volume import (
    nearest_views,
    plane_sweep_cost_volume,
    scale_intrinsics,
)
from prosplat.pipeline import ProSplat


class Captured:
    """The generator's 1/4-resolution t and its matching features from each forward pass,
    caught by forward hooks on the depth head and the encoder (:meth:`close` removes them)."""

    def __init__(self, generator) -> None:
        self.maps: dict[str, torch.Tensor] = {}

        def head_hook(module, inputs, out) -> None:
            self.maps["t"] = out[0]  # [V,1,h/4,w/4]

        def encoder_hook(module, inputs, out) -> None:
            self.maps["feats"], self.maps["fine"] = out  # [1,V,C,h/4,..], [1,V,Cf,h/2,..]

        self._handles = [
            generator.depth_head.register_forward_hook(head_hook),
            generator.encoder.register_forward_hook(encoder_hook),
        ]

    def close(self) -> None:
        for handle in self._handles:
            handle.remove()


def band_scores(
    t: torch.Tensor,
    t_true: torch.Tensor,
    covered: torch.Tensor,
    band: torch.Tensor,
    costs: dict[str, torch.Tensor],
    half_width: float,
    rng: torch.Generator,
) -> dict[str, float]:
    """One scene's row: t, t_true, covered [V,1,h,w] (covered: share of the pixel the truth
    hits), band [V,Dc,h,w] candidates in t, costs name -> [V,Dc,h,w] correlation ->
    {"in band": share of pixels, "estimate" / each cost / "random": mean |t error| on the
    covered pixels whose truth is within ``half_width`` of t}."""
    in_band = (covered > 0.99) & ((t_true - t).abs() < half_width)  # [V,1,h,w]

    def error(pick: torch.Tensor) -> float:  # pick [V,1,h,w] candidate indices
        return float((band.gather(1, pick) - t_true).abs()[in_band].mean())

    row = {"in band": float(in_band.float().mean())}
    row["estimate"] = float((t - t_true).abs()[in_band].mean())
    for name, cost in costs.items():
        row[name] = error(cost.argmax(1, keepdim=True))
    row["random"] = error(torch.randint(0, band.shape[1], t.shape, generator=rng))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/val128")
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--band-steps", type=float, nargs="+", default=[2.0, 4.0])
    ap.add_argument("--candidates", type=int, default=9)
    ap.add_argument("--generator", default=None, help="weights (default: the shipped ones)")
    args = ap.parse_args()

    generator = ProSplat.from_pretrained(generator=args.generator).generator.eval()
    if not generator.config.fine_matching_channels:
        raise SystemExit("band_matching.py: these weights have no fine matching features")
    captured = Captured(generator)
    coarse_steps = generator.config.num_depth_candidates - 1
    ds = SceneDataset(args.data, n_inputs=args.views)
    print(f"{len(ds)} scenes of {args.data}, {args.views} inputs, {args.candidates} candidates")
    print(
        "| px | band (coarse steps) | truth in band | estimate | fine | 1/4 upsampled | both | random |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for size in args.sizes:
        # per band width: its rng (the random column) and each scene's row
        rngs = {steps: torch.Generator().manual_seed(0) for steps in args.band_steps}
        rows: dict[float, dict[str, list[float]]] = {steps: {} for steps in args.band_steps}
        for i in range(len(ds)):
            s = ds[i]
            native = s["input_images"].shape[-1]  # the data's square size, K's pixels
            half = size // 2
            images = F.interpolate(
                s["input_images"], size=(size, size), mode="bilinear", antialias=True
            )
            near, far = float(s["near"]), float(s["far"])
            w2c = s["input_w2c"][None]
            K_half = scale_intrinsics(s["input_K"], half / native, half / native)[None]
            nbr = nearest_views(w2c, generator.config.cost_volume_views)
            truth = s["input_depths"][:, None]  # [V,1,H,W], 0 where nothing was hit
            inv = F.interpolate(1 / truth.clamp(min=1e-6), size=(half, half), mode="area")
            covered = F.interpolate((truth > 0).float(), size=(half, half), mode="area")
            t_true = (inv - 1 / far) / (1 / near - 1 / far)  # [V,1,h/2,w/2]
            with torch.no_grad():  # once per scene and size: every band width reads its maps
                K_in = scale_intrinsics(s["input_K"], size / native, size / native)[None]
                generator(images[None], K_in, w2c, near, far)
                t = F.interpolate(captured.maps["t"], size=(half, half), mode="bilinear")
                up = F.interpolate(captured.maps["feats"][0], size=(half, half), mode="bilinear")
            for steps in args.band_steps:
                offsets = torch.linspace(-steps, steps, args.candidates) / coarse_steps  # [Dc]
                band = (t + offsets[None, :, None, None]).clamp(1e-4, 1 - 1e-4)  # [V,Dc,..]
                depths = 1 / (1 / far + band * (1 / near - 1 / far))
                with torch.no_grad():
                    fine = plane_sweep_cost_volume(
                        captured.maps["fine"], K_half, w2c, depths[None], nbr
                    )[0]
                    coarse = plane_sweep_cost_volume(up[None], K_half, w2c, depths[None], nbr)[0]
                costs = {"fine": fine, "up": coarse, "both": fine + coarse}
                row = band_scores(
                    t, t_true, covered, band, costs, steps / coarse_steps, rngs[steps]
                )
                for key, value in row.items():
                    rows[steps].setdefault(key, []).append(value)
        for steps in args.band_steps:
            mean = {k: sum(v) / len(v) for k, v in rows[steps].items()}
            print(
                f"| {size} | ±{steps:g} | {mean['in band']:.0%} | {mean['estimate']:.4f} | "
                f"{mean['fine']:.4f} | {mean['up']:.4f} | {mean['both']:.4f} | "
                f"{mean['random']:.4f} |"
            )


if __name__ == "__main__":
    main()
