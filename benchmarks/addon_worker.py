"""Render View in Blender, cold and warm, per place the work runs: the add-on's thread,
the session's long-lived external worker (``--serve``), and one external process per job
(the old behaviour, *Keep Worker Running* off).

Each run is a fresh Python with the ``bpy`` module (a fresh Blender session): it builds the
scene in Blender (input cameras with their images, the Gaussian object, a 128-px camera),
then calls ``bpy.ops.prosplat.render_view()`` --calls times. The first call is *cold* (torch
imported, models loaded, worker started: whatever the session has not done yet), the others
*warm*. Times are wall-clock around the operator, so they include reading the Gaussians
from the mesh, the job's files, rasterizing and enhancing, and loading the result into
Blender. Medians over --runs sessions (cold) and all warm calls (warm). ``--busy N`` keeps N
spinning processes beside it (the issue's "busy CPU").

    python benchmarks/addon_worker.py [--runs 3] [--calls 6] [--busy 1] [--out out/bench]

``--code DIR --label NAME`` runs another checkout's ``addon``/``prosplat`` instead (e.g. the
commit before the warm worker, from ``git archive COMMIT addon prosplat tests``): its rows
are the "before". Prints a Markdown table and writes ``addon_worker_busyN[_NAME].json`` /
``.md`` to --out.
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

from prosplat.eval.bench.machine import cpu_name

ROOT = Path(__file__).resolve().parents[1]
MODES = {
    "thread": "Blender's Python, a thread (models cached in-process)",
    "external": "external Python, one warm worker per session (--serve)",
    "external-per-job": "external Python, a new process per job (Keep Worker Running off)",
}


def child(mode: str, scene: Path, calls: int, threads: int, code: Path) -> list[float]:
    """One Blender session: build the scene, time ``calls`` Render View calls."""
    import bpy
    import numpy as np

    sys.path[:0] = [str(code), str(code / "tests")]
    from addon_support import reset_scene

    try:  # this layout; a checkout from before the core/blender split has them in addon/
        from addon.blender import cameras, pointcloud, runtime, steps
    except ImportError:
        from addon import cameras, pointcloud, runtime, steps

    prefs = runtime.Defaults()
    prefs.threads = threads  # attributes an older add-on does not know are simply unused
    if mode != "thread":
        prefs.python_path, prefs.keep_worker = sys.executable, mode == "external"
    runtime.prefs = lambda context=None: prefs
    blender = reset_scene()
    spec = json.loads((scene / "bench.json").read_text())
    frames = [{"name": f["name"], "image": f["image"], "blender": f["camera"]}
              for f in spec["inputs"]]  # fmt: skip
    inputs = steps.apply_posed_images({"frames": frames, "near": 0.5, "far": 10.0}, blender,
                                      "inputs", set_resolution=False)  # fmt: skip
    with np.load(scene / "gaussians.npz") as z:
        obj = pointcloud.create_object("Gaussians", {k: z[k] for k in z.files}, blender.collection)
    obj[pointcloud.INPUTS_PROP] = inputs.name
    cam = cameras.new_camera("target", spec["target"]["camera"], None, blender.collection, 10.0)
    blender.camera = cam
    cameras.set_scene_resolution(blender, spec["target"]["camera"])
    s = blender.prosplat
    s.gaussians, s.inputs, s.render_mode = obj, inputs, "ACTIVE"
    s.output_dir = str(scene / "renders" / mode)
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        res = bpy.ops.prosplat.render_view("EXEC_DEFAULT")
        times.append(time.perf_counter() - t)
        assert res == {"FINISHED"}, res
    jobs = sys.modules.get("addon.core.jobs") or sys.modules["addon.jobs"]
    if hasattr(jobs, "shutdown_workers"):
        jobs.shutdown_workers()
    return times


def _commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True).stdout.strip()  # fmt: skip
    except OSError:
        return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="fresh sessions per mode")
    ap.add_argument("--calls", type=int, default=6, help="Render View calls per session")
    ap.add_argument("--busy", type=int, default=0, help="spinning processes beside it")
    ap.add_argument("--threads", type=int, default=0, help="the CPU Threads preference")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    ap.add_argument("--code", type=Path, default=ROOT, help="checkout whose add-on runs")
    ap.add_argument("--label", default="", help="names the rows and files of --code")
    ap.add_argument("--child", nargs=2, metavar=("MODE", "SCENE"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        times = child(args.child[0], Path(args.child[1]), args.calls, args.threads, args.code)
        print(json.dumps(times))
        return
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_scene import ensure_scene

    scene = ensure_scene(args.out / "scene128")
    code = args.code.resolve()
    tag = f" ({args.label})" if args.label else ""
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    rows = []
    try:
        for mode in args.modes:
            colds, warms = [], []
            for _ in range(args.runs):
                out = subprocess.run(
                    [sys.executable, __file__, "--child", mode, str(scene), "--calls",
                     str(args.calls), "--threads", str(args.threads), "--code", str(code)],
                    capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(code)},
                )  # fmt: skip
                if out.returncode != 0:
                    raise SystemExit(f"{mode} failed:\n{out.stderr[-3000:]}")
                times = json.loads(out.stdout.strip().splitlines()[-1])
                colds.append(times[0])
                warms += times[1:]
            rows.append({"mode": mode, "what": MODES[mode] + tag, "cold_s": statistics.median(colds),
                         "warm_s": statistics.median(warms), "warm_max_s": max(warms),
                         "colds": colds, "warms": warms})  # fmt: skip
            r = rows[-1]
            print(f"{mode}: cold {r['cold_s']:.2f} s, warm {r['warm_s']:.2f} s", flush=True)
    finally:
        for p in spin:
            p.kill()
            p.wait()
    meta = {"cpu": cpu_name(), "cpu_count": os.cpu_count(), "busy": args.busy,
            "threads_pref": args.threads, "runs": args.runs, "calls": args.calls,
            "commit": args.label or _commit(), "time": time.strftime("%Y-%m-%d %H:%M"),
            "size": "128x128 target, 2 inputs of 128x128, enhanced (improve_tiny)"}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [f"Render View, 128 px, {meta['cpu_count']} CPUs ({meta['cpu']}), busy={args.busy}, "
             f"commit {meta['commit']}", "",
             "| where the work runs | cold s (median) | warm s (median) | warm max s |",
             "|---|---|---|---|"]  # fmt: skip
    lines += [f"| {r['what']} | {r['cold_s']:.2f} | {r['warm_s']:.2f} | {r['warm_max_s']:.2f} |"
              for r in rows]  # fmt: skip
    stem = f"addon_worker_busy{args.busy}" + (f"_{args.label}" if args.label else "")
    (args.out / f"{stem}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    (args.out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
