"""Torch thread count against Render View time on a busy CPU: the measurement behind the
worker's automatic thread count (``prosplat.worker.threads``).

Each (threads, OpenMP wait policy, load) runs in its own subprocess, since the wait policy is
read once when OpenMP starts. "busy" adds one spinning process per CPU core / 2 (at least 1)
beside whatever else the machine runs. Times are the medians of --repeats warm 128-px render
jobs (rasterize + enhance, ``run_task("render")``), the model already loaded.

    python benchmarks/worker_threads.py [--repeats 8] [--out out/bench]

Prints a Markdown table and writes ``worker_threads.json`` / ``.md`` to --out.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

CHILD = r"""
import json, statistics, sys, time
import torch
sys.path[:0] = [sys.argv[1], sys.argv[1] + "/tests", sys.argv[1] + "/benchmarks"]
from bench_scene import render_params
from prosplat.worker import run_task
threads, repeats, scene = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
default = torch.get_num_threads()
if threads > 0:
    torch.set_num_threads(threads)
params = render_params(scene)
run_task("render", params)  # load the model
times = []
for _ in range(repeats):
    t = time.perf_counter()
    run_task("render", params)
    times.append(time.perf_counter() - t)
print(json.dumps({"threads": torch.get_num_threads(), "default": default, "times": times}))
"""


def _spinners(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = ap.parse_args()
    from bench_scene import ensure_scene

    from prosplat.worker.threads import physical_cores

    scene = ensure_scene(args.out / "scene128")
    cores = physical_cores()
    rows = []
    for load in ("busy", "idle"):
        for policy in ("ACTIVE", "PASSIVE"):
            for threads in sorted({1, 2, 0, min(4, cores)}):
                spin = _spinners(max(1, cores // 2)) if load == "busy" else []
                try:
                    env = {**os.environ, "OMP_WAIT_POLICY": policy}
                    out = subprocess.run(
                        [sys.executable, "-c", CHILD, str(ROOT), str(threads), str(args.repeats),
                         str(scene)],
                        env=env, capture_output=True, text=True, check=True,
                    )  # fmt: skip
                finally:
                    for p in spin:
                        p.kill()
                        p.wait()
                res = json.loads(out.stdout.strip().splitlines()[-1])
                label = f"{res['threads']}" + (" (torch default)" if threads == 0 else "")
                rows.append({"load": load, "omp_wait_policy": policy, "threads": label,
                             "median_s": statistics.median(res["times"]),
                             "min_s": min(res["times"]), "max_s": max(res["times"])})  # fmt: skip
                r = rows[-1]
                print(f"| {load} | {policy} | {label} | {r['median_s']:.3f} | {r['min_s']:.3f} "
                      f"| {r['max_s']:.3f} |", flush=True)  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"cpu_count": os.cpu_count(), "physical_cores": cores, "repeats": args.repeats,
            "time": time.strftime("%Y-%m-%d %H:%M"), "loadavg": os.getloadavg()}  # fmt: skip
    (args.out / "worker_threads.json").write_text(
        json.dumps({"meta": meta, "rows": rows}, indent=1)
    )
    lines = [
        "| load | OMP_WAIT_POLICY | threads | median s | min s | max s |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {r['load']} | {r['omp_wait_policy']} | {r['threads']} | {r['median_s']:.3f} "
              f"| {r['min_s']:.3f} | {r['max_s']:.3f} |" for r in rows]  # fmt: skip
    (args.out / "worker_threads.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
