"""Options several subcommands share: refinement's step count or time budget, and bounded
numbers."""

from __future__ import annotations

import argparse

from prosplat.pipeline.refine import RECOMMENDED_STEPS


def _between(cast, noun: str, lo, hi):
    """An argparse type: ``cast(text)`` (a ``noun``) in [lo, hi], refused with a one-line
    usage error."""

    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {noun}") from None
        if not lo <= value <= hi:  # NaN fails both comparisons
            raise argparse.ArgumentTypeError(
                f"must be {_shown(lo)}-{_shown(hi)}, got {_shown(value)}"
            )
        return value

    return parse


def _shown(x) -> str:
    """A bound or value as the user would write it: 0-1, not 0.0-1.0; 65536, not 65536.0."""
    return f"{x:g}" if isinstance(x, float) else str(x)


def int_between(lo: int, hi: int):
    """An argparse type: a whole number in [lo, hi]."""
    return _between(int, "a whole number", lo, hi)


def float_between(lo: float, hi: float):
    """An argparse type: a number in [lo, hi] (NaN refused)."""
    return _between(float, "a number", lo, hi)


def add_refine_arguments(parser: argparse.ArgumentParser, many: bool = False) -> None:
    """``--refine-steps`` / ``--refine-seconds``: fit the generator's Gaussians to the inputs
    (prosplat.pipeline.refine) for a step count or a time budget; ``many``: one row per value."""
    if many:
        parser.add_argument(
            "--refine-steps",
            type=int,
            nargs="*",
            default=[],
            help="add a 'generator+refine N' row per step count (refinement after the budget)",
        )
        parser.add_argument(
            "--refine-seconds",
            type=float,
            nargs="*",
            default=[],
            help="add a 'generator+refine Ss' row per time budget in seconds",
        )
        return
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--refine-steps",
        type=int,
        nargs="?",
        const=RECOMMENDED_STEPS,
        default=0,
        metavar="N",
        help="refine the Gaussians against the inputs for N steps after the budget (default 0: "
        f"off; the bare flag: {RECOMMENDED_STEPS}, the measured knee; README, 'Refinement')",
    )
    group.add_argument(
        "--refine-seconds",
        type=float,
        default=None,
        help="refine for this many seconds instead of a step count",
    )
