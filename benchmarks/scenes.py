"""Scene rendering benchmark: Cycles seconds per view and disk size per scene.

Renders one scene of each family (test-split seeds) at each size with the defaults of
``prosplat scenes render`` (4 inputs + 8 targets, 32 samples, no denoising), one worker so
Cycles has every core, and reports the median seconds per view (colour + depth renders and
file writes; scene build excluded and shown separately) and the folder size.

    python benchmarks/scenes.py [--sizes 128 256] [--seed 950000]

Prints a Markdown table; writes ``scenes.json`` to --out.
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
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            data = Path(tmp) / f"s{size}"
            cmd = [
                sys.executable,
                "-m",
                "prosplat",
                "scenes",
                "render",
                "--seed",
                str(args.seed),
                "--count",
                "3",
                "--out",
                str(data),
                "--size",
                str(size),
                "--samples",
                str(args.samples),
                "--workers",
                "1",
            ]
            subprocess.run(cmd, check=True)
            for folder in sorted(data.iterdir()):
                meta = json.loads((folder / "transforms.json").read_text())
                r = meta["renderer"]
                rows.append(
                    dict(
                        size=size,
                        scene=folder.name,
                        family=meta["family"],
                        views=len(r["view_seconds"]),
                        s_per_view=statistics.median(r["view_seconds"]),
                        build_s=r["build_seconds"],
                        total_s=r["seconds"],
                        mb=folder_bytes(folder) / 2**20,
                        overlap=meta["mean_input_overlap"],
                    )
                )
    print(f"\nCycles CPU, {args.samples} samples, 4 inputs + 8 targets per scene\n")
    print(
        "| size | scene | s/view (median) | build s | scene total s | MB/scene | mean input overlap |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['size']}² | {r['scene']} | {r['s_per_view']:.2f} | {r['build_s']:.2f} | "
            f"{r['total_s']:.1f} | {r['mb']:.2f} | {r['overlap']:.2f} |"
        )
    for size in args.sizes:
        sub = [r for r in rows if r["size"] == size]
        print(
            f"| {size}² | **median of {len(sub)}** | {statistics.median(r['s_per_view'] for r in sub):.2f} | | "
            f"{statistics.median(r['total_s'] for r in sub):.1f} | {statistics.median(r['mb'] for r in sub):.2f} | |"
        )
    (args.out / "scenes.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
