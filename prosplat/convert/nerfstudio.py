"""Read and write ``transforms.json`` (nerfstudio, instant-ngp and NeRF-synthetic forms).

The file holds intrinsics either at the top level or per frame (a frame's value wins):

* ``fl_x fl_y cx cy w h`` in pixels (nerfstudio, instant-ngp). Both tools cast rays through
  pixel centres at +0.5 with ``(u - cx) / fl_x``, which is exactly our convention, so the
  values map straight onto ``K``. Missing ``cx``/``cy`` default to the centre (w/2, h/2).
* ``camera_angle_x`` (and optionally ``camera_angle_y``), the full field of view in radians
  (NeRF synthetic): ``fx = 0.5 * w / tan(0.5 * camera_angle_x)``. That form usually has no
  ``w``/``h``, so the size comes from ``image_size=(w, h)`` or the image file's header.

``transform_matrix`` is an OpenGL camera-to-world matrix (x right, y up, looking down −z);
it is flipped to OpenCV axes with :data:`~prosplat.convert.blender.OPENGL_TO_OPENCV`, the same
flip Blender cameras need. Lens distortion (``k1 k2 k3 k4 p1 p2``; ``camera_model`` ``OPENCV``
or ``OPENCV_FISHEYE``, or instant-ngp's ``"is_fisheye": true``) is read only with
``read_transforms(..., allow_distortion=True)``, which puts a
:class:`~prosplat.convert.distortion.Distortion` on each frame (see that module for the
models); by default a file with non-zero coefficients is rejected rather than silently
mis-projected.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from prosplat.convert.blender import OPENGL_TO_OPENCV
from prosplat.convert.distortion import Distortion
from prosplat.core.camera import Camera

__all__ = ["TRANSFORMS_NAME", "Frame", "TransformsFile", "read_transforms", "write_transforms"]

TRANSFORMS_NAME = "transforms.json"

_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_CAMERA_MODEL_KEY = "camera_model"
# Pinhole-compatible nerfstudio camera models (OPENCV and friends only with zero distortion).
_PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "SIMPLE_RADIAL", "RADIAL", "PERSPECTIVE")
_FISHEYE_MODELS = ("OPENCV_FISHEYE", "FISHEYE")
_FISHEYE_FLAG = "is_fisheye"  # instant-ngp's way of saying OPENCV_FISHEYE
_FRAME_KEYS = ("file_path", "transform_matrix")
_RESERVED = (
    set(_INTRINSIC_KEYS) | set(_DISTORTION_KEYS) | {_CAMERA_MODEL_KEY, _FISHEYE_FLAG, "frames"}
)
# Extensions tried when a frame's file_path has none (NeRF synthetic writes "./train/r_0").
_IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".exr", ".PNG", ".JPG", ".JPEG", ".EXR")


@dataclass(frozen=True)
class Frame:
    """One posed image: its camera, its ``file_path`` as written in the file (relative to the
    json's folder, possibly without extension) and any other per-frame keys."""

    camera: Camera
    file_path: str
    extra: dict[str, Any] = field(default_factory=dict)
    distortion: Distortion | None = None  # only with read_transforms(allow_distortion=True)


@dataclass
class TransformsFile:
    """A parsed transforms file: frames in file order, ``meta`` = the other top-level keys
    (``aabb_scale``, ``applied_transform``, ...), passed through untouched."""

    frames: list[Frame]
    meta: dict[str, Any]
    path: Path | None = None


def _resolve(path: str | Path) -> Path:
    p = Path(path)
    return p / TRANSFORMS_NAME if p.is_dir() else p


def _image_file(root: Path, file_path: str) -> Path | None:
    p = root / file_path
    if p.is_file():
        return p
    if p.suffix == "":
        for ext in _IMAGE_EXTENSIONS:
            q = p.with_name(p.name + ext)
            if q.is_file():
                return q
    return None


def _image_size_from_file(path: Path) -> tuple[int, int]:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read the image header of {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        return int(spec.width), int(spec.height)
    finally:
        inp.close()


def _number(value: Any, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return v


def _frame_lens(get, where: str, allow_distortion: bool) -> Distortion | None:
    """The frame's lens model (None: pinhole), or an error when distortion is not allowed."""
    model = get(_CAMERA_MODEL_KEY)
    model = None if model is None else str(model).upper()
    fisheye = model in _FISHEYE_MODELS or bool(get(_FISHEYE_FLAG))
    if model is not None and model not in _PINHOLE_MODELS and not fisheye:
        raise ValueError(
            f"{where}: camera_model {model!r} is not supported; use PINHOLE, OPENCV or "
            "OPENCV_FISHEYE, or undistort the images first"
        )
    coeffs = {k: _number(get(k), f"{where}: {k}") for k in _DISTORTION_KEYS if get(k) is not None}
    if not allow_distortion:
        if fisheye:
            raise ValueError(
                f"{where}: camera_model {model or 'OPENCV_FISHEYE'} is a fisheye; only "
                "undistorted pinhole images are read here (undistort the images first, or use "
                "`prosplat reconstruct`, which undistorts them)"
            )
        for key, v in coeffs.items():
            if v != 0.0:
                raise ValueError(
                    f"{where}: distortion {key}={v} is non-zero; distorted cameras are read only "
                    "with read_transforms(..., allow_distortion=True) (`prosplat reconstruct` "
                    "undistorts them), or undistort the images first (e.g. ns-process-data or "
                    "COLMAP's image_undistorter) and write zero distortion"
                )
        return None
    if not fisheye and not any(coeffs.values()):
        return None
    try:
        return Distortion("fisheye" if fisheye else "opencv", **coeffs)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


def _frame_camera(
    frame: dict,
    top: dict,
    root: Path,
    where: str,
    image_size: tuple[int, int] | None,
    allow_distortion: bool = False,
) -> tuple[Camera, Distortion | None]:
    """The camera and lens of one frame; ``where`` names the frame in error messages."""

    def get(key: str) -> Any:
        return frame[key] if key in frame else top.get(key)

    lens = _frame_lens(get, where, allow_distortion)

    w, h = get("w"), get("h")
    if (w is None) != (h is None):
        raise ValueError(f"{where}: has only one of 'w' and 'h'; give both or neither")
    if w is None:
        if image_size is not None:
            w, h = image_size
        else:
            image = _image_file(root, str(frame["file_path"]))
            if image is None:
                raise FileNotFoundError(
                    f"{where}: no 'w'/'h' in the file and the image {root / frame['file_path']} "
                    "was not found to read its size; pass image_size=(w, h) to read_transforms "
                    "or add 'w' and 'h' to the transforms file"
                )
            w, h = _image_size_from_file(image)
    w_f, h_f = _number(w, f"{where}: w"), _number(h, f"{where}: h")
    if w_f != int(w_f) or h_f != int(h_f) or w_f < 1 or h_f < 1:
        raise ValueError(f"{where}: image size must be positive integers, got w={w}, h={h}")
    W, H = int(w_f), int(h_f)

    if get("fl_x") is not None:
        fx = _number(get("fl_x"), f"{where}: fl_x")
    elif get("camera_angle_x") is not None:
        angle = _number(get("camera_angle_x"), f"{where}: camera_angle_x")
        if not 0 < angle < math.pi:
            raise ValueError(f"{where}: camera_angle_x must be in (0, pi) radians, got {angle}")
        fx = 0.5 * W / math.tan(0.5 * angle)
    else:
        raise ValueError(f"{where}: no focal length; add 'fl_x' (pixels) or 'camera_angle_x'")
    if get("fl_y") is not None:
        fy = _number(get("fl_y"), f"{where}: fl_y")
    elif get("camera_angle_y") is not None:
        angle = _number(get("camera_angle_y"), f"{where}: camera_angle_y")
        if not 0 < angle < math.pi:
            raise ValueError(f"{where}: camera_angle_y must be in (0, pi) radians, got {angle}")
        fy = 0.5 * H / math.tan(0.5 * angle)
    else:
        fy = fx
    cx = _number(get("cx"), f"{where}: cx") if get("cx") is not None else W / 2
    cy = _number(get("cy"), f"{where}: cy") if get("cy") is not None else H / 2

    try:
        m = torch.tensor(frame["transform_matrix"], dtype=torch.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: transform_matrix is not a numeric matrix ({e})") from None
    if tuple(m.shape) == (3, 4):
        m = torch.cat([m, m.new_tensor([[0.0, 0.0, 0.0, 1.0]])])
    if tuple(m.shape) != (4, 4):
        raise ValueError(f"{where}: transform_matrix must be 4x4 (or 3x4), got {tuple(m.shape)}")
    if not torch.isfinite(m).all():
        raise ValueError(f"{where}: transform_matrix contains NaN or Inf; fix or drop the frame")
    c2w = m @ OPENGL_TO_OPENCV  # [4, 4] OpenCV camera-to-world
    R = c2w[:3, :3]
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R.T
    w2c[:3, 3] = -R.T @ c2w[:3, 3]
    w2c[3] = m[3]  # keep a bad last row visible to Camera's check
    try:
        return Camera.from_intrinsics(fx, fy, cx, cy, W, H, w2c), lens
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


def read_transforms(
    path: str | Path,
    image_size: tuple[int, int] | None = None,
    allow_distortion: bool = False,
) -> TransformsFile:
    """Read a ``transforms.json`` (or a folder holding one).

    Args:
        path: the json file, or a folder containing ``transforms.json``.
        image_size: (w, h) for files without ``w``/``h``; when omitted the size is read from
            each frame's image header (OpenImageIO).
        allow_distortion: read OpenCV / fisheye lens coefficients into ``Frame.distortion``
            instead of refusing them.
    Raises:
        FileNotFoundError: the file, or an image needed for its size, is missing.
        ValueError: malformed json, missing keys, NaN poses, distortion.
    """
    p = _resolve(path)
    if not p.is_file():
        raise FileNotFoundError(
            f"transforms file not found: {p}; pass the path of a transforms.json or of the "
            "folder that holds it"
        )
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{p} is not valid JSON: {e}") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise ValueError(
            f"{p} has no 'frames' list; is it a nerfstudio/instant-ngp transforms file?"
        )

    frames: list[Frame] = []
    for i, frame in enumerate(data["frames"]):
        where = f"{p} frame {i}"
        if not isinstance(frame, dict):
            raise ValueError(f"{where} is not an object")
        for key in _FRAME_KEYS:
            if key not in frame:
                raise ValueError(f"{where} has no '{key}'; every frame needs {_FRAME_KEYS}")
        where = f"{p} frame {i} ({frame['file_path']})"
        camera, lens = _frame_camera(frame, data, p.parent, where, image_size, allow_distortion)
        extra = {k: v for k, v in frame.items() if k not in _RESERVED and k not in _FRAME_KEYS}
        frames.append(Frame(camera, str(frame["file_path"]), extra, lens))
    meta = {k: v for k, v in data.items() if k not in _RESERVED}
    return TransformsFile(frames=frames, meta=meta, path=p)


def _intrinsics(camera: Camera, where: str) -> dict[str, Any]:
    K = camera.K.detach().to(device="cpu", dtype=torch.float64)
    if float(K[0, 1]) != 0.0:
        raise ValueError(f"{where}: transforms.json cannot hold skew (K[0, 1] = {float(K[0, 1])})")
    return {
        "fl_x": float(K[0, 0]),
        "fl_y": float(K[1, 1]),
        "cx": float(K[0, 2]),
        "cy": float(K[1, 2]),
        "w": camera.width,
        "h": camera.height,
    }


def _lens_keys(lens: Distortion | None) -> dict[str, Any]:
    """A frame's lens as nerfstudio writes it (``camera_model`` and coefficients); {} for a
    pinhole."""
    if lens is None or (lens.is_identity and lens.model == "opencv"):
        return {}
    if lens.model == "fisheye":
        keys = {"k1": lens.k1, "k2": lens.k2, "k3": lens.k3, "k4": lens.k4}
        return {_CAMERA_MODEL_KEY: "OPENCV_FISHEYE", **keys}
    keys = {"k1": lens.k1, "k2": lens.k2, "k3": lens.k3, "k4": lens.k4}
    return {_CAMERA_MODEL_KEY: "OPENCV", **keys, "p1": lens.p1, "p2": lens.p2}


def write_transforms(
    path: str | Path,
    frames: Sequence[Frame],
    meta: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write frames as a nerfstudio/instant-ngp ``transforms.json``; returns the file written.

    Intrinsics go to the top level when all frames share them (readable by every tool), and
    per frame otherwise; so does a frame's lens (:class:`Frame` ``distortion``: ``camera_model``
    ``OPENCV`` or ``OPENCV_FISHEYE`` with ``k1 k2 k3 k4 p1 p2``, which
    ``read_transforms(..., allow_distortion=True)`` reads back). ``meta`` keys are written at
    the top level; keys derived from the cameras (intrinsics, distortion, camera_model, frames)
    are refused there. Floats are written with full precision so reading back gives the same
    cameras.

    Raises:
        FileExistsError: the file exists and ``overwrite`` is False.
    """
    p = _resolve(path)
    meta = dict(meta or {})
    clash = sorted(set(meta) & _RESERVED)
    if clash:
        raise ValueError(f"meta keys {clash} are derived from the cameras; remove them from meta")
    if len(frames) == 0:
        raise ValueError("write_transforms needs at least one frame")

    intr = [
        _intrinsics(f.camera, f"frame {i} ({f.file_path})") | _lens_keys(f.distortion)
        for i, f in enumerate(frames)
    ]
    shared = all(x == intr[0] for x in intr)
    out: dict[str, Any] = {_CAMERA_MODEL_KEY: "PINHOLE"}
    if shared:
        out.update(intr[0])
    out.update(meta)
    out_frames = []
    for i, (f, k) in enumerate(zip(frames, intr, strict=True)):
        bad = sorted((set(f.extra) & _RESERVED) | (set(f.extra) & set(_FRAME_KEYS)))
        if bad:
            raise ValueError(f"frame {i} ({f.file_path}): extra keys {bad} are reserved; drop them")
        w2c = f.camera.world_to_cam.detach().to(device="cpu", dtype=torch.float64)
        c2w = torch.eye(4, dtype=torch.float64)  # [4, 4] OpenCV camera-to-world
        c2w[:3, :3] = w2c[:3, :3].T
        c2w[:3, 3] = -w2c[:3, :3].T @ w2c[:3, 3]
        entry: dict[str, Any] = {"file_path": f.file_path}
        entry["transform_matrix"] = (c2w @ OPENGL_TO_OPENCV).tolist()  # OpenGL camera-to-world
        if not shared:
            entry.update(k)
        entry.update(f.extra)
        out_frames.append(entry)
    out["frames"] = out_frames

    text = json.dumps(out, indent=2)
    if p.exists() and not overwrite:
        raise FileExistsError(f"{p} already exists; pass overwrite=True to replace it")
    p.parent.mkdir(parents=True, exist_ok=True)
    with open(p, "w" if overwrite else "x") as fh:  # "x": never clobber a file made meanwhile
        fh.write(text + "\n")
    return p
