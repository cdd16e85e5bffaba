"""Speed at the sizes artists render: reconstruction of 4 inputs, a warm raw view and an
enhanced view at 512 px, and a raw and an enhanced view at 1920x1080, against issue 70's
targets; medians of ``--repeats`` runs after one warm-up, peak memory, the machine named.

    python benchmarks/artist_speed.py --scene data/test512/open_950000 --repeats 5
    python benchmarks/artist_speed.py --repeats 3      # the built-in analytic scene instead
    python benchmarks/artist_speed.py --scene data/test960/open_950102 --size 544  # ~2M Gaussians

The 1080p camera is the first target's, with its focal length and principal point scaled to
1920x1080 (a wider view of the same scene). The views are what ``ProSplat.render`` returns:
raw views with their holes filled, enhanced views with stage 2 (the shipped models).
Writes ``--out``/speed.json and speed.png (median seconds against the targets).
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import time
from pathlib import Path

import torch

#: issue 70's targets, seconds, by step ("SIZE" is the input height: 512 px in the issue; a
#: 960x540 scene at 544 gives the 1080p views the "up to 2M Gaussians" of its 1080p target)
TARGETS = {
    "reconstruct 4 inputs, SIZE px": 6.0,
    "raw view, SIZE px (warm)": 0.3,
    "enhanced view, SIZE px": 1.5,
    "raw view, 1920x1080": 1.5,
    "enhanced view, 1920x1080": 4.0,
}


def machine() -> str:
    """The CPU's name and core count, as BENCHMARKS.md names machines."""
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, {torch.get_num_threads()} torch threads"


def scene_views(scene: str | None, size: int):
    """(input images [4,3,H,W], input cameras, target camera, near, far) at ``size`` px high:
    a scene folder's first 4 inputs and first target, or the analytic scene's orbit."""
    from prosplat.data.scene import resize_views

    if scene is None:
        from prosplat import render
        from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians

        cams = orbit_cameras(5, size, size, arc_deg=50.0)
        truth = pixel_aligned_gaussians(orbit_cameras(9, size, size, arc_deg=60.0))
        images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
        ins = [0, 1, 3, 4]
        return images[ins], [cams[i] for i in ins], cams[2], None, None
    from prosplat.data import load_scene

    sc = load_scene(scene)
    ins = sc.input_indices[:4]
    images, cams = resize_views(sc.images[ins], [sc.cameras[i] for i in ins], size)
    target = sc.cameras[sc.target_indices[0]]
    target = target.resized(round(target.width * size / target.height), size)
    return images, cams, target, float(sc.near[ins].min()), float(sc.far[ins].max())


def hd(camera, width: int = 1920, height: int = 1080):
    """``camera`` at ``width`` x ``height``: focal length scaled with the width, principal
    point at the centre (the same eye and direction, a wider or narrower field)."""
    from prosplat.core.camera import Camera

    k = camera.K.clone()
    s = width / camera.width
    k[0, 0], k[1, 1] = k[0, 0] * s, k[1, 1] * s
    k[0, 2], k[1, 2] = width / 2, height / 2
    return Camera(k, camera.world_to_cam, width, height)


def timed(fn, repeats: int) -> tuple[float, object]:
    """Median seconds of ``repeats`` calls of ``fn`` after one warm-up, and its last result."""
    out = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def measure(scene: str | None, size: int, repeats: int) -> dict:
    from prosplat import ProSplat

    model = ProSplat.from_pretrained()
    images, cams, target, near, far = scene_views(scene, size)
    rows = {}
    rows["reconstruct 4 inputs, SIZE px"], rec = timed(
        lambda: model.reconstruct(images, cams, near, far), repeats
    )
    big = hd(target)
    for cam, label in ((target, "SIZE px"), (big, "1920x1080")):
        raw_label = f"raw view, {label}" + (" (warm)" if cam is target else "")
        rows[raw_label], _ = timed(
            lambda c=cam: model.render(rec, c, images, cams, enhance=False, fill_holes=True),
            repeats,
        )
        rows[f"enhanced view, {label}"], _ = timed(
            lambda c=cam: model.render(rec, c, images, cams, fill_holes=True), repeats
        )
    return {
        "machine": machine(),
        "scene": scene or "analytic orbit scene",
        "size": list(images.shape[-2:]),
        "gaussians": len(rec.gaussians),
        "repeats": repeats,
        "seconds": rows,
        "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
    }


def table(result: dict) -> str:
    lines = [
        f"{result['scene']} at {result['size'][1]}x{result['size'][0]}, "
        f"{result['gaussians']:,} Gaussians; {result['machine']}; median of "
        f"{result['repeats']} runs; peak memory {result['peak_rss_gb']:.2f} GB",
        "",
        "| step | median s | target s | met |",
        "|---|---:|---:|---|",
    ]
    size = str(result["size"][0])
    for name, s in result["seconds"].items():
        goal = TARGETS[name]
        name = name.replace("SIZE", size)
        lines.append(f"| {name} | {s:.2f} | {goal:g} | {'yes' if s <= goal else 'no'} |")
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["seconds"])
    labels = [n.replace("SIZE", str(result["size"][0])) for n in names]
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.barh(labels, [result["seconds"][n] for n in names], label="median")
    ax.scatter([TARGETS[n] for n in names], labels, color="k", marker="|", s=200, label="target")
    ax.set_xlabel("seconds")
    ax.invert_yaxis()
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=None, help="a scene folder (default: analytic)")
    parser.add_argument("--size", type=int, default=512, help="input height in px (512)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per step (5)")
    parser.add_argument("--out", type=Path, default=Path("runs/artist_speed"))
    args = parser.parse_args(argv)
    result = measure(args.scene, args.size, args.repeats)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "speed.json").write_text(json.dumps(result, indent=1))
    plot(result, args.out / "speed.png")
    print(table(result))
    return result


if __name__ == "__main__":
    main()
