"""Photos in: list a folder, read each photo upright, and write the working copy SfM sees.

Structure from motion wants every photo as it was seen: a phone photo taken in portrait is
stored landscape with an EXIF ``Orientation`` tag, and COLMAP reads pixels, not tags, so the
copy is turned upright here (OpenImageIO ``ImageBufAlgo.reorient``). The copies are 8-bit,
at most ``image_size`` pixels on the longest side (the poses refer to them, and the
generator never needs more), sRGB (linear EXR is tone-mapped with the sRGB transfer curve
and clipped). A JPEG that needs no change is copied byte for byte (no second compression).
A file that cannot be read is named with the reason and left out, never fatal on its own.
"""

from __future__ import annotations

import math
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prosplat.poses.errors import require

try:
    import OpenImageIO as oiio
except ImportError:  # a training-only machine: the readers and writers say what to install
    oiio = None

__all__ = [
    "PHOTO_EXTENSIONS",
    "Photo",
    "list_photos",
    "working_names",
    "write_working_copy",
]

PHOTO_EXTENSIONS = (".jpg", ".jpeg", ".png", ".exr", ".tif", ".tiff", ".webp")
_LINEAR = (".exr", ".hdr")  # scene-linear files: tone-mapped to sRGB for the copy
_JPEG = (".jpg", ".jpeg")
# EXIF fields that still hold for a resized, upright copy (COLMAP's focal prior reads the
# focal lengths with make/model); FocalPlaneXResolution and the like do not, so they go
_KEEP_EXIF = ("Make", "Model", "Exif:FocalLength", "Exif:FocalLengthIn35mmFilm")
JPEG_QUALITY = 95


@dataclass(frozen=True)
class Photo:
    """One readable photo: its ``source`` file, the working copy's file ``name`` and size, and
    ``camera_key`` (size, make, model, focal): photos with one key can share one camera."""

    source: Path
    name: str
    width: int
    height: int
    camera_key: tuple


def list_photos(folder: str | Path) -> list[Path]:
    """The photos in ``folder`` (not its subfolders), sorted by name; hidden files skipped.

    Raises:
        FileNotFoundError: ``folder`` is not a folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder of photos")
    found = [
        p
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in PHOTO_EXTENSIONS
    ]
    return sorted(found, key=lambda p: p.name)


def working_names(sources: list[Path]) -> list[str]:
    """A file name for each source's working copy, unique and without whitespace (COLMAP's
    text files cannot hold it): the stem, ``.jpg`` for JPEGs and ``.png`` for the rest."""
    taken: set[str] = set()
    names = []
    for src in sources:
        ext = ".jpg" if src.suffix.lower() in _JPEG else ".png"
        stem = re.sub(r"\s+", "_", src.stem) or "photo"
        name, k = stem + ext, 2
        while name.lower() in taken:
            name, k = f"{stem}_{k}{ext}", k + 1
        taken.add(name.lower())
        names.append(name)
    return names


def _fail(src: Path, what: str) -> ValueError:
    reason = oiio.geterror() or what
    return ValueError(f"{src.name}: {reason.strip().splitlines()[0] if reason.strip() else what}")


def write_working_copy(src: Path, dst: Path, image_size: int) -> Photo:
    """Read ``src`` upright and write its working copy ``dst`` (8-bit, longest side at most
    ``image_size``); returns the :class:`Photo`.

    Raises:
        ValueError: the file cannot be read or decoded (the message names it and says why).
    """
    require(oiio, "OpenImageIO")
    src, dst = Path(src), Path(dst)
    buf = oiio.ImageBuf(str(src))
    linear = src.suffix.lower() in _LINEAR
    if not buf.read(0, 0, True, oiio.FLOAT if linear else oiio.UINT8) or buf.has_error:
        raise _fail(src, buf.geterror() or "cannot be read")
    spec = buf.spec()
    if spec.width < 8 or spec.height < 8 or spec.nchannels < 1:
        raise ValueError(f"{src.name}: {spec.width}x{spec.height} is too small for a photo")
    orientation = spec.get_int_attribute("Orientation", 1)
    exif = {a: spec.getattribute(a) for a in _KEEP_EXIF if spec.getattribute(a) is not None}
    w, h = spec.width, spec.height
    scale = min(1.0, image_size / max(w, h))
    plain = spec.nchannels == 3 and not linear
    if (
        src.suffix.lower() in _JPEG
        and dst.suffix.lower() in _JPEG
        and orientation == 1
        and scale == 1.0
        and plain
    ):
        shutil.copyfile(src, dst)  # nothing to change: no second JPEG compression
        return Photo(src, dst.name, w, h, _key(w, h, exif))

    if orientation != 1:
        buf = oiio.ImageBufAlgo.reorient(buf)
    if spec.nchannels >= 3:
        buf = oiio.ImageBufAlgo.channels(buf, (0, 1, 2))
    else:  # grey (+ alpha): grey in all three
        buf = oiio.ImageBufAlgo.channels(buf, (0, 0, 0))
    w, h = buf.spec().width, buf.spec().height
    if scale < 1.0:
        nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
        # triangle: an antialiased area filter at the reduction's width, 8x faster than the
        # default Blackman-Harris on a 12 MP photo and as good for SIFT
        buf = oiio.ImageBufAlgo.resize(
            buf, filtername="triangle", roi=oiio.ROI(0, nw, 0, nh, 0, 1, 0, 3)
        )
        w, h = nw, nh
    pixels = buf.get_pixels(oiio.FLOAT)  # [H, W, 3] in [0, 1] (8/16-bit scaled by OIIO)
    if pixels is None or buf.has_error:
        raise _fail(src, buf.geterror() or "cannot be decoded")
    pixels = np.nan_to_num(np.asarray(pixels, dtype=np.float32), nan=0.0, posinf=1.0)
    if linear:
        x = np.clip(pixels, 0.0, 1.0)
        pixels = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    out = np.clip(np.round(pixels * 255.0), 0, 255).astype(np.uint8)
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:  # a copy is there whole or not at all (a resumed run trusts it)
        write_rgb8(dst, out, exif)
    except OSError as e:
        raise ValueError(f"cannot write the working copy: {e}") from e
    return Photo(src, dst.name, w, h, _key(w, h, exif))


def _key(w: int, h: int, exif: dict) -> tuple:
    focal = exif.get("Exif:FocalLength")
    focal = (
        round(float(focal), 3) if isinstance(focal, (int, float)) and math.isfinite(focal) else None
    )
    return (w, h, exif.get("Make"), exif.get("Model"), focal)


def write_rgb8(path: Path, rgb: np.ndarray, attributes: dict | None = None) -> None:
    """Write ``rgb`` [H,W,3] uint8 to ``path`` (JPEG at quality 95 by its suffix), through a
    hidden sibling and a rename, so that no half-written image is ever seen (working copies
    and video frames are trusted by a resumed run). Raises OSError naming ``path``."""
    require(oiio, "OpenImageIO")
    height, width = rgb.shape[:2]
    spec = oiio.ImageSpec(width, height, 3, oiio.UINT8)
    for name, value in (attributes or {}).items():
        spec.attribute(name, value)
    if path.suffix.lower() in _JPEG:
        spec.attribute("Compression", f"jpeg:{JPEG_QUALITY}")
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        try:
            ok = out.write_image(np.ascontiguousarray(rgb))
        finally:
            out.close()
        if not ok:
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
