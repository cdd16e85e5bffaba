"""The ``prosplat`` command line. Each subcommand documents itself (``prosplat CMD --help``)."""

from __future__ import annotations

import argparse
import sys

from prosplat.cli import bench, demo_command, poses, reconstruct, scenes, train
from prosplat.cli import eval as eval_command  # not the builtin


def build_parser() -> argparse.ArgumentParser:
    """Every subcommand's parser, each made by the module that holds its handler."""
    parser = argparse.ArgumentParser(prog="prosplat", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo_command.add_parser(sub)
    scenes.add_parser(sub)
    train.add_parser(sub)
    bench.add_parser(sub)
    rc = sub.add_parser(
        "reconstruct",
        help="your own posed images (transforms.json, COLMAP), or photos / a video without "
        "poses -> Gaussians + enhanced renders",
        description=reconstruct.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    reconstruct.add_arguments(rc)
    rc.set_defaults(func=reconstruct.run)
    eval_command.add_parser(sub)
    poses.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    try:
        code = args.func(args)
    except KeyboardInterrupt:
        # every command writes its output aside and moves it into place when done
        # (prosplat.core.paths.staged_folder), so stopping leaves nothing half-written
        print(
            f"prosplat {args.command}: interrupted; nothing half-written was left", file=sys.stderr
        )
        code = 130
    sys.exit(code)
