"""Read COLMAP models (text and binary) and write text ones.

COLMAP already speaks our conventions: ``images.txt`` stores world-to-camera poses
(``QW QX QY QZ`` rotation, ``TX TY TZ`` translation) with OpenCV camera axes, and COLMAP puts
the centre of the top-left pixel at (0.5, 0.5), so ``cx, cy`` map onto ``K`` unchanged. Only
undistorted pinhole models (``PINHOLE``, ``SIMPLE_PINHOLE``) are accepted; anything with lens
distortion must go through COLMAP's ``image_undistorter`` first, which writes PINHOLE cameras
and the matching undistorted images. ``points3D.txt`` is not read (the sparse points are not
needed); it is written empty so COLMAP can open the model we write.

:func:`read_colmap_model` reads a whole model for reconstruction: text (``*.txt``) or binary
(``cameras.bin``, ``images.bin``, ``points3D.bin``, as COLMAP writes by default), distorted
camera models included (``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV`` without
rational terms, ``OPENCV_FISHEYE``, ``SIMPLE_RADIAL_FISHEYE``, ``RADIAL_FISHEYE``; each image
carries its :class:`~prosplat.convert.distortion.Distortion`), and the sparse points with the
images that observe them, from which :mod:`prosplat.posed` derives near/far.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from prosplat.convert.distortion import Distortion
from prosplat.core.camera import Camera
from prosplat.core.rotations import qvec_to_rotmat, rotmat_to_qvec

__all__ = [
    "ColmapImage",
    "ColmapModel",
    "qvec_to_rotmat",
    "read_colmap_model",
    "read_colmap_text",
    "rotmat_to_qvec",
    "write_colmap_text",
]

_FILES = ("cameras.txt", "images.txt", "points3D.txt")
# Parameters per supported model: SIMPLE_PINHOLE f cx cy, PINHOLE fx fy cx cy.
_N_PARAMS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4}
# Every model read_colmap_model understands: name -> (COLMAP's model id, parameter count).
_MODELS = {
    "SIMPLE_PINHOLE": (0, 3),
    "PINHOLE": (1, 4),
    "SIMPLE_RADIAL": (2, 4),
    "RADIAL": (3, 5),
    "OPENCV": (4, 8),
    "OPENCV_FISHEYE": (5, 8),
    "FULL_OPENCV": (6, 12),
    "SIMPLE_RADIAL_FISHEYE": (8, 4),
    "RADIAL_FISHEYE": (9, 5),
}
# binary cameras.bin stores the id; models it may hold that are not read, for the message
_OTHER_MODEL_IDS = {7: ("FOV", 5), 10: ("THIN_PRISM_FISHEYE", 12)}


@dataclass(frozen=True)
class ColmapImage:
    """One registered image of a COLMAP model: file ``name`` (relative to the image folder),
    its :class:`Camera`, COLMAP's ``image_id`` and its lens (None: an ideal pinhole)."""

    name: str
    camera: Camera
    image_id: int
    distortion: Distortion | None = None


@dataclass(frozen=True)
class ColmapModel:
    """A whole COLMAP model: ``images`` sorted by name, ``points [P,3]`` (float64, world) and
    ``observed``: image name -> indices into ``points`` of the points that image observes
    (empty when the model has no points3D file)."""

    images: list[ColmapImage]
    points: Tensor
    observed: dict[str, Tensor]
    binary: bool


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


def _camera_params(
    model: str, params: list[float], where: str
) -> tuple[tuple[float, float, float, float], Distortion | None]:
    """(fx, fy, cx, cy) and the lens (None for a pinhole) of one COLMAP camera."""
    if model not in _MODELS:
        raise ValueError(
            f"{where}: camera model {model} is not supported; supported: {sorted(_MODELS)}. "
            "Run COLMAP's image_undistorter and use its PINHOLE model and images"
        )
    need = _MODELS[model][1]
    if len(params) != need:
        raise ValueError(f"{where}: {model} needs {need} parameters, got {len(params)}")
    if not all(math.isfinite(x) for x in params):
        raise ValueError(f"{where}: camera parameters contain NaN or Inf: {params}")
    p = params
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE",
                 "RADIAL_FISHEYE"):  # fmt: skip
        intr, rest = (p[0], p[0], p[1], p[2]), p[3:]
    else:
        intr, rest = (p[0], p[1], p[2], p[3]), p[4:]
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return intr, None
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        return intr, Distortion("opencv", *rest)
    if model in ("SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        return intr, Distortion("fisheye", *rest)
    if model == "OPENCV_FISHEYE":
        return intr, Distortion("fisheye", *rest)
    k1, k2, p1, p2, *ks = rest  # OPENCV: k1 k2 p1 p2; FULL_OPENCV: ... k3 k4 k5 k6
    k3 = ks[0] if ks else 0.0
    if any(ks[1:]):
        raise ValueError(
            f"{where}: FULL_OPENCV with non-zero rational terms k4-k6 ({ks[1:]}) is not "
            "supported; run COLMAP's image_undistorter and use its PINHOLE model and images"
        )
    return intr, Distortion("opencv", k1=k1, k2=k2, k3=k3, p1=p1, p2=p2)


_Cameras = dict[int, tuple[tuple[float, float, float, float], int, int, Distortion | None]]


def _read_cameras(path: Path, allow_distortion: bool = False) -> _Cameras:
    """camera_id -> ((fx, fy, cx, cy), width, height, lens or None)."""
    cameras: _Cameras = {}
    for n, text in _data_lines(path):
        if not text:
            continue
        tok = text.split()
        where = f"{path}:{n}"
        if len(tok) < 4:
            raise ValueError(f"{where}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'")
        model = tok[1].upper()
        if not allow_distortion and model not in _N_PARAMS:
            raise ValueError(
                f"{where}: camera model {tok[1]} has lens distortion or is not a pinhole; only "
                "PINHOLE and SIMPLE_PINHOLE are supported here (read_colmap_model and "
                "`prosplat reconstruct` undistort OpenCV and fisheye models). Or run COLMAP's "
                "image_undistorter (`colmap image_undistorter --image_path ... --input_path ... "
                "--output_path ...`) and use its sparse model and images"
            )
        try:
            cam_id, width, height = int(tok[0]), int(tok[2]), int(tok[3])
            params = [float(x) for x in tok[4:]]
        except ValueError:
            raise ValueError(f"{where}: could not parse numbers in {text!r}") from None
        intr, lens = _camera_params(model, params, where)
        if cam_id in cameras:
            raise ValueError(f"{where}: duplicate CAMERA_ID {cam_id}")
        cameras[cam_id] = (intr, width, height, lens)
    return cameras


def _image(
    where: str, image_id: int, qt: list[float], cam_id: int, name: str, cameras: _Cameras
) -> ColmapImage:
    """One registered image from its parsed fields (checks shared by text and binary)."""
    if not all(math.isfinite(x) for x in qt):
        raise ValueError(f"{where}: pose of image {name} contains NaN or Inf; re-export it")
    if cam_id not in cameras:
        raise ValueError(f"{where}: image {name} uses CAMERA_ID {cam_id}, not in the cameras file")
    try:
        R = qvec_to_rotmat(qt[:4])
    except ValueError as e:
        raise ValueError(f"{where}: image {name}: {e}") from None
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R
    w2c[:3, 3] = torch.tensor(qt[4:], dtype=torch.float64)
    (fx, fy, cx, cy), width, height, lens = cameras[cam_id]
    try:
        camera = Camera.from_intrinsics(fx, fy, cx, cy, width, height, w2c)
    except ValueError as e:
        raise ValueError(f"{where}: image {name}: {e}") from None
    return ColmapImage(name=name, camera=camera, image_id=image_id, distortion=lens)


def _read_images_text(
    images_path: Path, cameras: _Cameras
) -> tuple[list[ColmapImage], dict[int, list[int]]]:
    """The images of ``images.txt`` in file order, and image_id -> its POINT3D_IDs."""
    images: list[ColmapImage] = []
    observed: dict[int, list[int]] = {}
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    lines = _data_lines(images_path)
    for n, text in lines:
        if not text:
            continue
        points_line = next(lines, None)  # the POINTS2D line after every image line (may be empty)
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
        if image_id in seen_ids or name in seen_names:
            raise ValueError(f"{where}: duplicate image id {image_id} or name {name}")
        seen_ids.add(image_id)
        seen_names.add(name)
        images.append(_image(where, image_id, qt, cam_id, name, cameras))
        pts = points_line[1].split() if points_line else []
        try:
            observed[image_id] = [int(float(x)) for x in pts[2::3] if int(float(x)) >= 0]
        except ValueError:
            observed[image_id] = []  # malformed POINTS2D only costs the near/far estimate
    return images, observed


def read_colmap_text(folder: str | Path) -> list[ColmapImage]:
    """Read the registered images of a COLMAP text model, sorted by name.

    Args:
        folder: the model folder (e.g. ``sparse/0`` or the undistorter's ``sparse``) holding
            ``cameras.txt`` and ``images.txt``.
    Raises:
        FileNotFoundError: a model file is missing (with a hint for binary models).
        ValueError: a distorted camera model (use :func:`read_colmap_model` for those),
            malformed lines, NaN poses, unknown camera ids.
    """
    folder = Path(folder)
    _check_folder(folder)
    cameras = _read_cameras(folder / "cameras.txt")
    images, _ = _read_images_text(folder / "images.txt", cameras)
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


# ---- whole models, text or binary -----------------------------------------------------------
class _Reader:
    """Little-endian fields of a COLMAP binary file, with the file named in errors."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise ValueError(
                f"{self.path} ends early (at byte {self.pos} of {len(self.data)}); the file is "
                "truncated or not a COLMAP binary model; re-export it"
            )
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise ValueError(f"{self.path}: an image name is not terminated; re-export the model")
        text = self.data[self.pos : end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return text


def _read_cameras_binary(path: Path) -> _Cameras:
    r = _Reader(path)
    (count,) = r.take("Q")
    cameras: _Cameras = {}
    by_id = {mid: (name, n) for name, (mid, n) in _MODELS.items()} | _OTHER_MODEL_IDS
    for k in range(count):
        cam_id, model_id, width, height = r.take("iiQQ")
        where = f"{path} camera {k} (id {cam_id})"
        if model_id not in by_id:
            raise ValueError(f"{where}: unknown camera model id {model_id}")
        model, n = by_id[model_id]
        params = list(r.take("d" * n))
        intr, lens = _camera_params(model, params, where)
        if cam_id in cameras:
            raise ValueError(f"{where}: duplicate CAMERA_ID {cam_id}")
        cameras[cam_id] = (intr, width, height, lens)
    return cameras


def _read_images_binary(
    path: Path, cameras: _Cameras
) -> tuple[list[ColmapImage], dict[int, list[int]]]:
    r = _Reader(path)
    (count,) = r.take("Q")
    images: list[ColmapImage] = []
    observed: dict[int, list[int]] = {}
    seen: set = set()
    for k in range(count):
        image_id, *qt, cam_id = r.take("i7di")
        name = r.name()
        where = f"{path} image {k} ({name})"
        if image_id in seen or name in seen:
            raise ValueError(f"{where}: duplicate image id {image_id} or name {name}")
        seen |= {image_id, name}
        images.append(_image(where, image_id, list(qt), cam_id, name, cameras))
        (n_points,) = r.take("Q")
        ids = r.take("ddq" * n_points)[2::3]
        observed[image_id] = [int(i) for i in ids if i >= 0]
    return images, observed


def _read_points_text(path: Path) -> tuple[list[int], list[list[float]]]:
    ids, xyz = [], []
    for n, text in _data_lines(path):
        if not text:
            continue
        tok = text.split()
        try:
            ids.append(int(tok[0]))
            xyz.append([float(x) for x in tok[1:4]])
        except (ValueError, IndexError):
            raise ValueError(
                f"{path}:{n}: expected 'POINT3D_ID X Y Z R G B ERROR TRACK[]'"
            ) from None
    return ids, xyz


def _read_points_binary(path: Path) -> tuple[list[int], list[list[float]]]:
    r = _Reader(path)
    (count,) = r.take("Q")
    ids, xyz = [], []
    for _ in range(count):
        pid, x, y, z, _r, _g, _b, _err, track = r.take("Q3d3BdQ")
        r.take("ii" * track)
        ids.append(int(pid))
        xyz.append([x, y, z])
    return ids, xyz


def read_colmap_model(folder: str | Path) -> ColmapModel:
    """Read a COLMAP model, text or binary, with lens models and sparse points.

    Args:
        folder: the model folder (``sparse/0``) holding ``cameras``/``images`` (and optionally
            ``points3D``) as ``.txt`` or ``.bin``; text wins when both are there.
    Raises:
        FileNotFoundError: neither a text nor a binary model in ``folder``.
        ValueError: unsupported camera models, malformed or truncated files, NaN poses.
    """
    folder = Path(folder)
    text = all((folder / f"{n}.txt").is_file() for n in ("cameras", "images"))
    binary = all((folder / f"{n}.bin").is_file() for n in ("cameras", "images"))
    if not text and not binary:
        hint = "point to the folder holding cameras.txt/images.txt or cameras.bin/images.bin"
        if (folder / "sparse" / "0").is_dir():
            hint = f"pass {folder / 'sparse' / '0'} instead"
        raise FileNotFoundError(
            f"no COLMAP model (cameras + images, .txt or .bin) in {folder}; {hint}"
        )
    if text:
        cameras = _read_cameras(folder / "cameras.txt", allow_distortion=True)
        images, observed = _read_images_text(folder / "images.txt", cameras)
        points_file = folder / "points3D.txt"
        ids, xyz = _read_points_text(points_file) if points_file.is_file() else ([], [])
    else:
        cameras = _read_cameras_binary(folder / "cameras.bin")
        images, observed = _read_images_binary(folder / "images.bin", cameras)
        points_file = folder / "points3D.bin"
        ids, xyz = _read_points_binary(points_file) if points_file.is_file() else ([], [])
    points = torch.tensor(xyz, dtype=torch.float64).reshape(-1, 3)
    keep = torch.isfinite(points).all(dim=1)
    index = {pid: i for i, pid in enumerate(ids) if bool(keep[i])}
    seen_by = {
        im.name: torch.tensor(
            sorted({index[p] for p in observed.get(im.image_id, []) if p in index}),
            dtype=torch.long,
        )
        for im in images
    }
    images = sorted(images, key=lambda im: im.name)
    return ColmapModel(images=images, points=points, observed=seen_by, binary=not text)
