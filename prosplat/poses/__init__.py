"""Poses for photos that have none (issue 69): structure from motion with pycolmap on the CPU.

A folder of photos, a list of photo files or a video becomes a pose folder (working copies,
a COLMAP model, ``transforms.json``) in an upright frame at a sensible scale, which every
posed-image reader of ProSplat opens. See :func:`estimate_poses`. Posed images without points
get sparse points triangulated with their known poses: :func:`triangulate_inputs`.
"""

from prosplat.poses.errors import PoseCancelled, PoseError
from prosplat.poses.photos import list_photos
from prosplat.poses.sfm import (
    PHASE_LABELS,
    PHASE_UNITS,
    PoseOptions,
    PoseResult,
    estimate_poses,
    load_pose_result,
    quiet_colmap,
    reusable,
    source_record,
    work_folder,
)
from prosplat.poses.triangulate import SparsePoints, triangulate_inputs
from prosplat.poses.video import extract_frames, is_video

__all__ = [
    "PHASE_LABELS",
    "PHASE_UNITS",
    "PoseCancelled",
    "PoseError",
    "PoseOptions",
    "PoseResult",
    "SparsePoints",
    "estimate_poses",
    "extract_frames",
    "is_video",
    "list_photos",
    "load_pose_result",
    "quiet_colmap",
    "reusable",
    "source_record",
    "triangulate_inputs",
    "work_folder",
]
