"""What *Import Photos* reads and where it writes, without ``bpy``: the source a chosen path
stands for (a folder of photos or a video file), the pose folder beside it, and the names.

The pose folder goes beside the photos, ``<folder>_prosplat_poses`` (``<clip>_prosplat_poses``
for a video), never inside the photo folder: the cameras show its working copies (oriented,
resized photos the poses refer to), so it must last as long as the .blend uses it (a cache
folder may be cleared), it must not need a saved .blend, and it is a plain posed set the
CLI reads too (``prosplat reconstruct <folder>_prosplat_poses``). The worker picks
``..._prosplat_poses-2`` and so on when the folder is already there, so nothing is replaced.
"""

from __future__ import annotations

from pathlib import Path

#: Photo files as ``prosplat.poses`` lists them (matched case-insensitively).
PHOTO_EXTENSIONS = (".jpg", ".jpeg", ".png", ".exr", ".tif", ".tiff", ".webp")
#: Video files the file browser shows (PyAV reads more; any other file is sent as it is).
VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts")
#: The file browser's filter: the photos (to open their folder) and the videos.
FILTER_GLOB = ";".join(f"*{e}" for e in PHOTO_EXTENSIONS + VIDEO_EXTENSIONS)
POSES_SUFFIX = "_prosplat_poses"


def photo_source(path: str | Path) -> Path:
    """The folder or video a chosen path stands for: a folder as it is, a photo its folder
    (picking one photo in the file browser means its folder), any other file itself.

    Raises:
        FileNotFoundError: nothing is there.
    """
    p = Path(path)
    if not str(path).strip() or not p.exists():
        raise FileNotFoundError(f"'{path}' does not exist; choose a folder of photos or a video")
    if p.is_file() and p.suffix.lower() in PHOTO_EXTENSIONS:
        return p.parent
    return p


def source_name(source: Path) -> str:
    """The folder's name, or the video's file stem."""
    return source.stem if source.is_file() else source.name


def default_pose_folder(source: Path) -> Path:
    """``<folder>_prosplat_poses`` beside a photo folder, ``<stem>_prosplat_poses`` beside a
    video (see the module docstring for why there)."""
    return source.parent / f"{source_name(source)}{POSES_SUFFIX}"


def collection_name(source: Path) -> str:
    """The input collection's name, as Import Posed Images names its (by the folder)."""
    return f"ProSplat Inputs {source_name(source)}".strip()


def describe(result: dict, collection: str) -> str:
    """One line for the status bar: photos posed of how many, where, what was left out."""
    text = (f"posed {result.get('registered', len(result.get('frames', [])))} of "
            f"{result.get('photos', '?')} photos into '{collection}'")  # fmt: skip
    left = len(result.get("unregistered") or [])
    skipped = len(result.get("skipped") or [])
    if left or skipped:
        parts = [f"{left} not matched"] * bool(left) + [f"{skipped} unreadable"] * bool(skipped)
        text += f" ({', '.join(parts)})"
    if result.get("reprojection_error") is not None:
        text += f", mean error {float(result['reprojection_error']):.2f} px"
    return text + f"; poses in {result.get('folder', '?')}"
