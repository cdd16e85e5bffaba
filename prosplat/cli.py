"""The ``prosplat`` command line. Each subcommand documents itself (``prosplat CMD --help``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _fresh_folder(path: Path, overwrite: bool) -> Path:
    """``path`` if it is new, empty, or ``overwrite``; otherwise the first free ``path-N``.

    Earlier results are never clobbered by a re-run unless the user asks.
    """
    if overwrite or not path.exists() or not any(path.iterdir()):
        return path
    k = 2
    while (candidate := path.with_name(f"{path.name}-{k}")).exists() and any(candidate.iterdir()):
        k += 1
    return candidate


def cmd_demo(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from prosplat import render
    from prosplat.demo_scene import demo_scene, orbit_cameras
    from prosplat.image_io import write_image

    out = _fresh_folder(args.out, args.overwrite)
    out.mkdir(parents=True, exist_ok=True)
    gaussians, inputs = demo_scene(args.size, n_inputs=2)
    print(
        f"demo scene: {len(gaussians):,} pixel-aligned Gaussians from {len(inputs)} input views "
        f"at {args.size}x{args.size}"
    )
    cams = orbit_cameras(args.views, args.size, args.size, arc_deg=70.0)
    with torch.no_grad():
        for i, cam in enumerate(tqdm(cams, desc="rendering orbit", unit="view")):
            result = render(gaussians, cam, background=torch.tensor([1.0, 1.0, 1.0]))
            write_image(out / f"view_{i:03d}.png", result.rgb, overwrite=args.overwrite)
            depth = result.depth / result.depth.max().clamp_min(1e-6)
            write_image(out / f"depth_{i:03d}.png", depth, overwrite=args.overwrite)
    print(f"wrote {len(cams)} views and depth maps to {out.resolve()}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="prosplat", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser(
        "demo",
        help="render the built-in Gaussian scene along an orbit of cameras",
        description="Render the built-in analytic Gaussian scene along an orbit into --out "
        "(a new out-N folder if --out already has results, unless --overwrite).",
    )
    demo.add_argument(
        "--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)"
    )
    demo.add_argument("--size", type=int, default=128, help="image size in pixels (default 128)")
    demo.add_argument("--views", type=int, default=24, help="number of orbit views (default 24)")
    demo.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")
    demo.set_defaults(func=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    if getattr(args, "size", 1) < 1 or getattr(args, "views", 1) < 1:
        print("prosplat: --size and --views must be positive", file=sys.stderr)
        sys.exit(2)
    sys.exit(args.func(args))
