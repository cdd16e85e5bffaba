"""The worker's ``poses`` task: camera poses for a folder of photos or a video
(:func:`prosplat.poses.estimate_poses`), returned as the frames Import Posed Images makes
cameras from, so the add-on's *Import Photos* creates its cameras with the same code.

Params: ``source`` (a folder of photos or a video file), ``out`` (the pose folder to write;
an existing, non-empty one is kept and ``out-2``, ``out-3``... is written instead unless
``overwrite``), and optionally the :class:`~prosplat.poses.PoseOptions` fields
``feature_size``, ``image_size``, ``max_features``, ``matching``, ``max_frames``.
The result: ``source``, ``frames`` (``{"name", "image", "blender"}`` per registered photo, ``image`` the
working copy in the pose folder that the camera's intrinsics refer to, or its undistorted copy
in ``undistorted/`` when the fitted lens bends: Blender's cameras are pinholes), ``folder``,
``registered`` and ``photos`` (counts), ``unregistered`` (names), ``skipped`` (``[file,
reason]``), ``near``, ``far``, ``reprojection_error`` and ``timings``; unregistered and
skipped photos are also the job's warnings.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from prosplat import poses
from prosplat.convert.distortion import undistort_image, undistorted_camera
from prosplat.convert.posed import camera_to_blender_dict, unique_names
from prosplat.core.camera import Camera
from prosplat.core.image_io import read_image, write_image
from prosplat.core.paths import fresh_folder
from prosplat.poses.errors import PoseError
from prosplat.worker.protocol import Cancelled, Progress

#: The PoseOptions fields a job may set (the rest keep their defaults).
OPTION_KEYS = ("feature_size", "image_size", "max_features", "matching", "max_frames")
#: Each phase's share of the job's progress bar: rough shares of the time a pose run took
#: here (issue 69: extraction and mapping dominate; frames only for a video).
PHASE_WEIGHTS = {"frames": 0.15, "prepare": 0.1, "extract": 0.3, "match": 0.2, "map": 0.35,
                 "write": 0.05}  # fmt: skip
#: The pose folder's subfolder of undistorted copies (photos whose fitted lens bends).
UNDISTORTED = "undistorted"
#: Seconds a phase runs before its time-left estimate is shown (earlier ones jump about).
ESTIMATE_AFTER_S = 3.0


class PhaseProgress:
    """``(phase, done, total)`` from :func:`~prosplat.poses.estimate_poses` as the job's
    ``(fraction, message)``, with the time left in the phase once it can be guessed.

    Never raises: pycolmap may call it from its own threads, and a cancel is seen through
    the ``cancel`` callable the pose step polls, not through an exception from here.
    """

    def __init__(self, progress: Progress, video: bool) -> None:
        self.progress = progress
        phases = [p for p in PHASE_WEIGHTS if video or p != "frames"]
        self.total = sum(PHASE_WEIGHTS[p] for p in phases)
        start, self.span = 0.0, {}
        for p in phases:  # (start, weight): a phase's end is exactly the next one's start
            self.span[p] = (start, PHASE_WEIGHTS[p])
            start += PHASE_WEIGHTS[p]
        self.phase: str | None = None
        self.phase_start = time.monotonic()

    def __call__(self, phase: str, done: int, total: int) -> None:
        if phase != self.phase:
            self.phase, self.phase_start = phase, time.monotonic()
        share = min(max(done / total, 0.0), 1.0) if total else 0.0
        fraction = self.progress.fraction  # a phase this does not know keeps the bar where it is
        if phase in self.span:
            lo, width = self.span[phase]
            fraction = 0.97 * (lo + width * share) / self.total
        message = poses.PHASE_LABELS.get(phase, phase)
        if total:
            message += f" ({done}/{total})"
        elapsed = time.monotonic() - self.phase_start
        if 0 < done < total and elapsed >= ESTIMATE_AFTER_S:
            message += f", about {elapsed / done * (total - done):.0f} s left"
        if self.progress.cancelled():
            return
        try:
            self.progress(fraction, message)
        except Cancelled:  # asked between the check and the call: the pose step sees it next
            pass


def task_poses(params: dict, progress: Progress) -> dict:
    """Estimate the poses of a folder of photos or a video (see the module docstring).

    Raises:
        ValueError: no source, or the pose step failed (:class:`~prosplat.poses.PoseError`:
            one line saying how many photos matched and what to do).
        FileNotFoundError: the source does not exist.
        Cancelled: ``progress`` was cancelled (the pose folder is then not written).
    """
    if not params.get("source"):
        raise ValueError("no photos given: choose a folder of photos or a video file")
    if not params.get("out"):
        raise ValueError("no pose folder given: say where the poses are written ('out')")
    source = Path(params["source"])
    if not source.exists():
        raise FileNotFoundError(f"{source} does not exist; choose a folder of photos or a video")
    options = poses.PoseOptions(**{k: params[k] for k in OPTION_KEYS if params.get(k) is not None})
    overwrite = bool(params.get("overwrite", False))
    if not overwrite and poses.reusable(params["out"], source, options):
        # the same photos, unchanged, with the same options: a second import of one folder
        # takes the finished poses (and their undistorted copies) instead of posing again
        progress(0.0, "reusing the poses of an earlier import")
        result = poses.load_pose_result(params["out"])
        frames = undistorted_frames(result, progress)
        return {"source": str(source), "reused": True,
                **pose_result_dict(result, progress, frames)}  # fmt: skip
    out = fresh_folder(Path(params["out"]), overwrite)
    progress(0.0, "starting the pose step")
    poses.quiet_colmap()  # the job's progress says it; COLMAP's line per step fills the log
    report = PhaseProgress(progress, poses.is_video(source))
    made = not out.exists()  # a pose folder this job makes is removed again if the job ends early
    try:
        try:
            result = poses.estimate_poses(source, out, options, progress=report,
                                          cancel=progress.cancelled, overwrite=overwrite)  # fmt: skip
        except PoseError as e:
            if progress.cancelled():  # PoseCancelled, or a failure while stopping: a cancel
                raise Cancelled(f"cancelled: {e}") from None
            raise
        progress(0.97, "reading the cameras")  # a cancel after the last phase still counts
        frames = undistorted_frames(result, progress)
    except BaseException:
        # Import Photos' failure or Esc leaves nothing beside the photos: not the pose step's
        # work folder either (the command line keeps it, to resume; an artist who cancels
        # has usually picked the wrong folder, and it can hold hundreds of MB of copies)
        shutil.rmtree(poses.work_folder(out), ignore_errors=True)
        if made:
            shutil.rmtree(out, ignore_errors=True)
        raise
    return {"source": str(source), "reused": False, **pose_result_dict(result, progress, frames)}


def undistorted_frames(result, progress: Progress) -> list[tuple[Path, Camera]] | None:
    """(image, pinhole camera) per registered photo: a Blender camera has no lens
    distortion, and the reconstruct task takes pinhole views, so photos whose fitted lens
    bends (SfM's radial term) get an undistorted copy in ``FOLDER/undistorted/`` and the
    pinhole camera it fits (:func:`~prosplat.convert.distortion.undistort_view`). None when
    no photo needs one (the working copies are shown as they are).

    The copies are written into a hidden sibling and renamed into place when all are done,
    so a cancel mid-way leaves the pose folder as the pose step wrote it.
    """
    folder = Path(result.folder)
    lenses = list(getattr(result, "distortions", None) or [None] * len(result.names))
    if all(d is None or d.is_identity for d in lenses):
        return None
    final, partial = folder / UNDISTORTED, folder / f".{UNDISTORTED}.partial"
    made = final.is_dir()  # an earlier import of these poses wrote the same copies
    if not made:
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir()
    out: list[tuple[Path, Camera]] = []
    try:
        for i, (file, cam, lens) in enumerate(
            zip(result.names, result.cameras, lenses, strict=True)
        ):
            if not made:
                progress(0.97 + 0.02 * i / len(lenses), f"undistorting photos ({i}/{len(lenses)})")
            if lens is None or lens.is_identity:
                out.append((folder / "images" / file, cam))
                continue
            pinhole = undistorted_camera(cam, lens)
            copy = f"{Path(file).stem}.png"
            if not made:
                image = undistort_image(read_image(folder / "images" / file), cam, lens, pinhole)
                write_image(partial / copy, image)
            out.append((final / copy, pinhole))
        if not made:
            os.replace(partial, final)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return out


def pose_result_dict(result, progress: Progress | None = None,
                     views: list[tuple[Path, Camera]] | None = None) -> dict:  # fmt: skip
    """The task's result for a :class:`~prosplat.poses.PoseResult` (cameras as blender
    dicts, images as the working copies' paths, or ``views``: (image, camera) per registered
    photo, from :func:`undistorted_frames`); names the photos left out as warnings."""
    folder = Path(result.folder)
    names = unique_names(list(result.names))  # display names: the file stems, as imports use
    if views is None:
        views = [(folder / "images" / file, cam) for file, cam in zip(result.names, result.cameras,
                                                                      strict=True)]  # fmt: skip
    frames = [
        {"name": name, "image": str(image), "blender": camera_to_blender_dict(cam)}
        for name, (image, cam) in zip(names, views, strict=True)
    ]
    unregistered = [str(n) for n in result.unregistered]
    skipped = [[str(f), str(why)] for f, why in result.skipped]
    count = len(frames) + len(unregistered)
    if progress is not None and unregistered:
        shown = ", ".join(unregistered[:8]) + (", ..." if len(unregistered) > 8 else "")
        progress.warn(f"{len(unregistered)} of {count} photos could not be matched and have no "
                      f"camera: {shown}")  # fmt: skip
    if progress is not None:
        for file, why in skipped:
            progress.warn(f"skipped {file}: {why}")
    return {
        "frames": frames,
        "folder": str(folder),
        "registered": len(frames),
        "photos": count,
        "unregistered": unregistered,
        "skipped": skipped,
        "near": float(result.near),
        "far": float(result.far),
        "reprojection_error": float(result.reprojection_error),
        "timings": {k: float(v) for k, v in dict(result.timings).items()},
    }
