"""Posed images and cameras as plain JSON data, for a Blender that may have no torch.

The add-on reads and writes Blender values (numbers, 4x4 lists) and must not need torch to do
so; :mod:`prosplat.worker` does the maths, in Blender's Python or in an external one, and
talks in the dicts defined here:

* a **blender camera dict** holds exactly the values of a Blender camera object and scene
  (``matrix_world``, ``lens``, ``sensor_width``, ``sensor_height``, ``sensor_fit``,
  ``shift_x``, ``shift_y``, ``width``, ``height``, ``pixel_aspect_x``, ``pixel_aspect_y``),
  with ``width``/``height`` the pixel size after the resolution percentage;
* an **opencv camera dict** holds ``K`` [3x3], ``world_to_cam`` [4x4], ``width``, ``height``.

:func:`read_posed_images` reads ``transforms.json`` (nerfstudio, instant-ngp, NeRF synthetic,
BlenderNeRF) or a COLMAP text model into :class:`PosedImage` records with resolved image files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from prosplat.convert.blender import blender_from_camera, camera_from_blender
from prosplat.convert.colmap import read_colmap_text
from prosplat.convert.nerfstudio import read_transforms
from prosplat.core.camera import Camera

__all__ = [
    "PosedImage",
    "camera_from_dict",
    "camera_to_blender_dict",
    "camera_to_opencv_dict",
    "read_posed_images",
    "unique_names",
]

_BLENDER_KEYS = ("matrix_world", "lens", "sensor_width", "sensor_height", "sensor_fit",
                 "shift_x", "shift_y", "width", "height")  # fmt: skip
_COLMAP_FILES = ("cameras.txt", "images.txt")


@dataclass(frozen=True)
class PosedImage:
    """One posed image: a display ``name`` (the file's stem, unique within the file), the
    ``image`` file (None if it was not found) and its :class:`Camera`. ``split`` and
    ``target_kind`` are the frame's own (ProSplat's scene folders mark each frame ``input``
    or ``target``, a target ``interpolation`` or ``extrapolation``); None when not given."""

    name: str
    image: Path | None
    camera: Camera
    split: str | None = None
    target_kind: str | None = None


def camera_to_blender_dict(camera: Camera, sensor_width: float = 36.0) -> dict[str, Any]:
    """The Blender settings (JSON-ready) that render exactly ``camera``'s view."""
    p = blender_from_camera(camera, sensor_width=sensor_width)
    return {
        "matrix_world": p.matrix_world.tolist(),
        "lens": p.lens,
        "sensor_width": p.sensor_width,
        "sensor_height": p.sensor_height,
        "sensor_fit": p.sensor_fit,
        "shift_x": p.shift_x,
        "shift_y": p.shift_y,
        "width": p.width,
        "height": p.height,
        "pixel_aspect_x": p.pixel_aspect_x,
        "pixel_aspect_y": p.pixel_aspect_y,
    }


def camera_to_opencv_dict(camera: Camera) -> dict[str, Any]:
    return {
        "K": camera.K.double().tolist(),
        "world_to_cam": camera.world_to_cam.double().tolist(),
        "width": camera.width,
        "height": camera.height,
    }


def camera_from_dict(d: dict[str, Any], where: str = "camera") -> Camera:
    """A :class:`Camera` from a blender or an opencv camera dict (see the module docstring).

    Raises:
        ValueError: neither form, or values no camera can have (the message names ``where``).
    """
    if not isinstance(d, dict):
        raise ValueError(f"{where} must be an object, got {type(d).__name__}")
    try:
        if "K" in d:
            K = torch.tensor(d["K"], dtype=torch.float64)
            w2c = torch.tensor(d["world_to_cam"], dtype=torch.float64)
            return Camera(K, w2c, d["width"], d["height"])
        missing = [k for k in _BLENDER_KEYS if k not in d]
        if missing:
            raise ValueError(f"has neither 'K' (opencv form) nor the blender form's keys {missing}")
        return camera_from_blender(
            d["matrix_world"], d["lens"], d["sensor_width"], d["sensor_height"],
            d["sensor_fit"], d["shift_x"], d["shift_y"], d["width"], d["height"],
            pixel_aspect_x=d.get("pixel_aspect_x", 1.0),
            pixel_aspect_y=d.get("pixel_aspect_y", 1.0),
        )  # fmt: skip
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from None


def _colmap_model_dir(path: Path) -> Path | None:
    folder = path if path.is_dir() else path.parent
    if all((folder / f).is_file() for f in _COLMAP_FILES):
        return folder
    for sub in ("sparse/0", "sparse", "colmap/sparse/0"):
        if all((folder / sub / f).is_file() for f in _COLMAP_FILES):
            return folder / sub
    return None


def colmap_image_dirs(model: Path, images_dir: Path | None) -> list[Path]:
    if images_dir is not None:
        return [images_dir]
    # COLMAP projects keep images/ beside sparse/ (model is sparse/0 or sparse).
    dirs = [model / "images", model.parent / "images", model.parent.parent / "images"]
    return [*dirs, model.parent.parent.parent / "images", model]


def read_posed_images(
    path: str | Path, images_dir: str | Path | None = None
) -> tuple[list[PosedImage], dict[str, Any]]:
    """Posed images from a transforms file (or its folder) or a COLMAP text model, and the
    file's other top-level values (``near``/``far`` when a transforms file has them; COLMAP: {}).

    Args:
        path: ``transforms*.json``, a folder holding ``transforms.json``, or a COLMAP model
            (``cameras.txt``/``images.txt``, their folder or a project folder with
            ``sparse/0``).
        images_dir: where the images are, if not where the format says (COLMAP: ``images/``
            beside ``sparse/``; transforms: relative to the json).

    Raises:
        FileNotFoundError: nothing readable at ``path``.
        ValueError: a malformed file (the reader's message names the line or frame).
    """
    path = Path(path)
    images_dir = Path(images_dir) if images_dir else None
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist; pick a transforms.json or a COLMAP model")
    model = None if path.suffix.lower() == ".json" else _colmap_model_dir(path)
    if model is not None:
        out = []
        dirs = colmap_image_dirs(model, images_dir)
        images = read_colmap_text(model)
        for im, name in zip(images, unique_names([im.name for im in images]), strict=True):
            found = next((d / im.name for d in dirs if (d / im.name).is_file()), None)
            out.append(PosedImage(name, found, im.camera))
        return out, {}
    tf = read_transforms(path)
    root = images_dir if images_dir is not None else tf.path.parent
    out = []
    names = unique_names([f.file_path for f in tf.frames])
    for frame, name in zip(tf.frames, names, strict=True):
        split, kind = frame.extra.get("split"), frame.extra.get("target_kind")
        out.append(PosedImage(name, find_image(root, frame.file_path), frame.camera,
                              split if isinstance(split, str) else None,
                              kind if isinstance(kind, str) else None))  # fmt: skip
    return out, dict(tf.meta)


def unique_names(paths: list[str]) -> list[str]:
    """Display names for image paths: the file stems, or where stems collide (``a/0.png``,
    ``b/0.png``) the relative path with ``/`` as ``_``; made unique with ``-2``, ``-3``..."""
    stems = [Path(p).stem for p in paths]
    if len(set(stems)) != len(stems):
        stems = [str(Path(p).with_suffix("")).replace("/", "_").replace("\\", "_")
                 for p in paths]  # fmt: skip
    seen: dict[str, int] = {}
    out = []
    for s in stems:
        seen[s] = seen.get(s, 0) + 1
        out.append(s if seen[s] == 1 else f"{s}-{seen[s]}")
    return out


def find_image(root: Path, file_path: str) -> Path | None:
    p = root / file_path
    if p.is_file():
        return p.resolve()
    if p.suffix == "":  # NeRF synthetic writes "./train/r_0" without an extension
        for ext in (".png", ".jpg", ".jpeg", ".exr", ".PNG", ".JPG", ".JPEG", ".EXR"):
            q = p.with_name(p.name + ext)
            if q.is_file():
                return q.resolve()
    return None
