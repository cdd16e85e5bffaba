"""Two ladder runs on the same scenes, paired target by target: ``B − A`` per row, size and
view count, with a bootstrapped 95 % interval, and per scene type.

``prosplat eval ladder`` pairs rows against the paste within one run; a new generator is
scored in a run of its own (``--generator``), so its gain over the shipped one needs the two
runs' ``ladder.json`` paired here. Targets are matched by (size, views, row, scene, target);
the runs must have drawn the same inputs and targets (the same data and ``--seed``).

    python benchmarks/compare_ladders.py runs/eval_v7/ladder/ladder.json \\
        runs/eval_v8/ladder/ladder.json --rows generator enhanced

``--against ROW`` pairs every B row with A's row ROW instead of its namesake, so two rows of
one run pair too (the same file as A and B):

    python benchmarks/compare_ladders.py L.json L.json --rows "refine 100 enhanced" \\
        --against enhanced

``prosplat eval posed``'s ``scores.json`` pairs the same way (its methods are the rows, its
targets matched by order within each case; the "size" column is blank). With
``--input-sets`` each case is one choice of inputs, and the interval resamples whole cases
(its targets share their inputs, so they are not independent draws):

    python benchmarks/compare_ladders.py runs/eval_v7/fox/scores.json \\
        runs/eval_v8/fox/scores.json --rows enhanced "refined enhanced"
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

from prosplat.eval.ladder.stats import bootstrap_ci


def _scores(path: Path) -> dict[tuple, dict]:
    """(size, views, row, scene, target) -> score, from a ladder.json or an eval posed
    scores.json (size "", the target's order within its case, the case as its type)."""
    data = json.loads(path.read_text())
    if "targets" in data:  # prosplat eval posed
        seen: dict[tuple, int] = defaultdict(int)
        out = {}
        for s in data["targets"]:
            case = (s["views"], s["method"], s["scene"])
            out[("", s["views"], s["method"], s["scene"], seen[case])] = s | {
                "scene_type": s["scene"]
            }
            seen[case] += 1
        return out
    scores = data["scores"]
    return {(s["size"], s["views"], s["rung"], s["scene"], s["target"]): s for s in scores}


def _mean(run: dict[tuple, dict], keys: list[tuple], metric: str) -> float:
    return sum(run[k][metric] for k in keys) / len(keys)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a", type=Path, help="ladder.json of the reference run (A)")
    p.add_argument("b", type=Path, help="ladder.json of the run compared with it (B)")
    p.add_argument("--rows", nargs="+", default=["generator", "enhanced"])
    p.add_argument("--against", default=None, metavar="ROW",
                   help="pair every B row with this row of A (default: the row of that name)")  # fmt: skip
    args = p.parse_args(argv)
    a, b = _scores(args.a), _scores(args.b)
    if args.against is not None:  # A re-keyed so that its ROW stands for each B row
        a = {(*k[:2], row, *k[3:]): s for k, s in a.items() if k[2] == args.against
             for row in args.rows}  # fmt: skip
    common = sorted(k for k in a.keys() & b.keys() if k[2] in args.rows)
    if not common:
        raise SystemExit(f"no targets of rows {args.rows} in both {args.a} and {args.b}")
    groups: dict[tuple, list[tuple]] = defaultdict(list)
    for k in common:
        groups[k[:3]].append(k)
    print(f"B − A, paired on the same targets (A = {args.a}, B = {args.b})\n")
    print(
        "| size | views | row | n | A PSNR / LPIPS | B PSNR / LPIPS | Δ PSNR [95 %] | Δ LPIPS [95 %] |"
    )
    print("|---:|---:|---|---:|---:|---:|---:|---:|")
    by_type: dict[tuple, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for (size, views, row), keys in groups.items():
        d_psnr = [b[k]["psnr"] - a[k]["psnr"] for k in keys]
        # eval posed's cases are choices of inputs: resample them whole
        clusters = [k[3] for k in keys] if size == "" else None
        dp = bootstrap_ci(d_psnr, clusters=clusters)
        dl = bootstrap_ci([b[k]["lpips"] - a[k]["lpips"] for k in keys], clusters=clusters)
        print(
            f"| {size} | {views} | {row} | {len(keys)} | {_mean(a, keys, 'psnr'):.2f} / "
            f"{_mean(a, keys, 'lpips'):.3f} | {_mean(b, keys, 'psnr'):.2f} / "
            f"{_mean(b, keys, 'lpips'):.3f} | "
            f"{dp.mean:+.2f} [{dp.lo:+.2f}, {dp.hi:+.2f}] | "
            f"{dl.mean:+.3f} [{dl.lo:+.3f}, {dl.hi:+.3f}] |"
        )
        for k, d in zip(keys, d_psnr, strict=True):
            by_type[(size, views, row)][a[k]["scene_type"]].append(d)
    types = sorted({t for d in by_type.values() for t in d})
    print("\nΔ PSNR per scene type\n")
    print("| size | views | row | " + " | ".join(types) + " |")
    print("|---:|---:|---|" + "---:|" * len(types))
    for (size, views, row), d in by_type.items():
        cells = [f"{sum(d[t]) / len(d[t]):+.2f}" if d[t] else "–" for t in types]
        print(f"| {size} | {views} | {row} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
