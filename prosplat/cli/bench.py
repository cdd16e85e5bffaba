"""``prosplat bench points|hard``: speed against error, and the hard-case suite; the options
live beside their engines in :mod:`prosplat.eval.bench`."""

from __future__ import annotations

import argparse

from prosplat.eval.bench import hard, points


def add_parser(sub) -> None:
    """``prosplat bench ...`` into the top-level subparsers ``sub``."""
    bench = sub.add_parser("bench", help="speed against error, and the hard-case suite")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True)
    for name, module, text in (
        ("points", points, "time per view against PSNR/SSIM/LPIPS over operating points"),
        ("hard", hard, "the whole pipeline on hard cases: finite outputs or clear errors"),
    ):
        p = bench_sub.add_parser(name, help=text, description=module.__doc__)
        p.formatter_class = argparse.RawDescriptionHelpFormatter
        module.add_arguments(p)
        p.set_defaults(func=module.run)
