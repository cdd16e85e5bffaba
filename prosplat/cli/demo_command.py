"""``prosplat demo``: the main job end to end on the built-in Blender demo scene.

The command's options and its summary line; the run itself (scene, reconstruction, enhanced
views, report) is :func:`prosplat.cli.demo.run_demo`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prosplat.cli.options import add_refine_arguments


def cmd_demo(args: argparse.Namespace) -> int:
    from prosplat.cli.demo import DemoConfig, run_demo

    cfg = DemoConfig(
        out=args.out,
        scene=args.scene,
        seed=args.seed,
        size=args.size,
        render_scale=args.render_scale,
        inputs=args.inputs,
        targets=args.targets,
        samples=args.samples,
        budget=args.budget,
        bf16=args.bf16,
        refine_steps=args.refine_steps,
        refine_seconds=args.refine_seconds,
        weights=args.weights,
        generator=args.generator,
        improve=args.improve,
        overwrite=args.overwrite,
    )
    try:
        cfg.check()
        result = run_demo(cfg)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"prosplat demo: {e}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:
        print(
            f"prosplat demo: {e.name} is missing; `make demo` installs everything "
            "(pip install -e '.[blender,bench]')",
            file=sys.stderr,
        )
        return 2
    from prosplat.cli.demo_report import summary_rows

    total = summary_rows(result.views)[-1]
    raw = "refined" if cfg.refine_steps or cfg.refine_seconds is not None else "generator"
    print(
        f"PSNR over {total['n']} new views: {raw} (holes filled) {total['psnr_raw']:.2f} dB -> "
        f"enhanced "
        f"{total['psnr_enhanced']:.2f} dB; LPIPS {total['lpips_raw']:.3f} -> "
        f"{total['lpips_enhanced']:.3f}; demo took {result.timings['total']:.0f} s"
    )
    print(f"report: {(result.out / 'report.md').resolve()}")
    return 0


def add_parser(sub) -> None:
    """``prosplat demo`` into the top-level subparsers ``sub``."""
    demo = sub.add_parser(
        "demo",
        help="the main job end to end on the built-in Blender demo scene",
        description="Build the demo scene in Blender, render its wide-baseline inputs and new "
        "target views, reconstruct Gaussians, render enhanced views and write side-by-side "
        "images, metrics and report.md into --out (a new out-N folder if --out already has "
        "results, unless --overwrite).",
    )
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="(default out/demo)")
    demo.add_argument("--scene", default="tabletop", help="scene family or hard scene name")
    demo.add_argument("--seed", type=int, default=950002, help="scene seed (default: a test one)")
    from prosplat.cli.demo import DEMO_SIZE
    from prosplat.pipeline.model import TRAINED_SIZE

    demo.add_argument(
        "--size",
        type=int,
        default=DEMO_SIZE,
        help=f"model resolution, multiple of 32 (default {DEMO_SIZE}, fast; the shipped "
        f"generator runs up to {TRAINED_SIZE})",
    )
    demo.add_argument(
        "--render-scale", type=int, default=2, help="Blender renders at size x this (default 2)"
    )
    demo.add_argument("--inputs", type=int, default=4, help="input views, 2-6 (default 4)")
    demo.add_argument("--targets", type=int, default=8, help="new target views (default 8)")
    demo.add_argument("--samples", type=int, default=16, help="Cycles samples (default 16)")
    demo.add_argument(
        "--budget",
        type=float,
        default=None,
        help="Gaussians to keep: a count or a fraction (default: automatic)",
    )
    demo.add_argument("--bf16", action="store_true", help="run stage 2 under bfloat16 autocast")
    demo.add_argument("--weights", default=None, help="generator checkpoint (default: shipped)")
    demo.add_argument(
        "--generator", default=None, help="a DepthSplat checkpoint (.pth) as stage 1 instead"
    )
    demo.add_argument("--improve", default=None, help="stage-2 checkpoint (default: shipped)")
    add_refine_arguments(demo)
    demo.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")
    demo.set_defaults(func=cmd_demo)
