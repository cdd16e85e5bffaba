"""Score stage-2 weights on the no-pattern test's probe views before shipping them.

``tests/test_stage2_no_pattern.py`` holds only the shipped weights to its bars (pattern < 3,
8- and 16-px lattice < 1.5); this prints the same figures for any candidates, side by side.

    python benchmarks/stage2_pattern.py runs/s2v9/run/improve.safetensors [more ...]
    python benchmarks/stage2_pattern.py --shipped runs/...   (the shipped weights first)
"""

from __future__ import annotations

import argparse

import torch

from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS, load_improver
from prosplat.improve.pattern_probe import PROBE_BARS, probe_changes, probe_scores


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("weights", nargs="*", help="stage-2 safetensors files")
    ap.add_argument("--shipped", action="store_true", help="score the shipped weights too")
    ap.add_argument("--views", type=int, default=64, help="probe views (the test: 64)")
    args = ap.parse_args()
    paths = ([str(DEFAULT_IMPROVE_WEIGHTS)] if args.shipped else []) + args.weights
    if not paths:
        ap.error("give weights files or --shipped")
    torch.set_grad_enabled(False)
    print(
        "| weights | mean change | pattern (< 3) | lattice 8 px (< 1.5) | lattice 16 px (< 1.5) |"
    )
    print("|---|---|---|---|---|")
    for path in [None, *paths]:  # None: the ideal change, the floor a perfect model scores
        model = None if path is None else load_improver(path).eval()
        s = probe_scores(probe_changes(model, views=args.views))
        passes = all(s[k] < bar for k, bar in PROBE_BARS.items())
        print(
            f"| {path or 'ideal (sharp - render)'}{'' if passes else ' (fails)'} | "
            f"{s['mean_change']:.4f} | "
            f"{s['pattern']:.2f} | {s['lattice8']:.2f} | {s['lattice16']:.2f} |"
        )


if __name__ == "__main__":
    main()
