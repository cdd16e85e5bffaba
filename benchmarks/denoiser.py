"""Cycles' denoiser settings for training renders: seconds per colour render against the
image's distance from a many-sample render of the same view.

For each scene (a family or hard scene and a seed, built as ``prosplat scenes render`` builds
it) and each of its first ``--views`` input cameras, renders a reference with
``--reference-samples`` samples and the default denoiser, then the view at ``--samples``
samples with each setting ``PREFILTER/QUALITY`` (Cycles' ``denoising_prefilter`` and
``denoising_quality``), ``--repeats`` times in turn so every setting sees the same machine
load. Prints the median seconds of a colour render and the PSNR against the reference (dB,
8-bit PNGs as the data set stores them) per scene and setting. Runs in the project's Python
with bpy:

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/denoiser.py --scenes room:10001 open:10000 \
        tabletop:10002 --threads 1
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from prosplat.camera import Camera  # noqa: E402
from scenes import render as R  # noqa: E402

DEFAULT_SETTINGS = ["ACCURATE/HIGH", "FAST/HIGH", "ACCURATE/BALANCED", "FAST/BALANCED", "FAST/FAST"]


def colour(png: Path, size: int) -> np.ndarray:
    """Render the scene camera's colour and read it back from an 8-bit PNG: [H, W, 3]."""
    sc = bpy.context.scene
    bpy.ops.render.render()
    bpy.data.images["Render Result"].save_render(filepath=str(png), scene=sc)
    img = bpy.data.images.load(str(png))
    px = np.array(img.pixels[:], dtype=np.float64).reshape(size, size, 4)[..., :3]
    bpy.data.images.remove(img)
    return px


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenes", nargs="+", default=["room:10001", "open:10000", "tabletop:10002"])
    ap.add_argument("--settings", nargs="+", default=DEFAULT_SETTINGS)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--reference-samples", type=int, default=256)
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    settings = [tuple(s.split("/")) for s in args.settings]
    print(
        f"| scene | setting | s / colour render (median) | PSNR vs {args.reference_samples} spp |"
    )
    print("|---|---|---:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        png = Path(tmp) / "view.png"
        for spec in args.scenes:
            name, seed = spec.split(":")
            info = R.build_scene(name, int(seed))
            rig = R.choose_rig(info.trajectory, 6, 10, int(seed))
            R.configure_render(args.size, args.samples, True, int(seed), args.threads)
            sc = bpy.context.scene
            fmt = sc.render.image_settings
            fmt.media_type, fmt.file_format, fmt.color_mode, fmt.color_depth = (
                "IMAGE", "PNG", "RGB", "8",
            )  # fmt: skip
            cam = bpy.data.objects.new("bench", bpy.data.cameras.new("bench"))
            sc.collection.objects.link(cam)
            sc.camera = cam
            sc.cycles.filter_width = 1.0
            fx = info.lens_mm / 36.0 * args.size
            seconds = {s: [] for s in settings}
            psnr = {s: [] for s in settings}
            for view in list(rig.inputs)[: args.views]:
                eye, look = info.trajectory[view]
                R._place_camera(cam, Camera.look_at(eye, look, R.SKY_UP, fx, args.size, args.size))
                sc.cycles.samples = args.reference_samples
                prefilter_quality = R.DENOISE_QUALITY["high"]  # the default denoiser
                sc.cycles.denoising_prefilter, sc.cycles.denoising_quality = prefilter_quality
                ref = colour(png, args.size)
                sc.cycles.samples = args.samples
                for rep in range(args.repeats):
                    for s in settings:
                        sc.cycles.denoising_prefilter, sc.cycles.denoising_quality = s
                        t0 = time.perf_counter()
                        img = colour(png, args.size)
                        seconds[s].append(time.perf_counter() - t0)
                        if rep == 0:
                            psnr[s].append(-10 * np.log10(((img - ref) ** 2).mean()))
            for s in settings:
                print(
                    f"| {name}_{int(seed):06d} | {'/'.join(s)} | {statistics.median(seconds[s]):.2f} "
                    f"| {' / '.join(f'{p:.1f}' for p in psnr[s])} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
