"""``prosplat demo``: the main job end to end on the built-in Blender demo scene.

The command's options and its summary line; the run itself (scene, reconstruction, enhanced
views, report) is :func:`prosplat.cli.demo.run_demo`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prosplat.cli.config_args import add_config_arguments, config_from_args
from prosplat.cli.demo import DENOISE_CHOICES, DemoConfig, run_demo
from prosplat.cli.options import add_refine_arguments


def cmd_demo(args: argparse.Namespace) -> int:
    cfg = config_from_args(DemoConfig, args)
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
    add_config_arguments(
        demo,
        DemoConfig,
        skip=("refine_steps", "refine_seconds"),
        extra={"out": {"type": Path}, "denoise": {"choices": DENOISE_CHOICES}},
    )
    add_refine_arguments(demo)
    demo.set_defaults(func=cmd_demo)
