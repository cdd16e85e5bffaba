"""``prosplat reconstruct PHOTOS``: a folder of unposed photos (or a video) is posed first.

When ``reconstruct``'s input is a folder that holds photos but no poses (neither
``transforms.json`` nor a COLMAP model: :func:`prosplat.pipeline.posed_views.holds_poses`), or
a video file, :func:`pose_step` runs :func:`prosplat.poses.estimate_poses` into ``OUT/poses``
and the reconstruction then reads ``OUT/poses`` as any posed set (its inputs picked among the
registered photos). A later run reuses ``OUT/poses`` when its ``poses.json`` records the same
source files (names, sizes, modification times) and the same pose options; otherwise the pose
step runs again (with ``--overwrite``; without it the run is refused, since the poses there
are not this input's).

Where the poses live: in ``OUT/poses``, written by ``estimate_poses``' own staging (the folder
appears complete or not at all; an interrupted pose step leaves its resumable work in a hidden
``OUT/.poses.*`` folder) *before* ``reconstruct`` stages the rest of ``OUT`` aside. Why not in
``reconstruct``'s staged folder: that folder is deleted when the reconstruction fails or is
interrupted, and posing is the slow step (a minute or more on 2 cores); kept in ``OUT/poses``
it survives, and the re-run reuses it. :func:`prosplat.core.paths.staged_folder` merges its
folder into a non-empty ``OUT`` entry by entry, replacing only names the reconstruction wrote,
so ``poses/`` stays; and ``OUT`` holding nothing but the poses counts as empty
(:func:`is_pose_entry`), so the re-run needs no ``--overwrite``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

from prosplat.cli.poses import pose_with_bars
from prosplat.pipeline.posed_views import holds_poses
from prosplat.poses import (
    PoseOptions,
    PoseResult,
    is_video,
    list_photos,
    load_pose_result,
    reusable,
)

__all__ = [
    "POSES_DIR",
    "PhotoPoses",
    "add_pose_arguments",
    "check_before_posing",
    "is_pose_entry",
    "photo_input",
    "pose_step",
    "report_lines",
    "summary_line",
]

#: the folder under --out the pose step writes (and a re-run reuses)
POSES_DIR = "poses"


def add_pose_arguments(p: argparse.ArgumentParser) -> None:
    """The pose options ``reconstruct`` takes for a folder of photos (the rest: ``prosplat
    poses``); defaults are :class:`~prosplat.poses.PoseOptions`'."""
    d = PoseOptions()
    p.add_argument(
        "--feature-size",
        type=int,
        default=None,
        help=f"photos without poses: the longest side in px features are found at (default "
        f"{d.feature_size}; larger finds more matches on big photos, slower)",
    )
    p.add_argument(
        "--matching",
        choices=["auto", "exhaustive", "sequential"],
        default=None,
        help=f"photos without poses: which photo pairs are matched (default {d.matching}: "
        "sequential for video frames or more than 60 photos, else every pair)",
    )


def is_pose_entry(name: str) -> bool:
    """True for what the pose step keeps in --out: ``poses/`` and its hidden work or staging
    folders (``.poses.*``). They do not make --out "not empty": a reconstruction that failed
    after posing leaves them, for the re-run to reuse."""
    return name == POSES_DIR or name.startswith(f".{POSES_DIR}.")


def photo_input(path: Path) -> str | None:
    """``"video"``, ``"photos"`` (a folder with photos and no poses), or None: a posed set
    (or nothing readable, which :func:`~prosplat.pipeline.posed_views.load_posed_set` names).

    Raises:
        FileNotFoundError: a folder with neither poses nor photos (the message says that a
            folder of photos is accepted too).
    """
    path = Path(path)
    if path.is_file() and is_video(path):
        return "video"
    if not path.is_dir() or holds_poses(path):
        return None
    if list_photos(path):
        return "photos"
    inner = path / "images"
    hint = (
        f" ({inner} holds photos: give that folder)"
        if inner.is_dir() and not holds_poses(inner) and list_photos(inner)
        else ""
    )
    raise FileNotFoundError(
        f"{path} holds neither transforms.json nor a COLMAP model (cameras.txt + images.txt, "
        f"or .bin) nor photos (jpg, png, exr, tif, webp){hint}; give a posed set, a folder of "
        "photos or a video"
    )


def check_before_posing(args: argparse.Namespace) -> None:
    """Refuse, before the slow pose step, what reconstruct would refuse later anyway."""
    if args.images is not None:
        raise ValueError(
            "--images names the image folder of a posed set; a folder of photos is its own "
            "images (leave --images out)"
        )
    if args.skip_missing:
        raise ValueError("--skip-missing is for posed sets; photos are posed here")


def _options(args: argparse.Namespace) -> PoseOptions:
    given = {"feature_size": args.feature_size, "matching": args.matching}
    return PoseOptions(**{k: v for k, v in given.items() if v is not None})


@dataclass
class PhotoPoses:
    """The pose step as ``reconstruct`` used it: where from, its result, reused or run."""

    source: Path
    kind: str  # "photos" | "video"
    result: PoseResult
    reused: bool
    seconds: float


def pose_step(args: argparse.Namespace, out: Path, kind: str) -> PhotoPoses:
    """Pose ``args.input`` into ``out/poses`` (or reuse it) and point ``args.input`` there.

    Raises:
        PoseError: too few photos matched (one line; the CLI exits 2).
        ValueError: ``out/poses`` holds other poses and ``--overwrite`` was not given.
    """
    source = Path(args.input)
    folder = out / POSES_DIR
    options = _options(args)
    t0 = time.perf_counter()
    if reusable(folder, source, options):
        result, reused = load_pose_result(folder), True
        print(
            f"reusing the poses in {folder} ({len(result.names)} registered photos; same "
            "photos and options)"
        )
    else:
        if folder.exists() and not args.overwrite:
            raise ValueError(
                f"{folder} holds poses of other photos or options; pass --overwrite to pose "
                "again, or pick a new --out"
            )
        print(
            f"posing the {'frames of' if kind == 'video' else 'photos in'} {source} into {folder}"
        )
        result, reused = pose_with_bars(source, folder, options, overwrite=True), False
    args.photos = source  # named in the report's options
    args.input = folder
    return PhotoPoses(source, kind, result, reused, time.perf_counter() - t0)


def _names(items: list[str], limit: int = 0) -> str:
    shown = items if not limit or len(items) <= limit else [*items[:limit], "..."]
    return ", ".join(shown)


def report_lines(p: PhotoPoses) -> list[str]:
    """report.md's lines on the pose step: registered count, each photo not registered,
    each file skipped (with why), and the time."""
    r = p.result
    read = len(r.names) + len(r.unregistered)
    what = "video frames" if p.kind == "video" else "photos"
    how = (
        "reused from an earlier run"
        if p.reused
        else f"in {p.seconds:.1f} s: " + ", ".join(f"{k} {v:.1f} s" for k, v in r.timings.items())
    )
    lines = [
        f"- {what}: `{p.source}` posed into `{POSES_DIR}/` ({how}): {len(r.names)} of {read} "
        f"registered, mean reprojection error {r.reprojection_error:.2f} px",
        f"- not registered ({len(r.unregistered)}): {_names(r.unregistered)}"
        if r.unregistered
        else f"- not registered: none (every {what[:-1]} read was registered)",
    ]
    if r.skipped:
        shown = "; ".join(f"{name} ({why})" for name, why in r.skipped)
        lines.append(f"- skipped, unreadable ({len(r.skipped)}): {shown}")
    return lines


def summary_line(p: PhotoPoses) -> str:
    """The printed summary's line on the pose step."""
    r = p.result
    read = len(r.names) + len(r.unregistered)
    what = "video frames" if p.kind == "video" else "photos"
    took = "reused" if p.reused else f"posed in {p.seconds:.0f} s"
    line = f"poses: {len(r.names)} of {read} {what} registered ({took})"
    if r.unregistered:
        line += f"; not registered: {_names(r.unregistered, 10)}"
    if r.skipped:
        line += f"; skipped: {_names([n for n, _ in r.skipped], 10)}"
    return line
