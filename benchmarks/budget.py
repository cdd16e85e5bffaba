"""Gaussian budget: count against PSNR and render time for the generator's output.

For each test scene (all its input views), the generator's Gaussians are rendered into every
target view unpruned, with the automatic budget (transparent / out-of-bounds / cross-view
duplicates removed; the default duplicate test and a looser one, to show what its tolerance
buys), and with fixed fractions of the unpruned count. Render times are medians of
--repeats renders per view, all configurations measured in the same run.

    python benchmarks/budget.py --data data/test --weights runs/tiny/checkpoint.safetensors

Prints a Markdown table and writes ``budget.json`` and ``budget.png`` to --out.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from prosplat.data import find_scenes, load_scene
from prosplat.geometry.budget import prune_gaussians
from prosplat.metrics import psnr
from prosplat.pipeline.model import ProSplat
from prosplat.render import render

#: (label, prune_gaussians keyword arguments; None = unpruned)
SETTINGS: list[tuple[str, dict | None]] = [
    ("unpruned", None),
    ("auto", {}),
    ("auto, loose dedup (5 %, 4 px)", {"dedup_tol": 0.05, "dedup_px": 4.0}),
    ("auto, no dedup", {"dedup_tol": None}),
    ("0.5", {"budget": 0.5}),
    ("0.3", {"budget": 0.3}),
    ("0.2", {"budget": 0.2}),
    ("0.1", {"budget": 0.1}),
]


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--scenes", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    args = ap.parse_args()
    model = ProSplat.from_pretrained(args.weights)
    acc: dict[str, dict[str, list[float]]] = {
        k: {"n": [], "psnr": [], "ms": []} for k, _ in SETTINGS
    }
    for folder in find_scenes(args.data)[: args.scenes]:
        sc = load_scene(folder)
        ins = sc.input_indices
        cams = [sc.cameras[i] for i in ins]
        near, far = float(sc.near[ins].min()), float(sc.far[ins].max())
        out = model.run_generator(sc.images[ins], cams, near, far)
        g_all, depths = out.gaussians(0), out.depths[0]
        view_index = torch.arange(len(ins)).repeat_interleave(depths.shape[1] * depths.shape[2])
        for label, kwargs in SETTINGS:
            g = (
                g_all
                if kwargs is None
                else prune_gaussians(g_all, view_index, depths, cams, **kwargs)[0]
            )
            acc[label]["n"].append(len(g))
            for t in sc.target_indices:
                times = []
                with torch.no_grad():
                    for _ in range(args.repeats):
                        t0 = time.perf_counter()
                        rgb = render(g, sc.cameras[t]).rgb
                        times.append((time.perf_counter() - t0) * 1e3)
                acc[label]["ms"].append(statistics.median(times))
                acc[label]["psnr"].append(float(psnr(rgb.clamp(0, 1), sc.images[t])))
    rows = []
    base = statistics.mean(acc["unpruned"]["psnr"])
    print("| budget | Gaussians (mean) | PSNR | Δ PSNR vs unpruned | render ms/view (median) |")
    print("|---|---:|---:|---:|---:|")
    for label, _ in SETTINGS:
        a = acc[label]
        row = dict(
            budget=label,
            gaussians=statistics.mean(a["n"]),
            psnr=statistics.mean(a["psnr"]),
            render_ms=statistics.median(a["ms"]),
        )
        rows.append(row)
        print(
            f"| {label} | {row['gaussians']:.0f} | {row['psnr']:.2f} | {row['psnr'] - base:+.2f} | "
            f"{row['render_ms']:.1f} |"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "budget.json").write_text(json.dumps(rows, indent=1))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot([r["gaussians"] for r in rows], [r["psnr"] for r in rows], "o-")
    for r in rows:
        ax.annotate(
            f"{r['budget']} ({r['render_ms']:.0f} ms)", (r["gaussians"], r["psnr"]), fontsize=8
        )
    ax.set_xlabel("Gaussians per scene")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title("Gaussian budget: count vs quality (render ms/view)")
    fig.tight_layout()
    fig.savefig(args.out / "budget.png", dpi=120)


if __name__ == "__main__":
    main()
