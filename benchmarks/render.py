"""Rasterizer benchmark: fast CPU path against the brute-force twin, forward and backward.

Scenes are laid out like a feed-forward generator's output: pixel-aligned Gaussians
unprojected from two depth maps (``prosplat.eval.demo_scene``), rendered from a camera between
the two inputs. Each (size, path, mode) runs in its own subprocess so its peak memory
(peak RSS above the RSS once the scene is built) is its own. Times are medians of --repeats.

    python benchmarks/render.py [--repeats 5] [--out out/bench]

Prints a Markdown table and writes ``render.json`` and ``render.png`` to --out.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

# (label, render size, input depth-map size (W, H)): N = 2 x W x H Gaussians.
CONFIGS = [("64²/4K", 64, (64, 32)), ("256²/131K", 256, (256, 256)), ("512²/524K", 512, (512, 512))]
TWIN_MAX_PAIRS = 5e7  # the dense twin holds pixels x Gaussians per tensor


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def child(size: int, inputs: tuple[int, int], path: str, mode: str, repeats: int) -> dict:
    import torch

    from prosplat import Gaussians, render
    from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
    from prosplat.render.reference import render_reference

    w, h = inputs
    g = pixel_aligned_gaussians(orbit_cameras(2, w, h))
    target = orbit_cameras(3, size, size)[1]
    params = [t.clone().requires_grad_(mode == "fwd+bwd") for t in g.tensors().values()]

    def run():
        gg = Gaussians(*params)
        if path == "fast":
            out = render(gg, target)
            rgb, alpha, depth = out.rgb, out.alpha, out.depth
        else:
            rgb, alpha, depth = render_reference(gg, target)
        if mode == "fwd+bwd":
            (rgb.sum() + alpha.sum() + 0.1 * depth.sum()).backward()
        return rgb.detach()

    base = _rss_bytes()
    times = []
    for i in range(repeats + 1):  # the first run warms up (kernel load, allocator)
        t0 = time.perf_counter()
        with torch.set_grad_enabled(mode == "fwd+bwd"):
            rgb = run()
        if i:
            times.append(time.perf_counter() - t0)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - base
    torch.save(rgb, f"/tmp/prosplat_bench_{size}_{path}_{mode}.pt")
    return {
        "n": len(g),
        "median_s": statistics.median(times),
        "times": times,
        "peak_mb": peak / 2**20,
    }


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        spec = json.loads(args.child)
        print(
            json.dumps(
                child(spec["size"], tuple(spec["inputs"]), spec["path"], spec["mode"], args.repeats)
            )
        )
        return

    import torch

    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for label, size, inputs in CONFIGS:
        n = 2 * inputs[0] * inputs[1]
        for path in ("fast", "twin"):
            for mode in ("fwd", "fwd+bwd"):
                if path == "twin" and n * size * size > TWIN_MAX_PAIRS:
                    rows.append(
                        dict(config=label, path=path, mode=mode, n=n, median_s=None, peak_mb=None)
                    )
                    continue
                spec = json.dumps(dict(size=size, inputs=inputs, path=path, mode=mode))
                res = subprocess.run(
                    [sys.executable, __file__, "--repeats", str(args.repeats), "--child", spec],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                r = json.loads(res.stdout.strip().splitlines()[-1])
                rows.append(dict(config=label, path=path, mode=mode, **r))
                print(
                    f"{label:>10} {path:>4} {mode:>7}: {r['median_s'] * 1e3:9.1f} ms  peak {r['peak_mb']:7.1f} MB",
                    file=sys.stderr,
                )
        fast = Path(f"/tmp/prosplat_bench_{size}_fast_fwd.pt")
        twin = Path(f"/tmp/prosplat_bench_{size}_twin_fwd.pt")
        if fast.exists() and twin.exists():
            diff = (torch.load(fast) - torch.load(twin)).abs().max().item()
            print(f"{label}: max |fast - twin| on rgb = {diff:.2e}", file=sys.stderr)
            for r in rows:
                if r["config"] == label:
                    r["max_abs_diff_vs_twin"] = diff

    from prosplat.eval.bench.machine import cpu_name

    machine = f"{cpu_name()}, {torch.get_num_threads()} threads, torch {torch.__version__}"
    print(f"\nMachine: {machine}; median of {args.repeats} runs\n")
    print("| config | path | fwd ms | fwd+bwd ms | fwd peak MB | fwd+bwd peak MB |")
    print("|---|---|---:|---:|---:|---:|")
    fmt = lambda v, s="{:.1f}": "—" if v is None else s.format(v)  # noqa: E731
    for label, _, _ in CONFIGS:
        for path in ("fast", "twin"):
            f = next(
                r for r in rows if r["config"] == label and r["path"] == path and r["mode"] == "fwd"
            )
            b = next(
                r
                for r in rows
                if r["config"] == label and r["path"] == path and r["mode"] == "fwd+bwd"
            )
            ms = lambda r: None if r["median_s"] is None else r["median_s"] * 1e3  # noqa: E731
            print(
                f"| {label} | {path} | {fmt(ms(f))} | {fmt(ms(b))} | {fmt(f['peak_mb'])} | {fmt(b['peak_mb'])} |"
            )
    (args.out / "render.json").write_text(json.dumps(dict(machine=machine, rows=rows), indent=1))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    labels = [c[0] for c in CONFIGS]
    for k, (path, mode) in enumerate(
        [("fast", "fwd"), ("fast", "fwd+bwd"), ("twin", "fwd"), ("twin", "fwd+bwd")]
    ):
        vals = [
            next(r for r in rows if r["config"] == lab and r["path"] == path and r["mode"] == mode)[
                "median_s"
            ]
            for lab in labels
        ]
        xs = [i + (k - 1.5) * 0.2 for i in range(len(labels))]
        ax.bar(xs, [v * 1e3 if v else 0 for v in vals], width=0.2, label=f"{path} {mode}")
    ax.set_xticks(range(len(labels)), labels)
    ax.set_yscale("log")
    ax.set_ylabel("ms (median)")
    ax.set_title("prosplat.render on CPU: fast path vs brute-force twin")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "render.png", dpi=120)
    print(f"\nwrote {args.out / 'render.json'} and {args.out / 'render.png'}", file=sys.stderr)


if __name__ == "__main__":
    main()
