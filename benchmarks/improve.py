"""Stage-2 speed: milliseconds per enhanced view and peak memory, fp32 against bf16 autocast.

    python benchmarks/improve.py --size 256 --repeats 7

Each (size, dtype) runs in its own process so its peak resident memory (ru_maxrss) is its
own; the table prints the median of ``--repeats`` timed runs after two warm-ups and the
bf16/fp32 ratio of medians from the same invocation. Speed does not depend on the weights,
so the model is the ``tiny`` preset (the shipped file if present, else random).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import torch


def measure(size: int, dtype_name: str, repeats: int, reference: bool) -> dict:
    from prosplat.improve.config import TINY
    from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS, load_improver
    from prosplat.improve.model import ImproveModel

    torch.manual_seed(0)
    if DEFAULT_IMPROVE_WEIGHTS.is_file():
        model = load_improver(DEFAULT_IMPROVE_WEIGHTS)
    else:
        model = ImproveModel(TINY)
    if not reference:
        model = ImproveModel(model.config.with_(reference=False))
    model.eval()
    dtype = {"fp32": torch.float32, "bf16": torch.bfloat16}[dtype_name]
    x, ref = torch.rand(1, 3, size, size), torch.rand(1, 3, size, size)
    fund = torch.tensor([[[0.0, -1e-3, 0.1], [1e-3, 0.0, -0.2], [-0.1, 0.2, 0.0]]])
    times = []
    with torch.no_grad(), torch.autocast("cpu", dtype=dtype, enabled=dtype != torch.float32):
        for i in range(repeats + 2):
            t0 = time.perf_counter()
            out = model(x, ref if reference else None, fund if reference else None)
            if i >= 2:
                times.append((time.perf_counter() - t0) * 1e3)
    assert torch.isfinite(out).all()
    return {
        "size": size,
        "dtype": dtype_name,
        "reference": reference,
        "ms_median": statistics.median(times),
        "ms_min": min(times),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "threads": torch.get_num_threads(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, nargs="+", default=[256])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--one", nargs=3, metavar=("SIZE", "DTYPE", "REF"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        size, dtype, ref = args.one
        print(json.dumps(measure(int(size), dtype, args.repeats, ref == "1")))
        return
    rows = []
    for size in args.size:
        for ref in ("1", "0"):
            for dtype in ("fp32", "bf16"):
                cmd = [
                    sys.executable,
                    __file__,
                    "--one",
                    str(size),
                    dtype,
                    ref,
                    "--repeats",
                    str(args.repeats),
                ]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
                rows.append(json.loads(out.strip().splitlines()[-1]))
    print(
        "| size | MORI+DWEA | dtype | ms/view (median) | ms/view (min) | peak RSS MB | bf16/fp32 |"
    )
    print("|---:|---|---|---:|---:|---:|---:|")
    for r in rows:
        fp32 = next(
            o["ms_median"] for o in rows
            if (o["size"], o["reference"], o["dtype"]) == (r["size"], r["reference"], "fp32")
        )  # fmt: skip
        print(
            f"| {r['size']} | {'on' if r['reference'] else 'off'} | {r['dtype']} | "
            f"{r['ms_median']:.1f} | {r['ms_min']:.1f} | {r['peak_rss_mb']:.0f} | "
            f"{r['ms_median'] / fp32:.2f} |"
        )


if __name__ == "__main__":
    main()
