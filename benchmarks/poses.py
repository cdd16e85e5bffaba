"""Speed of the pose step (issue 69): seconds per phase of ``prosplat.poses.estimate_poses``.

For each photo count, an evenly spaced subset of ``--photos`` (default: the 50 photos of the
fox, 1080x1920) is posed from scratch (a fresh output folder, so no database is reused) at
each ``--feature-sizes`` (the longest side SIFT sees) and each ``--matching`` mode. Each run
records the seconds of every phase (prepare, extract, match, map, write), how many photos
were registered and the mean reprojection error; with ``--repeats N`` the medians of N runs
are reported. A run that fails (too few photos matched) is a row with its message. With
reference poses (``--reference``, default the ``transforms.json`` beside the photos' folder,
as the fox has) each run's cameras are aligned to them by a similarity transform of the
centres and the median rotation error (degrees) and centre error (% of the reference rig's
size) are reported too: the reference is another SfM's answer, not the truth, so these say
whether a setting agrees with it, to a fraction of a degree at best.

    nice python benchmarks/poses.py --counts 10 25 50 --feature-sizes 512 1024 --repeats 1

Prints a Markdown table and writes ``poses.json`` and ``poses.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap

from prosplat.pipeline.posed_views import load_posed_set
from prosplat.poses import PoseError, PoseOptions, estimate_poses, list_photos, quiet_colmap

ROOT = Path(__file__).resolve().parents[1]
PHASES = ("prepare", "extract", "match", "map", "write")


def subset(photos: list[Path], count: int) -> list[Path]:
    """``count`` photos evenly spaced over ``photos`` (all of them when there are fewer), in
    order: the first and the last always, the others as close to equal steps as indices allow."""
    if count >= len(photos):
        return list(photos)
    if count == 1:
        return [photos[0]]
    step = (len(photos) - 1) / (count - 1)
    return [photos[round(k * step)] for k in range(count)]


def reference_poses(path: Path) -> dict[str, np.ndarray]:
    """Camera-to-world [4, 4] (OpenCV axes) of each photo of a posed set, by file stem."""
    posed = load_posed_set(path, skip_missing=True)
    return {
        v.image.stem: np.linalg.inv(v.camera.world_to_cam.double().numpy()) for v in posed.views
    }


def similarity(a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama's least-squares (scale, rotation [3,3], translation [3]) taking points a [N,3]
    onto b [N,3]: b ≈ s·R·a + t."""
    ma, mb = a.mean(0), b.mean(0)
    da, db = a - ma, b - mb
    u, sig, vt = np.linalg.svd(db.T @ da / len(a))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rot = u @ d @ vt
    scale = float(np.trace(np.diag(sig) @ d) / (da**2).sum(1).mean())
    return scale, rot, mb - scale * rot @ ma


def pose_errors(est: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> dict | None:
    """Median rotation error (degrees) and centre error (% of the reference rig's largest
    centre-to-centre distance) of ``est`` after aligning its centres to ``ref``'s; None with
    fewer than 3 photos in common."""
    common = sorted(set(est) & set(ref))
    if len(common) < 3:
        return None
    a = np.stack([est[k][:3, 3] for k in common])
    b = np.stack([ref[k][:3, 3] for k in common])
    scale, rot, shift = similarity(a, b)
    moved = scale * a @ rot.T + shift
    rig = max(np.linalg.norm(b[:, None] - b[None], axis=-1).max(), 1e-12)
    angles = []
    for k in common:
        r = ref[k][:3, :3].T @ rot @ est[k][:3, :3]
        # ||r - I|| = 2√2·sin(θ/2): unlike arccos of the trace, exact near θ = 0
        half = np.linalg.norm(r - np.eye(3)) / (2 * np.sqrt(2))
        angles.append(np.degrees(2 * np.arcsin(min(half, 1.0))))
    return {
        "rotation_deg": float(np.median(angles)),
        "centre_pct": float(np.median(np.linalg.norm(moved - b, axis=1)) / rig * 100),
    }


def run_once(
    photos: list[Path], feature_size: int, matching: str, reference: dict | None = None
) -> dict:
    """Pose ``photos`` into a fresh temporary folder; the run's timings and result figures."""
    options = PoseOptions(feature_size=feature_size, matching=matching)
    with tempfile.TemporaryDirectory(prefix="prosplat-poses-bench-") as tmp:
        t0 = time.perf_counter()
        try:
            result = estimate_poses(photos, Path(tmp) / "poses", options)
        except PoseError as e:
            return {"seconds": {}, "total": time.perf_counter() - t0, "registered": 0,
                    "reprojection_error": None, "accuracy": None, "error": str(e)}  # fmt: skip
        total = time.perf_counter() - t0
    est = {
        Path(name).stem: np.linalg.inv(cam.world_to_cam.double().numpy())
        for name, cam in zip(result.names, result.cameras, strict=True)
    }
    return {
        "seconds": {p: float(result.timings.get(p, 0.0)) for p in PHASES},
        "total": total,
        "registered": len(result.names),
        "reprojection_error": float(result.reprojection_error),
        "accuracy": pose_errors(est, reference) if reference else None,
        "error": None,
    }


def _median_accuracy(runs: list[dict]) -> dict | None:
    found = [r["accuracy"] for r in runs if r.get("accuracy")]
    if not found:
        return None
    return {k: statistics.median(a[k] for a in found) for k in ("rotation_deg", "centre_pct")}


def summarise(runs: list[dict]) -> dict:
    """Medians over repeated runs of one setting (phases, total, registered, error); the
    first failure's message when every run failed."""
    ok = [r for r in runs if r["error"] is None]
    if not ok:
        return {"seconds": {}, "total": statistics.median(r["total"] for r in runs),
                "registered": 0, "reprojection_error": None, "accuracy": None,
                "error": runs[0]["error"]}  # fmt: skip
    return {
        "seconds": {p: statistics.median(r["seconds"][p] for r in ok) for p in PHASES},
        "total": statistics.median(r["total"] for r in ok),
        "registered": int(statistics.median(r["registered"] for r in ok)),
        "reprojection_error": statistics.median(r["reprojection_error"] for r in ok),
        "accuracy": _median_accuracy(ok),
        "error": None,
    }


def table(rows: list[dict]) -> str:
    """The Markdown table of summarised rows."""
    lines = [
        "| photos | feature px | matching | " + " | ".join(PHASES)
        + " | total s | registered | reproj. err px | rot. err ° | centre err % |",
        "|---:|---:|---|" + "---:|" * (len(PHASES) + 5),
    ]  # fmt: skip
    for r in rows:
        head = f"| {r['photos']} | {r['feature_size']} | {r['matching']} |"
        if r["error"] is not None:
            cells = " | ".join(["–"] * len(PHASES))
            lines.append(
                f"{head} {cells} | {r['total']:.1f} | 0 / {r['photos']} | failed | – | – |"
            )
            continue
        cells = " | ".join(f"{r['seconds'][p]:.1f}" for p in PHASES)
        acc = r.get("accuracy")
        accuracy = f"{acc['rotation_deg']:.2f} | {acc['centre_pct']:.2f}" if acc else "– | –"
        lines.append(
            f"{head} {cells} | {r['total']:.1f} | {r['registered']} / {r['photos']} | "
            f"{r['reprojection_error']:.2f} | {accuracy} |"
        )
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    """Total seconds and registered share against the photo count, a line per setting."""
    import matplotlib  # only for the figure: the measurements need none of it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    settings = sorted({(r["feature_size"], r["matching"]) for r in rows})
    for size, matching in settings:
        mine = sorted((r for r in rows if (r["feature_size"], r["matching"]) == (size, matching)),
                      key=lambda r: r["photos"])  # fmt: skip
        label = f"{size} px, {matching}"
        counts = [r["photos"] for r in mine]
        ax_t.plot(counts, [r["total"] for r in mine], "o-", label=label)
        ax_r.plot(counts, [r["registered"] / r["photos"] for r in mine], "o-", label=label)
    ax_t.set_xlabel("photos")
    ax_t.set_ylabel("seconds (all phases)")
    ax_t.set_title("pose step time")
    ax_r.set_xlabel("photos")
    ax_r.set_ylabel("registered share")
    ax_r.set_ylim(0, 1.05)
    ax_r.set_title("photos registered")
    ax_t.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--photos", type=Path, default=ROOT / "data" / "real" / "fox" / "images")
    ap.add_argument("--counts", type=int, nargs="+", default=[10, 25, 50])
    ap.add_argument("--feature-sizes", type=int, nargs="+", default=[512, 1024])
    ap.add_argument("--matching", nargs="+", default=["exhaustive", "sequential"],
                    choices=["auto", "exhaustive", "sequential"])  # fmt: skip
    ap.add_argument("--repeats", type=int, default=1, help="runs per setting (medians reported)")
    ap.add_argument("--reference", type=Path, default=None,
                    help="poses to compare with (transforms.json or COLMAP model); default: "
                    "the transforms.json beside --photos, if any")  # fmt: skip
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "poses_bench")
    args = ap.parse_args(argv)
    quiet_colmap()  # the table says it all; COLMAP's line per step would bury it
    photos = list_photos(args.photos)
    if len(photos) < 2:
        raise SystemExit(f"{args.photos}: fewer than 2 photos")
    ref_path = args.reference or args.photos.parent / "transforms.json"
    reference = reference_poses(ref_path) if ref_path.exists() else None
    rows = []
    for count in args.counts:
        chosen = subset(photos, count)
        for size in args.feature_sizes:
            for matching in args.matching:
                runs = [run_once(chosen, size, matching, reference) for _ in range(args.repeats)]
                row = {"photos": len(chosen), "feature_size": size, "matching": matching,
                       **summarise(runs), "runs": runs}  # fmt: skip
                rows.append(row)
                done = row["error"] or f"{row['registered']}/{len(chosen)} registered"
                print(f"{len(chosen)} photos, {size} px, {matching}: {row['total']:.1f} s, {done}",
                      file=sys.stderr, flush=True)  # fmt: skip
    text = table(rows)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {
        "photos": str(args.photos),
        "reference": str(ref_path) if reference else None,
        "repeats": args.repeats,
        "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "pycolmap": pycolmap.__version__,
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    (args.out / "poses.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    (args.out / "poses.md").write_text(text + "\n")
    plot(rows, args.out / "poses.png")
    return rows


if __name__ == "__main__":
    main()
