"""Scene rendering benchmark: Cycles seconds per view and disk size per scene.

Renders one scene of each family (three consecutive seeds) at each size with ``prosplat scenes
render`` and reports the median seconds per view (colour + depth renders and file writes; the
scene build is excluded and shown separately) and the folder size. Each ``--denoiser`` is one
configuration (``none``: no denoising; ``high`` / ``fast``: ``--denoise`` with that
``--denoise-quality``); with several, every round renders the same scenes with each in turn,
so they see the same machine load, and the table ends with each one's per-view time as a
ratio to the first's, paired by scene and round.

    python benchmarks/scenes.py [--sizes 128 256] [--seed 950000]
    python benchmarks/scenes.py --sizes 128 --samples 8 --inputs 6 --targets 10 \
        --denoiser high fast --repeats 2 --threads 1      # the training set's settings

Prints Markdown tables; writes ``scenes.json`` to --out.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def render_args(denoiser: str) -> list[str]:
    return [] if denoiser == "none" else ["--denoise", "--denoise-quality", denoiser]


def render(args: argparse.Namespace, size: int, denoiser: str, out: Path) -> None:
    """The benchmark's three scenes at ``size`` with ``denoiser``, into ``out``."""
    cmd = [sys.executable, "-m", "prosplat", "scenes", "render"]
    cmd += ["--seed", str(args.seed), "--count", "3", "--out", str(out)]
    cmd += ["--size", str(size), "--samples", str(args.samples), "--workers", "1"]
    cmd += ["--inputs", str(args.inputs), "--targets", str(args.targets)]
    cmd += ["--threads", str(args.threads)] if args.threads else []
    subprocess.run(cmd + render_args(denoiser), check=True)


def scene_rows(data: Path, **labels) -> list[dict]:
    """One row per scene folder of ``data``: its timings (from transforms.json) and size."""
    rows = []
    for folder in sorted(data.iterdir()):
        meta = json.loads((folder / "transforms.json").read_text())
        r = meta["renderer"]
        rows.append(
            dict(
                **labels,
                scene=folder.name,
                views=len(r["view_seconds"]),
                s_per_view=statistics.median(r["view_seconds"]),
                build_s=r["build_seconds"],
                total_s=r["seconds"],
                mb=folder_bytes(folder) / 2**20,
                overlap=meta["mean_input_overlap"],
            )
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 256])
    ap.add_argument(
        "--seed",
        type=int,
        default=950_000,
        help="first seed; three consecutive seeds = three families",
    )
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--inputs", type=int, default=4)
    ap.add_argument("--targets", type=int, default=8)
    ap.add_argument("--denoiser", nargs="+", choices=("none", "high", "fast"), default=["none"])
    ap.add_argument("--repeats", type=int, default=1, help="rounds over every denoiser")
    ap.add_argument("--threads", type=int, default=None, help="Cycles threads (default: all)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            for rnd in range(args.repeats):
                for denoiser in args.denoiser:
                    data = Path(tmp) / f"s{size}_r{rnd}_{denoiser}"
                    render(args, size, denoiser, data)
                    rows += scene_rows(data, size=size, round=rnd, denoiser=denoiser)
    views = args.inputs + args.targets
    print(f"\nCycles CPU, {args.samples} samples, {views} views per scene\n")
    print(
        "| size | denoiser | scene | s/view (median) | build s | scene total s | MB/scene "
        "| mean input overlap |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['size']}² | {r['denoiser']} | {r['scene']} | {r['s_per_view']:.2f} | "
            f"{r['build_s']:.2f} | {r['total_s']:.1f} | {r['mb']:.2f} | {r['overlap']:.2f} |"
        )
    print("\n| size | denoiser | s/view (median) | scene total s (median) | × the first |")
    print("|---|---|---:|---:|---:|")
    first = args.denoiser[0]
    for size in args.sizes:
        base = {
            (r["round"], r["scene"]): r
            for r in rows
            if r["size"] == size and r["denoiser"] == first
        }
        for denoiser in args.denoiser:
            sub = [r for r in rows if r["size"] == size and r["denoiser"] == denoiser]
            ratio = statistics.median(
                r["s_per_view"] / base[(r["round"], r["scene"])]["s_per_view"] for r in sub
            )
            print(
                f"| {size}² | {denoiser} | {statistics.median(r['s_per_view'] for r in sub):.2f} | "
                f"{statistics.median(r['total_s'] for r in sub):.1f} | {ratio:.2f} |"
            )
    (args.out / "scenes.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
