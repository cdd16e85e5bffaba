"""Sparse 3D points from posed input images: SIFT, matching and triangulation with KNOWN poses.

Posed photo sets often come without COLMAP points (``transforms.json``, Middlebury, DTU, our own
Blender renders), and a depth range from the camera geometry alone is 3-5x too wide on object
rings. :func:`triangulate_inputs` finds the points in the input images themselves: pycolmap's
SIFT on the CPU, every pair matched and verified, then COLMAP's point triangulator with the
cameras as given (poses and intrinsics stay fixed; only the points are refined).

Pixel convention: COLMAP puts the centre of the top-left pixel at (0.5, 0.5) and reports its
SIFT keypoints so (``prosplat.convert.colmap`` relies on the same), which is
:class:`~prosplat.core.camera.Camera`'s convention (pixel c spans [c, c+1)); ``K`` maps onto
COLMAP's PINHOLE ``fx, fy, cx, cy`` unchanged. Checked: a blob centred at (60, 70) in our
convention gives a SIFT keypoint at (60.02, 69.98), and on a rendered tabletop shifting every
principal point moves the median signed depth error from +0.04 % to -0.28 % (+0.5 px) and
+0.35 % (-0.5 px).

COLMAP's log is left as it is: it is process-wide, so callers (the command line, the worker)
silence it with :func:`prosplat.poses.quiet_colmap`, as for :func:`~prosplat.poses.estimate_poses`.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

try:
    import pycolmap
except ImportError:  # a training-only machine: triangulate_inputs says what to install
    pycolmap = None

from prosplat.core.camera import Camera
from prosplat.core.image_io import write_image
from prosplat.poses.errors import require

__all__ = ["SparsePoints", "triangulate_inputs"]

SEED = 0
DATABASE = "database.db"


@dataclass(frozen=True)
class SparsePoints:
    """Points triangulated from the input views (see :func:`triangulate_inputs`)."""

    points: Tensor  # [P,3] float64, world coordinates
    observed: list[Tensor]  # per input view: [p_v] int64 indices into points it observes
    seconds: float  # wall time of the whole call


def _for_sift(
    images: Tensor, cameras: Sequence[Camera], max_size: int
) -> tuple[Tensor, list[Camera]]:
    """Images and cameras no longer than ``max_size`` on the long side: SIFT's cost grows with
    the pixel count and its features gain little beyond about 1000 px."""
    h, w = images.shape[-2:]
    scale = max_size / max(h, w)
    if scale >= 1:
        return images, list(cameras)
    size = (max(1, round(h * scale)), max(1, round(w * scale)))
    small = F.interpolate(images.float(), size=size, mode="bilinear", antialias=True)
    return small.clamp(0, 1), [c.resized(size[1], size[0]) for c in cameras]  # [V,3,h,w]


def _extract(db: Path, folder: Path, names: list[str], threads: int) -> None:
    """SIFT of every image, one PINHOLE camera each (its parameters are set afterwards)."""
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    pycolmap.extract_features(
        str(db), str(folder), names, pycolmap.CameraMode.PER_IMAGE, reader, extraction,
        pycolmap.Device.cpu,
    )  # fmt: skip


def _match(db: Path, work: Path, names: list[str], threads: int) -> None:
    """Every pair (a handful of views), verified by two-view geometry as COLMAP does."""
    listing = work / "pairs.txt"
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]]
    listing.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(listing)
    pairing.block_size = len(pairs)
    pycolmap.match_image_pairs(str(db), matching, pairing, device=pycolmap.Device.cpu)


def _pinhole(camera: Camera, camera_id: int) -> pycolmap.Camera:
    return pycolmap.Camera(
        model="PINHOLE", width=camera.width, height=camera.height, camera_id=camera_id,
        params=[camera.fx, camera.fy, camera.cx, camera.cy],
    )  # fmt: skip


def _model(
    db: Path, names: list[str], cameras: list[Camera]
) -> tuple[pycolmap.Reconstruction, list[int]]:
    """A reconstruction of the known cameras under the database's ids (the triangulator
    pairs database and model by id and name), and each view's image id. The database's
    cameras get the same parameters, so both sides agree."""
    database = pycolmap.Database.open(str(db))
    try:
        by_name = {im.name: im for im in database.read_all_images()}
        model = pycolmap.Reconstruction()
        ids = []
        for name, cam in zip(names, cameras, strict=True):
            entry = by_name[name]
            pinhole = _pinhole(cam, int(entry.camera_id))
            database.update_camera(pinhole)
            model.add_camera_with_trivial_rig(pinhole)
            w2c = cam.world_to_cam.double().cpu().numpy()  # [4,4] = COLMAP's cam_from_world
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
            image = pycolmap.Image(
                name=name, camera_id=int(entry.camera_id), image_id=int(entry.image_id)
            )
            model.add_image_with_trivial_frame(image, pose)
            ids.append(int(entry.image_id))
    finally:
        database.close()
    return model, ids


def _triangulate(model, db: Path, folder: Path, out: Path, threads: int, reproj: float,
                 angle: float) -> pycolmap.Reconstruction:  # fmt: skip
    """COLMAP's point triangulator: poses stay as given (it fixes the frames), intrinsics too
    (``refine_intrinsics=False``); points only, two-view tracks included (two inputs)."""
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = SEED
    options.num_threads = threads
    options.triangulation.ignore_two_view_tracks = False
    options.triangulation.min_angle = angle
    options.mapper.filter_max_reproj_error = reproj
    options.mapper.filter_min_tri_angle = angle
    out.mkdir()
    return pycolmap.triangulate_points(
        model, str(db), str(folder), str(out), clear_points=True, options=options,
        refine_intrinsics=False,
    )  # fmt: skip


def _tracks(model: pycolmap.Reconstruction, ids: list[int]):
    """Points [P,3], and the observations as (point row, view, keypoint [2]) arrays."""
    view_of = {image_id: v for v, image_id in enumerate(ids)}
    keypoints = {i: model.image(i).points2D for i in ids}
    xyz, rows, views, uv = [], [], [], []
    for row, point in enumerate(model.points3D.values()):
        xyz.append(point.xyz)
        for element in point.track.elements:
            rows.append(row)
            views.append(view_of[element.image_id])
            uv.append(keypoints[element.image_id][element.point2D_idx].xy)
    points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    uv_arr = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    return points, np.asarray(rows, dtype=np.int64), np.asarray(views, dtype=np.int64), uv_arr


def _keep(points, rows, views, uv, cameras: list[Camera], reproj: float, angle: float):
    """Which points pass: track length >= 2, mean reprojection error <= ``reproj`` px, largest
    triangulation angle >= ``angle`` degrees, in front of every camera that observes them."""
    P, V = len(points), len(cameras)
    pts = torch.from_numpy(points)  # [P,3]
    error, front = np.zeros(P), np.ones(P, dtype=bool)
    seen = np.zeros((P, V), dtype=bool)
    seen[rows, views] = True
    for v, cam in enumerate(cameras):
        mine = views == v
        proj, z = cam.to(dtype=torch.float64).project(pts[rows[mine]])  # [n,2], [n]
        error[rows[mine]] += np.linalg.norm(proj.numpy() - uv[mine], axis=1)
        front[rows[mine]] &= z.numpy() > 0
    count = seen.sum(1)
    error /= np.maximum(count, 1)
    centres = np.stack([c.center.double().cpu().numpy() for c in cameras])  # [V,3]
    rays = centres[None] - points[:, None]  # [P,V,3]
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    cos = np.einsum("pvc,pwc->pvw", rays, rays)  # [P,V,V]
    cos = np.where(seen[:, :, None] & seen[:, None, :], cos, 1.0)
    widest = np.degrees(np.arccos(np.clip(cos.min(axis=(1, 2)), -1, 1)))  # [P]
    return (count >= 2) & (error <= reproj) & (widest >= angle) & front, seen


def triangulate_inputs(
    images: Tensor,
    cameras: Sequence[Camera],
    *,
    max_size: int = 1024,
    max_reproj_px: float = 2.0,
    min_angle_deg: float = 1.5,
    num_threads: int = 1,
) -> SparsePoints:
    """Sparse world points seen in the posed input images, their cameras held as given.

    Args:
        images: [V,3,H,W] float in 0..1 (as ``load_views`` returns), V >= 2.
        cameras: V pinhole, undistorted cameras of those images.
        max_size: SIFT sees the images at most this long on the long side.
        max_reproj_px: largest mean reprojection error of a kept point, in pixels of the
            image SIFT saw.
        min_angle_deg: smallest triangulation angle of a kept point (the widest pair of its
            observing cameras).
        num_threads: for SIFT, matching and triangulation. 1 by default: COLMAP's result
            depends on the thread count (a 32-px four-view set gave 20 points on one thread
            and none on two), and the same inputs must give the same depth range on every
            machine; four 256-px inputs take about 0.5 s on one.
    Raises:
        PoseError: pycolmap is not installed (one line that says what to install).
        ValueError: fewer than 2 views, or images and cameras that do not agree.
    """
    require(pycolmap, "pycolmap")
    clock = time.perf_counter()
    if images.ndim != 4 or images.shape[1] != 3 or len(images) != len(cameras):
        raise ValueError(f"need [V,3,H,W] images and V cameras, got {list(images.shape)}, "
                         f"{len(cameras)} cameras")  # fmt: skip
    if len(cameras) < 2:
        raise ValueError("triangulation needs at least 2 views")
    h, w = images.shape[-2:]
    if any((c.width, c.height) != (w, h) for c in cameras):
        raise ValueError(f"cameras must match the {w}x{h} images")
    threads = max(1, int(num_threads))
    small, sift_cams = _for_sift(images.detach().cpu(), cameras, max_size)
    pycolmap.set_random_seed(SEED)
    with tempfile.TemporaryDirectory(prefix="prosplat-triangulate-") as tmp:
        work = Path(tmp)
        folder, db = work / "images", work / DATABASE
        folder.mkdir()
        names = [f"{v:04d}.png" for v in range(len(cameras))]
        for name, image in zip(names, small, strict=True):
            write_image(folder / name, image)
        _extract(db, folder, names, threads)
        _match(db, work, names, threads)
        model, ids = _model(db, names, sift_cams)
        model = _triangulate(model, db, folder, work / "sparse", threads, max_reproj_px,
                             min_angle_deg)  # fmt: skip
    points, rows, views, uv = _tracks(model, ids)
    keep, seen = _keep(points, rows, views, uv, sift_cams, max_reproj_px, min_angle_deg)
    kept = np.flatnonzero(keep)
    observed = [torch.from_numpy(np.flatnonzero(seen[kept, v])) for v in range(len(cameras))]
    return SparsePoints(torch.from_numpy(points[kept]), observed, time.perf_counter() - clock)
