"""``prosplat poses PHOTOS|VIDEO --out DIR``: camera poses for photos that have none.

Runs structure from motion (pycolmap: SIFT features, matching, incremental mapping) on the
CPU and writes a pose folder that ``prosplat reconstruct``, Blender's *Import Posed Images*
and COLMAP/nerfstudio tools read: ``images/`` (upright working copies), ``sparse/0`` (COLMAP
text model), ``transforms.json`` (with near/far), ``poses.json`` (the report) and
``database.db`` (features kept for a re-run). The scene comes out upright (+Z up) with the
cameras about 4 units from its centre.

An interrupted run (Ctrl-C) leaves its work in a hidden ``.DIR.poses-work`` folder beside DIR
and the next run resumes from it. Photos need overlap: neighbouring photos at most about 30
degrees apart around the subject.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from tqdm import tqdm

from prosplat.cli.options import int_between
from prosplat.poses import (
    PHASE_LABELS,
    PHASE_UNITS,
    PoseCancelled,
    PoseError,
    PoseOptions,
    PoseResult,
    estimate_poses,
    quiet_colmap,
)


class _Bars:
    """One tqdm bar per phase, the previous one closed when the next phase starts (tqdm's
    rate and remaining-time estimate per phase)."""

    def __init__(self) -> None:
        self.phase: str | None = None
        self.bar: tqdm | None = None

    def __call__(self, phase: str, done: int, total: int) -> None:
        if phase != self.phase:
            self.close()
            desc, unit = PHASE_LABELS.get(phase, phase), PHASE_UNITS.get(phase, "photo")
            self.phase, self.bar = phase, tqdm(total=total, desc=desc, unit=unit)
        assert self.bar is not None
        if self.bar.total != total:
            self.bar.total = total
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = self.phase = None


def pose_with_bars(
    source: Path, out: Path, options: PoseOptions, overwrite: bool = False
) -> PoseResult:
    """:func:`~prosplat.poses.estimate_poses` as the command line runs it (``prosplat poses``
    and ``prosplat reconstruct PHOTOS``): a bar per phase, COLMAP's own log kept to errors,
    and the first Ctrl-C as a clean cancel (pycolmap stops at its next check and the work
    folder stays for the re-run; :class:`KeyboardInterrupt` then goes up, so ``main`` says
    "interrupted" and exits 130). A second Ctrl-C interrupts at once."""
    stop = threading.Event()
    previous = None

    def on_interrupt(signum, frame) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, on_interrupt)
    bars = _Bars()
    quiet_colmap()
    try:
        return estimate_poses(
            source, out, options, progress=bars, cancel=stop.is_set, overwrite=overwrite
        )
    except PoseCancelled:
        raise KeyboardInterrupt from None
    finally:
        bars.close()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def run(args: argparse.Namespace) -> int:
    options = PoseOptions(
        feature_size=args.feature_size,
        image_size=args.image_size,
        matching=args.matching,
        max_frames=args.max_frames,
        max_features=args.max_features,
        single_camera={"auto": None, "single": True, "per-photo": False}[args.camera],
        seed=args.seed,
    )
    try:
        result = pose_with_bars(args.source, args.out, options, args.overwrite)
    except (PoseError, FileExistsError) as e:
        print(f"prosplat poses: {e}", file=sys.stderr)
        return 2
    n = len(result.names) + len(result.unregistered)
    print(f"registered {len(result.names)} of {n} photos into {result.folder}")
    if result.unregistered:
        print(f"  not registered ({len(result.unregistered)}): {', '.join(result.unregistered)}")
    for name, why in result.skipped:
        print(f"  skipped (unreadable) {name}: {why}")
    print(
        f"  mean reprojection error {result.reprojection_error:.2f} px, {len(result.points)} "
        f"points, near/far {result.near:.2f}/{result.far:.2f}"
    )
    print("  seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in result.timings.items()))
    return 0


def add_parser(sub) -> None:
    """``prosplat poses`` into the top-level subparsers ``sub``."""
    p = sub.add_parser(
        "poses",
        help="photos (or a video) without poses -> cameras (COLMAP model + transforms.json)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    defaults = PoseOptions()
    p.add_argument("source", type=Path, help="a folder of photos or a video file")
    p.add_argument("--out", type=Path, required=True, help="the pose folder to write")
    p.add_argument(
        "--feature-size",
        type=int_between(64, 16384),
        default=defaults.feature_size,
        help=f"longest side (px) features are found at (default {defaults.feature_size})",
    )
    p.add_argument(
        "--image-size",
        type=int_between(64, 16384),
        default=defaults.image_size,
        help=f"longest side (px) of the working copies (default {defaults.image_size})",
    )
    p.add_argument(
        "--max-features",
        type=int_between(64, 65536),
        default=defaults.max_features,
        help=f"SIFT features per photo, at most (default {defaults.max_features})",
    )
    p.add_argument(
        "--matching",
        choices=("auto", "exhaustive", "sequential"),
        default="auto",
        help="which photo pairs to match: all (exhaustive), each with its next ten by name "
        "(sequential), or auto: sequential for a video or more than 60 photos",
    )
    p.add_argument(
        "--camera",
        choices=("auto", "single", "per-photo"),
        default="auto",
        help="shared intrinsics: auto (photos of one size and camera share them), single, or "
        "per-photo (default auto)",
    )
    p.add_argument(
        "--max-frames",
        type=int_between(2, 10000),
        default=defaults.max_frames,
        help=f"a video: frames kept, the sharpest of equal intervals (default {defaults.max_frames})",
    )
    p.add_argument("--seed", type=int, default=defaults.seed, help="random seed (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    p.set_defaults(func=run)
