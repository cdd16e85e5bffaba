"""Read and write COLMAP text models (``cameras.txt``, ``images.txt``, ``points3D.txt``).

COLMAP already speaks our conventions: ``images.txt`` stores world-to-camera poses
(``QW QX QY QZ`` rotation, ``TX TY TZ`` translation) with OpenCV camera axes, and COLMAP puts
the centre of the top-left pixel at (0.5, 0.5), so ``cx, cy`` map onto ``K`` unchanged. Only
undistorted pinhole models (``PINHOLE``, ``SIMPLE_PINHOLE``) are accepted; anything with lens
distortion must go through COLMAP's ``image_undistorter`` first, which writes PINHOLE cameras
and the matching undistorted images. ``points3D.txt`` is not read (the sparse points are not
needed); it is written empty so COLMAP can open the model we write.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from prosplat.camera import Camera

__all__ = [
    "ColmapImage",
    "qvec_to_rotmat",
    "read_colmap_text",
    "rotmat_to_qvec",
    "write_colmap_text",
]

_FILES = ("cameras.txt", "images.txt", "points3D.txt")
# Parameters per supported model: SIMPLE_PINHOLE f cx cy, PINHOLE fx fy cx cy.
_N_PARAMS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4}


@dataclass(frozen=True)
class ColmapImage:
    """One registered image of a COLMAP model: file ``name`` (relative to the image folder),
    its :class:`Camera` and COLMAP's ``image_id``."""

    name: str
    camera: Camera
    image_id: int


def qvec_to_rotmat(qvec: Sequence[float] | Tensor) -> Tensor:
    """[4] quaternion (w, x, y, z) -> [3, 3] rotation (float64). Normalises, as COLMAP does."""
    q = torch.as_tensor(qvec, dtype=torch.float64)
    n = q.norm()
    if not torch.isfinite(q).all() or n < 1e-12:
        raise ValueError(f"quaternion must be finite and non-zero, got {q.tolist()}")
    w, x, y, z = (q / n).tolist()
    return torch.tensor(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ],
        dtype=torch.float64,
    )


def rotmat_to_qvec(R: Tensor) -> Tensor:
    """[3, 3] rotation -> [4] unit quaternion (w, x, y, z) with w >= 0 (float64).

    Shepperd's method: take the square root of the largest of the four diagonal combinations,
    so no branch divides by a small number and the result is accurate for every rotation.
    """
    m = torch.as_tensor(R, dtype=torch.float64).tolist()
    tr = m[0][0] + m[1][1] + m[2][2]
    cands = [tr, m[0][0], m[1][1], m[2][2]]
    k = max(range(4), key=lambda i: cands[i])
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = [(m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s]
    qt = torch.tensor(q, dtype=torch.float64)
    qt = qt / qt.norm()
    return -qt if qt[0] < 0 else qt


def _data_lines(path: Path):
    """(line number, stripped text) of the non-comment lines; blank lines included."""
    with open(path) as fh:
        for n, line in enumerate(fh, start=1):
            text = line.strip()
            if not text.startswith("#"):
                yield n, text


def _check_folder(folder: Path) -> None:
    for name in ("cameras.txt", "images.txt"):
        if (folder / name).is_file():
            continue
        hint = "point to the folder holding cameras.txt and images.txt"
        if (folder / name.replace(".txt", ".bin")).is_file():
            hint = (
                "the model is binary; convert it with `colmap model_converter --input_path "
                f"{folder} --output_path {folder} --output_type TXT`"
            )
        elif (folder / "sparse" / "0" / name).is_file():
            hint = f"pass {folder / 'sparse' / '0'} instead"
        raise FileNotFoundError(f"COLMAP model file not found: {folder / name}; {hint}")


def _read_cameras(path: Path) -> dict[int, tuple[list[float], int, int]]:
    """camera_id -> ([fx, fy, cx, cy], width, height)."""
    cameras: dict[int, tuple[list[float], int, int]] = {}
    for n, text in _data_lines(path):
        if not text:
            continue
        tok = text.split()
        where = f"{path}:{n}"
        if len(tok) < 4:
            raise ValueError(f"{where}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'")
        model = tok[1].upper()
        if model not in _N_PARAMS:
            raise ValueError(
                f"{where}: camera model {tok[1]} has lens distortion or is not a pinhole; only "
                "PINHOLE and SIMPLE_PINHOLE are supported. Run COLMAP's image_undistorter "
                "(`colmap image_undistorter --image_path ... --input_path ... --output_path "
                "...`) and use its sparse model and images"
            )
        try:
            cam_id, width, height = int(tok[0]), int(tok[2]), int(tok[3])
            params = [float(x) for x in tok[4:]]
        except ValueError:
            raise ValueError(f"{where}: could not parse numbers in {text!r}") from None
        if len(params) != _N_PARAMS[model]:
            raise ValueError(
                f"{where}: {model} needs {_N_PARAMS[model]} parameters, got {len(params)}"
            )
        if not all(math.isfinite(x) for x in params):
            raise ValueError(f"{where}: camera parameters contain NaN or Inf: {params}")
        if cam_id in cameras:
            raise ValueError(f"{where}: duplicate CAMERA_ID {cam_id}")
        if model == "SIMPLE_PINHOLE":
            f, cx, cy = params
            params = [f, f, cx, cy]
        cameras[cam_id] = (params, width, height)
    return cameras


def read_colmap_text(folder: str | Path) -> list[ColmapImage]:
    """Read the registered images of a COLMAP text model, sorted by name.

    Args:
        folder: the model folder (e.g. ``sparse/0`` or the undistorter's ``sparse``) holding
            ``cameras.txt`` and ``images.txt``.
    Raises:
        FileNotFoundError: a model file is missing (with a hint for binary models).
        ValueError: a distorted camera model, malformed lines, NaN poses, unknown camera ids.
    """
    folder = Path(folder)
    _check_folder(folder)
    cameras = _read_cameras(folder / "cameras.txt")
    images_path = folder / "images.txt"

    images: list[ColmapImage] = []
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    lines = _data_lines(images_path)
    for n, text in lines:
        if not text:
            continue
        next(lines, None)  # the POINTS2D line that follows every image line (may be empty)
        where = f"{images_path}:{n}"
        tok = text.split(maxsplit=9)
        if len(tok) != 10:
            raise ValueError(
                f"{where}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {text!r}"
            )
        try:
            image_id, cam_id = int(tok[0]), int(tok[8])
            qt = [float(x) for x in tok[1:8]]
        except ValueError:
            raise ValueError(f"{where}: could not parse numbers in {text!r}") from None
        name = tok[9].strip()
        if not all(math.isfinite(x) for x in qt):
            raise ValueError(f"{where}: pose of image {name} contains NaN or Inf; re-export it")
        if cam_id not in cameras:
            raise ValueError(f"{where}: image {name} uses CAMERA_ID {cam_id}, not in cameras.txt")
        if image_id in seen_ids or name in seen_names:
            raise ValueError(f"{where}: duplicate image id {image_id} or name {name}")
        seen_ids.add(image_id)
        seen_names.add(name)
        try:
            R = qvec_to_rotmat(qt[:4])
        except ValueError as e:
            raise ValueError(f"{where}: image {name}: {e}") from None
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = R
        w2c[:3, 3] = torch.tensor(qt[4:], dtype=torch.float64)
        (fx, fy, cx, cy), width, height = cameras[cam_id]
        try:
            camera = Camera.from_intrinsics(fx, fy, cx, cy, width, height, w2c)
        except ValueError as e:
            raise ValueError(f"{where}: image {name}: {e}") from None
        images.append(ColmapImage(name=name, camera=camera, image_id=image_id))
    return sorted(images, key=lambda im: im.name)


def _fmt(x: float) -> str:
    return repr(float(x))  # shortest text that reads back to the same double


def write_colmap_text(
    folder: str | Path, images: Sequence[ColmapImage], overwrite: bool = False
) -> Path:
    """Write images as a COLMAP text model (PINHOLE cameras, shared when identical).

    ``points3D.txt`` is written empty and every image gets an empty POINTS2D line, so COLMAP
    (e.g. ``point_triangulator``) can open the model. Returns the folder.

    Raises:
        FileExistsError: a model file exists and ``overwrite`` is False.
        ValueError: skewed intrinsics, duplicate ids/names, names with whitespace.
    """
    folder = Path(folder)
    if not overwrite:
        existing = [str(folder / f) for f in _FILES if (folder / f).exists()]
        if existing:
            raise FileExistsError(f"{existing} already exist; pass overwrite=True to replace them")
    ids = [im.image_id for im in images]
    names = [im.name for im in images]
    if len(set(ids)) != len(ids) or len(set(names)) != len(names):
        raise ValueError("write_colmap_text: image ids and names must be unique")

    cam_ids: dict[tuple, int] = {}
    image_lines: list[str] = []
    for im in sorted(images, key=lambda im: im.image_id):
        if int(im.image_id) != im.image_id or im.image_id < 0:
            raise ValueError(f"image {im.name}: image_id must be a non-negative int")
        if not im.name or any(ch.isspace() for ch in im.name):
            raise ValueError(
                f"image name {im.name!r} is empty or has whitespace, which COLMAP text files "
                "cannot hold; rename the image"
            )
        K = im.camera.K.detach().to(device="cpu", dtype=torch.float64)
        if float(K[0, 1]) != 0.0:
            raise ValueError(f"image {im.name}: COLMAP cannot hold skew (K[0, 1]={float(K[0, 1])})")
        key = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
        key = (*key, im.camera.width, im.camera.height)
        cam_id = cam_ids.setdefault(key, len(cam_ids) + 1)
        w2c = im.camera.world_to_cam.detach().to(device="cpu", dtype=torch.float64)
        q = rotmat_to_qvec(w2c[:3, :3])
        fields = [str(int(im.image_id))] + [_fmt(x) for x in q.tolist()]
        fields += [_fmt(x) for x in w2c[:3, 3].tolist()] + [str(cam_id), im.name]
        image_lines += [" ".join(fields), ""]

    cam_lines = [
        f"{cid} PINHOLE {w} {h} {_fmt(fx)} {_fmt(fy)} {_fmt(cx)} {_fmt(cy)}"
        for (fx, fy, cx, cy, w, h), cid in cam_ids.items()
    ]
    texts = {
        "cameras.txt": [
            "# Camera list with one line of data per camera:",
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
            f"# Number of cameras: {len(cam_lines)}",
            *cam_lines,
        ],
        "images.txt": [
            "# Image list with two lines of data per image:",
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
            "#   POINTS2D[] as (X, Y, POINT3D_ID)",
            f"# Number of images: {len(images)}, mean observations per image: 0",
            *image_lines,
        ],
        "points3D.txt": [
            "# 3D point list with one line of data per point:",
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
            "# Number of points: 0, mean track length: 0",
        ],
    }
    folder.mkdir(parents=True, exist_ok=True)
    for name, lines in texts.items():
        with open(folder / name, "w" if overwrite else "x") as fh:
            fh.write("\n".join(lines) + "\n")
    return folder
